// The release's training recipe (qdo/design/recipe.hpp), checked against an independent reference of the
// release's quantities. The reference (namespace rel) is written in double from the facts of the
// authors' code (REFERENCE §2-3: optics/diffractive_optical_element.py, model.py,
// tasks/hyperspectral.py), in the release's own coordinates: the weight w_rel in [-1, 1] of each
// ring, the normalised etch depth u_rel = (w_rel + 1) / 2, the quantizer round-half-even(u_rel (L-1))
// with offsets 0.5 a_l on levels 1..L-1 (level 0, the unetched surface, fixed), L_aq the mean over
// the ring profile. qdo's relief axis is the other way round (u = 1 - u_rel, so w = -w_rel and qdo's
// offset of level k is -a_rel of level L-1-k); the states are mapped only at the comparison.
#include <cmath>
#include <filesystem>
#include <random>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "commands_common.hpp"
#include "common.hpp"
#include "qdo/design/design.hpp"
#include "qdo/design/design_run_options.hpp"
#include "qdo/data/io.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/radial.hpp"
#include "qdo/design/recipe.hpp"
#include "qdo/design/run.hpp"
#include "qdo/physics/simulator.hpp"

using namespace qdo;
using namespace qdo::test;
using qdo::test::commands_suite::cfg_arg;
namespace fs = std::filesystem;

namespace {

namespace rel {
// ExponentialDecay(initial_learning_rate=0.01, decay_steps=500, decay_rate=0.8), staircase False.
double lr(long t) { return 0.01 * std::pow(0.8, double(t) / 500.0); }
// The blending weight at step counter t: epochs 5 to 40 of steps_per_epoch steps.
double alpha(long t, long steps_per_epoch) {
  const double start = 5.0 * double(steps_per_epoch), end = 40.0 * double(steps_per_epoch);
  if (double(t) < start) return 0.0;
  if (double(t) > end) return 1.0;
  return 1.0 - std::pow((end - double(t)) / (end - start), 3.0);
}
// tf.round: half to even (the current rounding mode, to nearest, ties to even).
double round_half_even(double x) { return std::nearbyint(x); }
int level(double u, int levels) { return int(round_half_even(u * double(levels - 1))); }
double quantize(double u, const std::vector<double>& a, int levels) {
  const int k = level(u, levels);
  return (double(k) + (k >= 1 ? 0.5 * a[std::size_t(k)] : 0.0)) / double(levels - 1);
}
struct Laq {
  double value = 0;                // mean over the rings of (Q(u) - u)^2
  std::vector<double> g_w, g_a;    // d(beta L_aq)/dw_rel, d(beta L_aq)/da_rel
};
Laq laq(const std::vector<double>& w, const std::vector<double>& a, int levels, double beta) {
  Laq r;
  const double n = double(w.size());
  r.g_w.assign(w.size(), 0.0);
  r.g_a.assign(a.size(), 0.0);
  for (std::size_t i = 0; i < w.size(); ++i) {
    const double u = (w[i] + 1.0) / 2.0, d = quantize(u, a, levels) - u;
    r.value += d * d / n;
    r.g_w[i] = beta * (-2.0 * d / n) * 0.5;  // du/dw = 1/2; round passes no gradient
    const int k = level(u, levels);
    if (k >= 1) r.g_a[std::size_t(k)] += beta * 2.0 * d / n * 0.5 / double(levels - 1);
  }
  return r;
}
// Table 2's deviation as the release logs it (alpha = 1): mean over the rings of h |Q(u) - u|.
double deviation_m(const std::vector<double>& w, const std::vector<double>& a, int levels, double h_m) {
  double s = 0;
  for (double wi : w) {
    const double u = (wi + 1.0) / 2.0;
    s += h_m * std::fabs(quantize(u, a, levels) - u);
  }
  return s / double(w.size());
}
// Keras' Adam (epsilon hat), one step from zero moments: w - lr sqrt(1 - b2) / (1 - b1) m / (sqrt(v) + eps).
double adam_first_step(double w, double g, double lr_now) {
  const double b1 = 0.9, b2 = 0.999, m = (1 - b1) * g, v = (1 - b2) * g * g;
  return std::clamp(w - lr_now * std::sqrt(1 - b2) / (1 - b1) * m / (std::sqrt(v) + 1e-7), -1.0, 1.0);
}
}  // namespace rel

// A 2-D PSF source that remembers the heights it was given (the step's heights, noise included).
class Recording final : public HeightMapPsfSource {
 public:
  explicit Recording(Simulator& s) : s_(s) {}
  Runtime& runtime() const override { return s_.runtime(); }
  const SystemConfig& config() const override { return s_.config(); }
  Precision precision() const override { return s_.precision(); }
  std::size_t sensor_size() const override { return s_.sensor_size(); }
  std::size_t psf_planes() const override { return s_.psf_planes(); }
  bool psf_ready() const override { return s_.psf_ready(); }
  const cl::Buffer& psf_sensor_buffer() const override { return s_.psf_sensor_buffer(); }
  std::uint64_t psf_generation() const override { return s_.psf_generation(); }
  RealStack psf_sensor() const override { return s_.psf_sensor(); }
  std::string describe() const override { return "recording " + s_.describe(); }
  void set_heights(const Map2D& h) override {
    last = h;
    s_.set_heights(h);
  }
  void compute_psf() override { s_.compute_psf(); }
  Map2D psf_sensor_vjp(const RealStack& g) override { return s_.psf_sensor_vjp(g); }
  Map2D psf_sensor_vjp(const cl::Buffer& g) override { return s_.psf_sensor_vjp(g); }
  Map2D last;

 private:
  Simulator& s_;
};

DesignRunOptions release_options(int levels) {
  DesignRunOptions o;
  o.cfg = tiny_config(32, 3);
  o.design.mode = DesignMode::QDOA;
  o.design.quantizer.levels = levels;
  apply_recipe("release", o);
  return o;
}

// The zero objective: the gradient is beta L_aq's alone (the quantized path carries nothing).
const PsfObjective kZero = [](const RealStack& psf, RealStack& g) {
  g = RealStack(psf.planes, psf.rows, psf.cols);
  return 0.0;
};

double rel_err(double a, double b) { return std::fabs(a - b) / std::max(std::fabs(b), 1e-300); }

}  // namespace

TEST_SUITE("recipe") {
  TEST_CASE("the release recipe's items as the release sets them, and qdo's as before") {
    const DesignRunOptions r = release_options(4);
    CHECK(r.recipe == "release");
    CHECK(r.epochs == 50);
    CHECK(r.design.steps_per_epoch == 418);
    CHECK(r.design.t0_epochs == 5.0);
    CHECK(r.design.t1_epochs == 40.0);
    CHECK(r.design.lr_optics == 0.01);
    CHECK(r.design.lr_decay_per_epoch == 0.8);
    CHECK(r.design.lr_decay_steps == 500.0);
    CHECK_FALSE(r.design.lr_staircase);
    CHECK(r.design.adam_epsilon == 1e-7);
    CHECK(r.design.adam_keras_form);
    CHECK(r.init.kind == InitSpec::Kind::Half);
    CHECK(r.design.aq_domain == AqDomain::Parameters);
    CHECK(r.design.quantizer.pin_top);
    CHECK(r.design.height_noise_m == doctest::Approx(20e-9).epsilon(1e-12));
    CHECK(r.height_noise_at_test);
    CHECK(r.design.psf_path == PsfPath::TwoD);
    CHECK(r.gamma_decoder == 0.0);
    CHECK(r.lr_decoder == 0.001);
    CHECK(r.sampling.noise_on_bands);
    CHECK(r.sampling.fixed_patches);
    CHECK(r.network_style.keras_batch_norm);
    CHECK(r.network_style.glorot_final);
    DesignRunOptions q;
    apply_recipe("qdo", q);
    CHECK(q.design.steps_per_epoch == 10);
    CHECK(q.design.lr_decay_steps == 0.0);
    CHECK(q.design.lr_staircase);
    CHECK(q.init.kind == InitSpec::Kind::Random);
    CHECK(q.design.aq_domain == AqDomain::Pixels);
    CHECK_FALSE(q.design.quantizer.pin_top);
    CHECK(q.design.height_noise_m == 0.0);
    CHECK(q.gamma_decoder == 1e-4);
    CHECK_FALSE(q.sampling.noise_on_bands);
    CHECK_FALSE(q.sampling.fixed_patches);
    CHECK_FALSE(q.network_style.keras_batch_norm);
    CHECK_FALSE(q.network_style.glorot_final);
    // A caller's own choice stays; an unknown recipe is refused by name.
    DesignRunOptions g;
    g.epochs = 7;
    apply_recipe("release", g, [](const std::string& opt) { return opt == "epochs"; });
    CHECK(g.epochs == 7);
    CHECK(g.design.t1_epochs == doctest::Approx(5.6));
    CHECK_THROWS_WITH_AS(apply_recipe("paper", g), doctest::Contains("paper"), InputError);
    // The recipe round-trips through config.json, item by item.
    DesignRunOptions rt = r;
    rt.out = "x";
    const DesignRunOptions back = design_run_options_from_json(design_run_options_to_json(rt), "config.json");
    CHECK(design_run_options_to_json(back) == design_run_options_to_json(rt));
    CHECK(back.recipe == "release");
    CHECK(back.design.aq_domain == AqDomain::Parameters);
    CHECK(back.design.quantizer.pin_top);
    CHECK(back.init.kind == InitSpec::Kind::Half);
    CHECK(back.sampling.fixed_patches);
    CHECK(back.sampling.noise_on_bands);
    CHECK(back.network_style.keras_batch_norm);
    CHECK(back.network_style.glorot_final);
    // A config.json written before the network items read as qdo's network.
    nlohmann::json j = nlohmann::json::parse(design_run_options_to_json(rt));
    for (const char* k : {"keras_batch_norm", "glorot_final", "noise_on_bands", "fixed_patches"}) j["design"].erase(k);
    const DesignRunOptions old = design_run_options_from_json(j.dump(), "config.json");
    CHECK_FALSE(old.sampling.fixed_patches);
    CHECK_FALSE(old.network_style.glorot_final);
  }

  TEST_CASE("parity with the release: lr, alpha, the initial rings, L_aq and its gradients, the deviation") {
    for (int levels : {2, 4, 8}) {
      CAPTURE(levels);
      const DesignRunOptions o = release_options(levels);
      Simulator sim(runtime(), o.cfg, Precision::F32);
      Designer d(sim, o.design);
      // lr and alpha at the release's steps (418 per epoch): the window opens at 2,090 and closes at 16,720.
      for (long t : {0L, 1L, 499L, 500L, 501L, 2089L, 2090L, 2091L, 9405L, 16719L, 16720L, 16721L, 20899L}) {
        CAPTURE(t);
        CHECK(rel_err(o.design.lr_optics * o.design.lr_factor(t), rel::lr(t)) < 1e-14);
        CHECK(std::fabs(d.alpha_at(t) - rel::alpha(t, 418)) < 1e-15);
      }
      // The initial design: every ring at w_rel = 1e-4 (u = 0.5 on the etch axis).
      const double h = o.cfg.h_max_m();
      DesignState s = d.initial_state(initial_params(o));
      for (double w : s.w) CHECK(std::fabs(-w - 1e-4) < 1e-15);
      // L_aq, its gradients and the deviation at the initial state and at random states with offsets.
      std::mt19937_64 rng(11 + unsigned(levels));
      std::uniform_real_distribution<double> uw(-1.0, 1.0), ua(levels == 2 ? -0.2 : -1.0, levels == 2 ? 0.2 : 1.0);
      for (int trial = 0; trial < 4; ++trial) {
        CAPTURE(trial);
        if (trial > 0) {
          for (double& w : s.w) w = uw(rng);
          for (double& a : s.offsets) a = ua(rng);
          s.offsets[std::size_t(levels - 1)] = 0.0;  // the pinned (top) level
          s.offsets[0] = std::fabs(s.offsets[0]);    // level 0 stays at or above H = 0
        }
        s.step = trial * 3000;  // before, inside and after the alpha window (L_aq does not depend on it)
        std::vector<double> w_rel(s.w.size()), a_rel(s.offsets.size());
        for (std::size_t i = 0; i < s.w.size(); ++i) w_rel[i] = -s.w[i];
        for (int l = 0; l < levels; ++l) a_rel[std::size_t(l)] = -s.offsets[std::size_t(levels - 1 - l)];
        const rel::Laq ref = rel::laq(w_rel, a_rel, levels, o.design.beta_aq);
        const Designer::Gradient g = d.gradient(s, kZero);
        CHECK(rel_err(g.report.loss_aq, ref.value) < 1e-12);
        CHECK(rel_err(g.report.loss, o.design.beta_aq * ref.value) < 1e-12);
        double scale = 0;
        for (double v : ref.g_w) scale = std::max(scale, std::fabs(v));
        for (std::size_t i = 0; i < s.w.size(); ++i) CHECK(std::fabs(g.g_w[i] - (-ref.g_w[i])) <= 1e-6 * scale);
        double ascale = 1e-300;
        for (double v : ref.g_a) ascale = std::max(ascale, std::fabs(v));
        for (int k = 0; k < levels; ++k)
          CHECK(std::fabs(g.g_offsets[std::size_t(k)] - (-ref.g_a[std::size_t(levels - 1 - k)])) <= 1e-6 * ascale);
        CHECK(rel_err(g.report.deviation_m, rel::deviation_m(w_rel, a_rel, levels, h)) < 1e-12);
      }
      // One step from the initial state in Keras' Adam form, at the release's lr.
      DesignState s0 = d.initial_state(initial_params(o));
      const Designer::Gradient g0 = d.gradient(s0, kZero);
      const std::vector<double> w0 = s0.w;
      const StepReport rep = d.step(s0, kZero);
      CHECK(rel_err(rep.lr, rel::lr(0)) < 1e-15);
      for (std::size_t i = 0; i < w0.size(); ++i) CHECK(std::fabs(s0.w[i] - rel::adam_first_step(w0[i], g0.g_w[i], rel::lr(0))) < 1e-15);
    }
  }

  TEST_CASE("the release recipe's gradients against central differences (float64): weights and the unpinned offsets") {
    if (!skip_unless(runtime().has_fp64(), "a float64 device for the central differences")) return;
    DesignRunOptions o = release_options(4);
    o.design.height_noise_m = 0;  // the loss as a function of the state alone
    Simulator sim(runtime(), o.cfg, Precision::F64);
    sim.set_heights(lens_design(o.cfg, 500));
    sim.compute_psf();
    const PsfObjective obj = psf_target_objective(sim.psf_sensor());
    Designer d(sim, o.design);
    DesignState s = d.initial_state(initial_params(o));
    std::mt19937_64 rng(5);
    std::uniform_real_distribution<double> uw(-0.9, 0.9), ua(0.05, 0.6);
    for (double& w : s.w) w = uw(rng);
    for (std::size_t l = 0; l + 1 < s.offsets.size(); ++l) s.offsets[l] = ua(rng) * (l % 2 ? -1.0 : 1.0);
    s.offsets[0] = std::fabs(s.offsets[0]);
    s.step = 6 * 418;  // alpha about 0.26: both branches of the blend carry gradient
    const Designer::Gradient g = d.gradient(s, obj);
    // The central difference of the loss in parameter `i` of the group `group` picks from a state.
    const auto central = [&](std::vector<double> DesignState::*group, std::size_t i) {
      const double h = 1e-7;
      DesignState a = s, b = s;
      (a.*group)[i] += h;
      (b.*group)[i] -= h;
      return (d.gradient(a, obj).report.loss - d.gradient(b, obj).report.loss) / (2 * h);
    };
    const double gw_scale = max_abs(g.g_w), ga_scale = max_abs(g.g_offsets);
    REQUIRE(ga_scale > 0);
    for (std::size_t i : {std::size_t(0), std::size_t(3), std::size_t(7), std::size_t(12), std::size_t(15)}) {
      CAPTURE(i);
      CHECK(std::fabs(central(&DesignState::w, i) - g.g_w[i]) <= 1e-5 * gw_scale + 1e-9);
    }
    CHECK(g.g_offsets[3] == 0.0);  // the pinned top level
    for (std::size_t l = 0; l < 3; ++l) {
      CAPTURE(l);
      CHECK(std::fabs(central(&DesignState::offsets, l) - g.g_offsets[l]) <= 1e-5 * ga_scale + 1e-9);
    }
  }

  TEST_CASE("the release's height noise: a fresh uniform +-20 nm draw per pixel on every step") {
    const DesignRunOptions o = release_options(4);
    Simulator sim(runtime(), o.cfg, Precision::F32);
    Recording rec(sim);
    Designer d(rec, o.design);
    DesignState s = d.initial_state(initial_params(o));
    const Map2D clean = d.training_heights(s);
    std::vector<double> all, first;
    for (int step = 0; step < 8; ++step) {
      s.step = step;  // the noise comes from (seed, step); the heights stay the initial ones
      d.gradient(s, kZero);
      REQUIRE(rec.last.data.size() == clean.data.size());
      std::vector<double> dn;
      for (std::size_t i = 0; i < clean.data.size(); ++i) dn.push_back((rec.last.data[i] - clean.data[i]) * 1e9);
      if (step == 0) first = dn;
      else CHECK(max_abs_diff(dn, first) > 1.0);  // a new draw each step
      all.insert(all.end(), dn.begin(), dn.end());
    }
    double mean = 0, var = 0, below = 0;
    for (double v : all) {
      CHECK(std::fabs(v) <= 20.0 + 1e-6);
      mean += v / double(all.size());
      below += v < -10.0 ? 1.0 / double(all.size()) : 0.0;
    }
    for (double v : all) var += (v - mean) * (v - mean) / double(all.size() - 1);
    const double n = double(all.size());  // 8 x 1024 draws
    CHECK(std::fabs(mean) < 4.0 * std::sqrt(400.0 / 3.0 / n));
    CHECK(std::fabs(var - 400.0 / 3.0) < 4.0 * 400.0 / 3.0 * std::sqrt(0.8 / n));  // var of U(-a, a) is a^2/3; of its estimate 0.8 a^4/9/n
    CHECK(std::fabs(below - 0.25) < 4.0 * std::sqrt(0.25 * 0.75 / n));
  }

  TEST_CASE("qdo design without --recipe trains as the release; --resume holds to the recipe") {
    const qdo::test::commands_suite::ScratchDir scratch("recipe_cli");  // removed on exit, a failed REQUIRE included
    const fs::path& dir = scratch.dir;
    const std::string run = (dir / "r").string(), init = (dir / "i").string();
    const std::string base = "design " + cfg_arg() + " --mode qdo+a --levels 4 --synthetic-scenes 2 --epochs 2 --steps-per-epoch 3 --out ";
    const Run r = qdo_run(base + run + " --max-steps 3");
    CAPTURE(r.out);
    REQUIRE(r.code == 0);
    const DesignRunOptions o = design_run_options_from_json(slurp(fs::path(run) / "config.json"), "config.json");
    CHECK(o.recipe == "release");
    CHECK(o.design.lr_decay_steps == 500.0);
    CHECK_FALSE(o.design.lr_staircase);
    CHECK(o.design.aq_domain == AqDomain::Parameters);
    CHECK(o.design.quantizer.pin_top);
    CHECK(o.design.adam_keras_form);
    CHECK(o.init.kind == InitSpec::Kind::Half);
    CHECK(o.design.height_noise_m == doctest::Approx(20e-9).epsilon(1e-12));
    CHECK(o.height_noise_at_test);
    const CsvTable log = read_csv((fs::path(run) / "log.csv").string());
    REQUIRE(log.column("lr").size() == 3);
    for (std::size_t t = 0; t < 3; ++t) CHECK(rel_err(log.column("lr")[t], rel::lr(long(t))) < 1e-9);
    CHECK(log.column("deviation_nm").size() == 3);
    // The initial heights (no step taken): every ring at half the quantization height.
    REQUIRE(qdo_run(base + init + " --max-steps 0").code == 0);
    const Design full = read_design((fs::path(init) / "design_full.h5").string());
    const std::vector<double> rings = ring_heights_of_map(full.height_m);
    for (double v : rings) CHECK(rel_err(v, o.cfg.h_max_m() * (1.0 - 0.50005)) < 1e-12);
    // --resume continues with the stored recipe; another one given is refused by name.
    const Run bad = qdo_run(base + run + " --resume --recipe qdo");
    CHECK(bad.code == 2);
    CHECK(bad.out.find("--recipe") != std::string::npos);
    const Run cont = qdo_run("design --resume --out " + run + " --max-steps 5");
    CAPTURE(cont.out);
    REQUIRE(cont.code == 0);
    const CsvTable log2 = read_csv((fs::path(run) / "log.csv").string());
    REQUIRE(log2.column("lr").size() == 5);
    for (std::size_t t = 0; t < 5; ++t) CHECK(rel_err(log2.column("lr")[t], rel::lr(long(t))) < 1e-9);
    // The qdo recipe decays per epoch, in whole epochs.
    const Run q = qdo_run(base + (dir / "q").string() + " --recipe qdo --max-steps 4");
    REQUIRE(q.code == 0);
    const CsvTable lq = read_csv(((dir / "q") / "log.csv").string());
    REQUIRE(lq.column("lr").size() == 4);
    CHECK(lq.column("lr")[2] == doctest::Approx(0.01));
    CHECK(lq.column("lr")[3] == doctest::Approx(0.008));
  }
}
