// Designs over a range of object points, doctest suite "design-range": the
// range objective's gradient against finite differences (tests/adjoint_ladder.hpp), the Wiener
// objective's indifference to where in the window the PSF lies (why off-axis PSFs are not
// recentred), `qdo design` training over a depth range end to end, resume, a range design
// against a one-point design on the same points, and the refusals. Tiny system (N = 32, 3 bands,
// z = 1.56 mm), where object distances of millimetres to centimetres defocus as 0.5 to 5 m do on
// the paper's 50 mm camera.
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <map>
#include <memory>
#include <random>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "adjoint_ladder.hpp"
#include "commands_common.hpp"
#include "common.hpp"
#include "qdo/design/design.hpp"
#include "qdo/design/design_run.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/point_psf.hpp"
#include "qdo/design/run.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/decode/wiener.hpp"

using namespace qdo;
using namespace qdo::test;
using namespace qdo::test::commands_suite;
namespace fs = std::filesystem;
using nlohmann::json;

namespace {

Precision precision() { return runtime().has_fp64() ? Precision::F64 : Precision::F32; }

// The tiny system with on-axis object points at these distances (metres; inf allowed).
SystemConfig range_config(const std::vector<double>& distances_m) {
  SystemConfig c = tiny_config(32, 3);
  c.object_points = object_point_grid(distances_m, {{0.0, 0.0}});
  c.validate();
  return c;
}

constexpr double kInf = std::numeric_limits<double>::infinity();

// The closed-form Wiener objective (CPU, double) on a prior from seeded random scenes.
struct WienerFixture {
  Eigen::MatrixXd srf;
  wiener::SpectralPrior prior;
  explicit WienerFixture(const SystemConfig& c) : srf(sensor_response(c)) {
    const std::size_t s = c.sensor_size_px();
    std::vector<RealStack> scenes;
    for (unsigned k = 0; k < 4; ++k) scenes.push_back(random_cube(c.bands, s, s, 40 + k));
    prior = wiener::estimate_prior(scenes, 8);
  }
  double value(const RealStack& psf, RealStack* grad = nullptr) const {
    wiener::PsfObjective r = wiener::objective_psf(wiener::Loss::Expected, psf, srf, prior, 1e-3, {});
    if (grad) *grad = std::move(r.grad_psf);
    return r.value;
  }
  PointObjective point_objective() const {
    return [this](std::size_t, const RealStack& psf, RealStack& grad) { return value(psf, &grad); };
  }
};

DesignOptions ladder_options(DesignMode m, PsfPath path) {
  DesignOptions o;
  o.mode = m;
  o.parameterization = Parameterization::Radial;
  o.quantizer.levels = 4;
  o.steps_per_epoch = 2;
  o.t0_epochs = 1;
  o.t1_epochs = 5;
  o.seed = 3;
  o.psf_path = path;
  return o;
}


// One 2-D source per object point of c (point_config), and the list the Designer takes.
struct PointSources {
  std::vector<std::unique_ptr<Simulator>> sims;
  std::vector<HeightMapPsfSource*> list;
  PointSources(const SystemConfig& c, Precision p) {
    for (std::size_t k = 0; k < c.point_count(); ++k) {
      sims.push_back(std::make_unique<Simulator>(runtime(), point_config(c, k), p));
      list.push_back(sims.back().get());
    }
  }
};

DesignRunOptions range_run(const std::string& out, const SystemConfig& cfg, std::size_t points_per_step) {
  DesignRunOptions o;
  o.cfg = cfg;
  o.design.mode = DesignMode::QDOA;
  o.design.quantizer.levels = 4;
  o.design.steps_per_epoch = 3;
  o.design.t0_epochs = 1;
  o.design.t1_epochs = 3;
  o.design.seed = 7;
  o.design.points_per_step = points_per_step;
  o.epochs = 4;
  o.synthetic_scenes = 3;
  o.checkpoint_every = 4;
  o.precision = precision();
  o.out = out;
  o.quiet = true;
  return o;
}

std::vector<std::string> split(const std::string& s, char sep) {
  std::vector<std::string> v;
  std::stringstream ss(s);
  for (std::string item; std::getline(ss, item, sep);) v.push_back(item);
  return v;
}

// log.csv as rows of fields (header dropped).
std::vector<std::vector<std::string>> log_rows(const fs::path& p, std::vector<std::string>* header = nullptr) {
  std::istringstream s(slurp(p));
  std::string line;
  std::getline(s, line);
  if (header) *header = split(line, ',');
  std::vector<std::vector<std::string>> rows;
  while (std::getline(s, line))
    if (!line.empty()) rows.push_back(split(line, ','));
  return rows;
}

}  // namespace

TEST_SUITE("design-range") {
  // The range objective (mean over P = 3 on-axis distances of the closed-form Wiener loss, every
  // point every step) against central differences, on the radial and the 2-D paths, in full
  // precision and mid-schedule qdo+a: the ladder's directional and per-parameter rungs in double.
  // Within 1e-5 of the entry plus 1e-9, as the one-point design rows of the adjoint table.
  TEST_CASE("the range objective's gradient matches finite differences (P = 3 distances, every point per step)") {
    REQUIRE(runtime().has_fp64());
    const SystemConfig cfg = range_config({0.005, 0.012, kInf});
    const auto wf = std::make_shared<const WienerFixture>(cfg);
    for (PsfPath path : {PsfPath::Auto, PsfPath::TwoD}) {
      for (DesignMode m : {DesignMode::Full, DesignMode::QDOA}) {
        struct Run {
          PointSources src;
          Designer d;
          DesignState s;
          Run(const SystemConfig& c, const DesignOptions& o) : src(c, Precision::F64), d(src.list, o) {}
        };
        DesignOptions o = ladder_options(m, path);
        o.points_per_step = 3;
        const auto run = std::make_shared<Run>(cfg, o);
        CHECK(run->d.uses_radial() == (path == PsfPath::Auto));
        CHECK(run->d.step_points(0) == std::vector<std::size_t>{0, 1, 2});
        run->s = run->d.initial_state(start_params(cfg, 5));
        run->s.step = 6;  // mid-schedule: 0 < alpha < 1
        run->s.offsets = {0.0, 0.3, -0.2, 0.1};
        const std::vector<std::size_t> all{0, 1, 2};
        Stage w("range design " + to_string(m) + ", " + to_string(path) + " path: weights -> mean loss over 3 points", run->s.w.size(), 1);
        w.forward = [run, wf, all](const std::vector<double>& x) {
          DesignState st = run->s;
          st.w = x;
          return std::vector<double>{run->d.range_gradient(st, all, wf->point_objective()).report.loss};
        };
        w.vjp = [run, wf, all](const std::vector<double>& x, const std::vector<double>& g) {
          DesignState st = run->s;
          st.w = x;
          std::vector<double> gw = run->d.range_gradient(st, all, wf->point_objective()).g_w;
          for (double& v : gw) v *= g[0];
          return gw;
        };
        w.x0 = run->s.w;
        w.g0 = {1.0};
        w.fd_tol = 0;
        // The Wiener loss carries rounding of ~1e-12 relative (its 3 x 3 solves): a plain 1e-7
        // step is off by ~1e-5 at a correct gradient (gradcheck.cpp); Richardson's extrapolation
        // of 1e-5 and 2e-5 steps (7.7 pm of height) has truncation O(h^4) and small rounding.
        w.fd_step = 1e-5;
        w.richardson = true;
        w.dir_rel = w.probe_rel = 1e-5;
        w.dir_abs = w.probe_abs = 1e-9;
        w.probes = {0, 3, 7, 11};
        check_ladder(w, 11);

        // The range gradient is the mean of the one-point designs' gradients (each on its own
        // source), and its loss the mean of theirs; the per-point losses are reported.
        const Designer::Gradient g = run->d.range_gradient(run->s, all, wf->point_objective());
        REQUIRE(g.report.points == all);
        REQUIRE(g.report.point_loss.size() == 3);
        std::vector<double> mean_g(g.g_w.size(), 0.0);
        double mean_loss = 0;
        for (std::size_t p = 0; p < 3; ++p) {
          Simulator one(runtime(), point_config(cfg, p), Precision::F64);
          DesignOptions o1 = o;
          o1.points_per_step = 1;
          Designer d1(one, o1);
          const Designer::Gradient g1 =
              d1.gradient(run->s, [&wf](const RealStack& psf, RealStack& gr) { return wf->value(psf, &gr); });
          const double aq = m == DesignMode::QDOA ? o.beta_aq * g1.report.loss_aq : 0.0;
          CHECK(g1.report.loss - aq == doctest::Approx(g.report.point_loss[p]).epsilon(1e-12));
          mean_loss += g1.report.loss / 3;
          for (std::size_t i = 0; i < mean_g.size(); ++i) mean_g[i] += g1.g_w[i] / 3;
        }
        CHECK(g.report.loss == doctest::Approx(mean_loss).epsilon(1e-12));
        double diff = 0, norm = 0;
        for (std::size_t i = 0; i < mean_g.size(); ++i) {
          diff = std::max(diff, std::fabs(mean_g[i] - g.g_w[i]));
          norm = std::max(norm, std::fabs(mean_g[i]));
        }
        CHECK(diff <= 1e-12 * norm);
        // The three points see different PSFs (the depths matter on this system).
        CHECK(std::fabs(g.report.point_loss[0] - g.report.point_loss[2]) > 1e-3 * std::fabs(g.report.point_loss[2]));
      }
    }
  }

  // Why an off-axis PSF is not recentred for the Wiener objectives: the closed-form MMSE error is
  // built on A(f) = S diag(OTF_b(f)), and a PSF moved as a whole (every band the same whole-pixel
  // circular shift) multiplies every OTF_b(f) by one phase exp(-i 2 pi f . shift), which cancels
  // in A^H (A P A^H + s^2 I)^-1 A. A PSF at its chief-ray image is such a move of a centred one
  // (up to the light at the window's edge), so the objective sees no shifted target.
  TEST_CASE("the Wiener objective does not see where in the window the PSF lies; off-axis points train on the 2-D path") {
    REQUIRE(runtime().has_fp64());
    SystemConfig cfg = tiny_config(32, 3);
    const WienerFixture wf(cfg);
    Simulator sim(runtime(), cfg, Precision::F64);
    sim.set_heights(lens_design(cfg, 500));
    sim.compute_psf();
    const RealStack psf = sim.psf_sensor();
    const std::size_t s = psf.rows;
    for (const auto& [dy, dx] : {std::pair<long, long>{3, -2}, {-5, 4}, {0, 7}}) {
      RealStack moved(psf.planes, s, s);
      for (std::size_t b = 0; b < psf.planes; ++b)
        for (std::size_t y = 0; y < s; ++y)
          for (std::size_t x = 0; x < s; ++x)
            moved(b, (y + s + std::size_t(dy + long(s))) % s, (x + s + std::size_t(dx + long(s))) % s) = psf(b, y, x);
      CAPTURE(dy);
      CAPTURE(dx);
      CHECK(wf.value(moved) == doctest::Approx(wf.value(psf)).epsilon(1e-10));
    }
    // An off-axis point: the largest angle the sampling allows at 1 cm, halved.
    const double limit = max_field_angle_deg(cfg, 0.01);
    MESSAGE("tiny system: field angles up to " << limit << " deg at 0.01 m");
    REQUIRE(limit > 0.5);
    const double angle = 0.5 * limit;
    cfg.object_points = {ObjectPoint{0.01, 0, 0}, ObjectPoint{0.01, angle, 0}};
    cfg.validate();
    const auto off = chief_ray_offset_px(cfg, cfg.object_points[1]);
    MESSAGE("off-axis point at " << angle << " deg: chief-ray image " << off.second << " px from the axis");
    // The off-axis PSF and the same PSF moved onto the axis give the Wiener objective the same value
    // to the light the move pushes out of the window.
    Simulator offsim(runtime(), point_config(cfg, 1), Precision::F64);
    offsim.set_heights(lens_design(cfg, 500));
    offsim.compute_psf();
    const RealStack at_image = offsim.psf_sensor();
    double lost = 0;
    const RealStack centred = recentre_on_chief_ray(at_image, point_config(cfg, 1), cfg.object_points[1], &lost);
    MESSAGE("Wiener objective at the chief-ray image " << wf.value(at_image) << ", recentred " << wf.value(centred)
                                                       << " (light moved out of the window: " << lost << ")");
    CHECK(wf.value(centred) == doctest::Approx(wf.value(at_image)).epsilon(1e-6 + 10 * lost));
    // A design over an on-axis and an off-axis point: auto takes the 2-D path (the radial engine
    // serves on-axis points only), an explicit radial path is refused naming it, and the range
    // gradient passes the directional finite difference.
    PointSources src(cfg, Precision::F64);
    DesignOptions o = ladder_options(DesignMode::Full, PsfPath::Auto);
    o.points_per_step = 2;
    Designer d(src.list, o);
    CHECK_FALSE(d.uses_radial());
    DesignOptions radial = o;
    radial.psf_path = PsfPath::Radial;
    CHECK_THROWS_WITH_AS(Designer(src.list, radial), doctest::Contains("psf_path"), InputError);
    DesignState st = d.initial_state(start_params(cfg, 9));
    const std::vector<std::size_t> both{0, 1};
    Stage w("range design full, on- and off-axis points, 2-D path", st.w.size(), 1);
    w.forward = [&](const std::vector<double>& x) {
      DesignState t = st;
      t.w = x;
      return std::vector<double>{d.range_gradient(t, both, wf.point_objective()).report.loss};
    };
    w.vjp = [&](const std::vector<double>& x, const std::vector<double>& g) {
      DesignState t = st;
      t.w = x;
      std::vector<double> gw = d.range_gradient(t, both, wf.point_objective()).g_w;
      for (double& v : gw) v *= g[0];
      return gw;
    };
    w.x0 = st.w;
    w.g0 = {1.0};
    w.fd_tol = 0;
    w.fd_step = 1e-5;
    w.richardson = true;
    w.dir_rel = w.probe_rel = 1e-5;
    w.dir_abs = w.probe_abs = 1e-9;
    w.probes = {2, 9};
    check_ladder(w, 12);
  }

  TEST_CASE("step_points: points_per_step distinct points drawn from (seed, step); all of them when it is P") {
    const SystemConfig cfg = range_config({0.004, 0.008, 0.016, kInf});
    PointSources src(cfg, precision());
    DesignOptions o = ladder_options(DesignMode::Full, PsfPath::TwoD);
    o.points_per_step = 2;
    const Designer d(src.list, o);
    std::map<std::size_t, int> seen;
    for (long k = 0; k < 40; ++k) {
      const std::vector<std::size_t> p = d.step_points(k);
      REQUIRE(p.size() == 2);
      CHECK(p[0] < p[1]);
      CHECK(p[1] < 4);
      CHECK(p == d.step_points(k));  // the same draw again (a resumed run)
      for (std::size_t i : p) ++seen[i];
    }
    CHECK(seen.size() == 4);  // every point trained on in 40 steps
    o.seed = 4;
    const Designer other(src.list, o);
    bool differs = false;
    for (long k = 0; k < 10; ++k) differs = differs || other.step_points(k) != d.step_points(k);
    CHECK(differs);
    o.points_per_step = 4;
    CHECK(Designer(src.list, o).step_points(3) == std::vector<std::size_t>{0, 1, 2, 3});
    o.points_per_step = 5;
    CHECK_THROWS_WITH_AS(Designer(src.list, o), doctest::Contains("points_per_step"), InputError);
    o.points_per_step = 0;
    CHECK_THROWS_WITH_AS(Designer(src.list, o), doctest::Contains("points_per_step"), InputError);
    // One point: the one-point design exactly (step() and range_step() agree bit for bit).
    Simulator one(runtime(), tiny_config(32, 3), precision());
    DesignOptions o1 = ladder_options(DesignMode::QDOA, PsfPath::Auto);
    Designer a(one, o1), b(one, o1);
    const RealStack target = [&] {
      one.set_heights(lens_design(one.config(), 500));
      one.compute_psf();
      return one.psf_sensor();
    }();
    const PsfObjective obj = psf_target_objective(target);
    DesignState sa = a.initial_state(start_params(one.config(), 2)), sb = sa;
    for (int k = 0; k < 3; ++k) {
      const StepReport ra = a.step(sa, obj);
      const StepReport rb = b.range_step(sb, [&](std::size_t, const RealStack& p, RealStack& g) { return obj(p, g); });
      CHECK(ra.loss == rb.loss);
      CHECK(rb.points == std::vector<std::size_t>{0});
    }
    CHECK(sa.w == sb.w);
    CHECK(sa.offsets == sb.offsets);
  }

  TEST_CASE("a range run resumed after a stop mid-run equals an uninterrupted one, bit for bit") {
    const auto dir = temp_dir("range_resume");
    const std::string a = (dir / "a").string(), b = (dir / "b").string();
    const SystemConfig cfg = range_config({0.004, 0.008, 0.016, kInf});
    const DesignRunResult ra = run_design(runtime(), range_run(a, cfg, 2), false);
    CHECK(ra.steps_done == 12);
    DesignRunOptions first = range_run(b, cfg, 2);
    first.max_steps = 6;  // stopped after step 6 (checkpoint at 4, then the session's last at 6)
    CHECK(run_design(runtime(), first, false).steps_done == 6);
    const DesignRunResult rb = run_design(runtime(), range_run(b, cfg, 2), true);
    CHECK(rb.steps_done == 12);
    const DesignState sa = load_checkpoint(a + "/checkpoint.h5", 16, 4), sb = load_checkpoint(b + "/checkpoint.h5", 16, 4);
    CHECK(sa.w == sb.w);
    CHECK(sa.offsets == sb.offsets);
    CHECK(sa.adam_w.v == sb.adam_w.v);
    CHECK(read_design(a + "/design.h5").height_m.data == read_design(b + "/design.h5").height_m.data);
    CHECK(slurp(fs::path(a) / "range.csv") == slurp(fs::path(b) / "range.csv"));
    REQUIRE(ra.point_losses.size() == 4);
    CHECK(ra.point_losses == rb.point_losses);
    // The logs agree on every column but the step time.
    const auto la = log_rows(fs::path(a) / "log.csv"), lb = log_rows(fs::path(b) / "log.csv");
    REQUIRE(la.size() == 12);
    REQUIRE(lb.size() == 12);
    for (std::size_t k = 0; k < la.size(); ++k) {
      REQUIRE(la[k].size() == lb[k].size());
      for (std::size_t c = 0; c < la[k].size(); ++c)
        if (c != 5) CHECK(la[k][c] == lb[k][c]);
    }
    // config.json keeps the object points and points_per_step; a run folder of a range run is
    // refused by the commands that consume one point's run, naming the count.
    const json cj = read_json(fs::path(a) / "config.json");
    CHECK(cj["system"]["object_points"].size() == 4);
    CHECK(cj["system"]["object_points"][3][0] == "inf");
    CHECK(cj["design"]["points_per_step"] == 2);
    CHECK_THROWS_WITH_AS(read_run_config(a, "RUN"), doctest::Contains("4 object points"), InputError);
    CHECK(read_run_config(a, "RUN", "x", true).cfg.point_count() == 4);
    fs::remove_all(dir);
  }

  // End to end: qdo design trains over a depth range (P = 4 distances, two per step).
  TEST_CASE("qdo design --object-distances trains over a depth range: points sampled per step, the loss falls, range.csv") {
    const auto dir = temp_dir("range_cli");
    const fs::path run = dir / "run";
    const Run r = qdo_run("design " + cfg_arg() + " --object-distances 0.004,0.008,0.016,inf --points-per-step 2 --mode qdo+a "
                          "--levels 4 --epochs 4 --steps-per-epoch 4 --t0 1 --t1 3 --synthetic-scenes 3 --seed 3 --out " +
                          run.string());
    CAPTURE(r.out);
    REQUIRE(r.code == 0);
    CHECK(r.out.find("range: mean loss") != std::string::npos);
    CHECK(r.out.find("range.csv") != std::string::npos);
    const json cj = read_json(run / "config.json");
    REQUIRE(cj["system"]["object_points"].size() == 4);
    CHECK(cj["system"]["object_points"][0][0] == 0.004);
    CHECK(cj["system"]["object_points"][3][0] == "inf");
    CHECK(cj["design"]["points_per_step"] == 2);
    std::vector<std::string> header;
    const auto rows = log_rows(run / "log.csv", &header);
    REQUIRE(rows.size() == 16);
    REQUIRE(header.size() == 10);
    CHECK(header[7] == "points");
    CHECK(header[8] == "point_losses");
    CHECK(header[9] == "deviation_nm");
    std::set<std::string> draws;
    std::vector<int> trained(4, 0);
    std::vector<double> loss;
    for (const auto& row : rows) {
      REQUIRE(row.size() == 10);
      const auto pts = split(row[7], ';'), pl = split(row[8], ';');
      REQUIRE(pts.size() == 2);
      REQUIRE(pl.size() == 2);
      draws.insert(row[7]);
      for (const auto& p : pts) ++trained.at(std::stoul(p));
      // The step's loss is the mean over its points plus beta L_aq (beta 0.01).
      const double mean = 0.5 * (std::stod(pl[0]) + std::stod(pl[1]));
      CHECK(std::stod(row[1]) == doctest::Approx(mean + 0.01 * std::stod(row[2])).epsilon(1e-8));
      loss.push_back(mean);
    }
    CHECK(draws.size() >= 3);  // several different pairs over the run
    for (int t : trained) CHECK(t > 0);
    // The loss falls: each point's objective at its last draw is below its first draw.
    std::vector<double> first(4, NAN), last(4, NAN);
    for (const auto& row : rows) {
      const auto pts = split(row[7], ';'), pl = split(row[8], ';');
      for (std::size_t i = 0; i < 2; ++i) {
        const std::size_t p = std::stoul(pts[i]);
        if (std::isnan(first[p])) first[p] = std::stod(pl[i]);
        last[p] = std::stod(pl[i]);
      }
    }
    for (std::size_t p = 0; p < 4; ++p) {
      CAPTURE(p);
      CHECK(last[p] < first[p]);
    }
    // range.csv: every training point, the final design's loss there, how often it was trained on.
    const auto rc = log_rows(run / "range.csv", &header);
    CHECK(header == std::vector<std::string>{"point", "distance_m", "field_x_deg", "field_y_deg", "loss", "steps_trained"});
    REQUIRE(rc.size() == 4);
    const std::vector<std::string> dist{"0.004", "0.008", "0.016", "inf"};
    for (std::size_t p = 0; p < 4; ++p) {
      CHECK(rc[p][0] == std::to_string(p));
      CHECK(rc[p][1] == dist[p]);
      CHECK(std::isfinite(std::stod(rc[p][4])));
      CHECK(std::stod(rc[p][4]) > 0);
      CHECK(std::stoi(rc[p][5]) == trained[p]);
    }
    for (const char* f : {"range.png", "design.h5", "psf.h5", "loss.png"}) CHECK(fs::exists(run / f));
    // The run folder of a range run is refused by the commands that read one point's run.
    const Run ev = qdo_run("eval " + run.string() + " --out " + (dir / "eval").string());
    CHECK(ev.code == 2);
    CHECK(ev.out.find("4 object points") != std::string::npos);
    // --resume with other points or another --points-per-step is refused, naming them; with the
    // run's own it goes on (the run is complete: nothing to add).
    const Run other = qdo_run("design --object-distances 0.004,0.008 --resume --out " + run.string());
    CHECK(other.code == 2);
    CHECK(other.out.find("object_points") != std::string::npos);
    const Run k3 = qdo_run("design --points-per-step 3 --resume --out " + run.string());
    CHECK(k3.code == 2);
    CHECK(k3.out.find("--points-per-step: stored 2, given 3") != std::string::npos);
    const Run same = qdo_run("design " + cfg_arg() + " --object-distances 0.004,0.008,0.016,inf --points-per-step 2 --resume --out " +
                             run.string());
    CAPTURE(same.out);
    CHECK(same.code == 0);
    CHECK(log_rows(run / "log.csv").size() == 16);
    fs::remove_all(dir);
  }

  TEST_CASE("the config route: a --config with object_points designs over them (psf-target: a sharp focus at each depth)") {
    const auto dir = temp_dir("range_cfg");
    SystemConfig c = range_config({0.004, 0.016});
    std::ofstream(dir / "range.json") << config_to_json_text(c) << "\n";
    const Run r = qdo_run("design --config " + (dir / "range.json").string() + " --objective psf-target --target lens:550 "
                          "--points-per-step 2 --mode full --epochs 2 --steps-per-epoch 2 --seed 1 --out " + (dir / "run").string());
    CAPTURE(r.out);
    REQUIRE(r.code == 0);
    const auto rc = log_rows(dir / "run" / "range.csv");
    REQUIRE(rc.size() == 2);
    for (const auto& row : log_rows(dir / "run" / "log.csv")) CHECK(row.at(7) == "0;1");
    // The imaging commands keep one point per configuration (refused naming object_points).
    const Run psf = qdo_run("simulate --config " + (dir / "range.json").string() + " --design lens:550 --scene builtin --out " +
                            (dir / "psf").string());
    CHECK(psf.code == 2);
    CHECK(psf.out.find("object_points") != std::string::npos);
    fs::remove_all(dir);
  }

  TEST_CASE("qdo design refuses bad object points before any work, naming the option and the value") {
    const auto dir = temp_dir("range_refuse");
    const std::string out = " --epochs 2 --steps-per-epoch 1 --out " + (dir / "run").string();
    struct Case {
      std::string args, option, value;
    };
    const double limit = max_field_angle_deg(tiny(), 0.01);
    const std::vector<Case> cases = {
        {"--object-distances 0", "--object-distances", "= 0:"},
        {"--object-distances 1,-2", "--object-distances", "-2"},
        {"--object-distances 1,far", "--object-distances", "far"},
        {"--object-distances 0.01 --field-angles 60", "--field-angles", "60"},
        {"--object-distances 0.01,0.02 --points-per-step 3", "--points-per-step", "[1, 2]"},
        {"--object-distances 0.01,0.02 --points-per-step 0", "--points-per-step", "0"},
        {"--object-distances 0.01,0.02 --decoder resunet", "objective", "object points"},
        // One point given twice is not a range (eval and reconstruct would refuse the run).
        {"--object-distances 1,1", "--object-distances", "1 is given twice"},
        {"--object-distances 0.01 --field-angles 0,0", "--field-angles", "0 is given twice"},
        {"--object-distances 0.01 --field-angles 1:2,0,1:2", "--field-angles", "1:2 is given twice"},
    };
    for (const Case& c : cases) {
      const Run r = qdo_run("design " + cfg_arg() + " " + c.args + out);
      CAPTURE(c.args);
      CAPTURE(r.out);
      CHECK(r.code == 2);
      CHECK(r.out.find(c.option) != std::string::npos);
      CHECK(r.out.find(c.value) != std::string::npos);
      CHECK_FALSE(fs::exists(dir / "run"));
    }
    // A point too near for the DOE grid's sampling trains (the user may want it) but is said to
    // be INACCURATE, as qdo psf says it for that point; a sampled one is not.
    {
      const Run near = qdo_run("design " + cfg_arg() + " --recipe qdo --object-distances 0.0002,0.05 --epochs 1 --steps-per-epoch 1 --out " +
                               (dir / "near").string());
      CAPTURE(near.out);
      CHECK(near.code == 0);
      CHECK(near.out.find("training point 0 of 2 INACCURATE") != std::string::npos);
      CHECK(near.out.find("training point 1 of 2 INACCURATE") == std::string::npos);
      fs::remove_all(dir / "near");
    }
    // The field-angle refusal names the largest angle this configuration samples there.
    const Run wide = qdo_run("design " + cfg_arg() + " --object-distances 0.01 --field-angles 60" + out);
    CHECK(wide.out.find("up to " + to_str(limit) + " deg") != std::string::npos);
    // Points both in the --config file and on the command line.
    std::ofstream(dir / "range.json") << config_to_json_text(range_config({0.01, 0.02})) << "\n";
    const Run both = qdo_run("design --config " + (dir / "range.json").string() + " --object-distances 0.01" + out);
    CHECK(both.code == 2);
    CHECK(both.out.find("--object-distances") != std::string::npos);
    CHECK_FALSE(fs::exists(dir / "run"));
    fs::remove_all(dir);
  }

  // Same seed, same steps, same objective: A trains on three distances every step, B on the middle
  // one alone; both evaluated on the three points (design_point_losses: the fabricated designs on
  // the 2-D path). On this tiny system which of the two has the smaller worst case depends on the
  // seed and the start (measured over 12 runs: A's worst case lower in 8, B's worst / A's worst
  // from 0.47 to 2.3; the landscape is rugged and single-point runs end far apart), so that is
  // printed, not asserted. Asserted: training over the range lowers the mean loss over the range
  // (what it optimises) from the initial design's, at every seed tried here, and range.csv holds
  // what design_point_losses gives.
  TEST_CASE("a design trained over the range lowers the loss over the range; against one trained at the middle point (printed)") {
    const auto dir = temp_dir("range_vs_middle");
    const SystemConfig cfg = range_config({0.004, 0.008, kInf});
    for (std::uint64_t seed : {3u, 4u}) {
      fs::remove_all(dir / "a");
      fs::remove_all(dir / "a0");
      fs::remove_all(dir / "b");
      DesignRunOptions a = range_run((dir / "a").string(), cfg, 3);
      DesignRunOptions b = range_run((dir / "b").string(), range_config({0.008}), 1);
      for (DesignRunOptions* o : {&a, &b}) {
        o->design.mode = DesignMode::Full;
        o->design.seed = seed;
        o->epochs = 20;
        o->design.steps_per_epoch = 10;
        o->design.t0_epochs = 2;
        o->design.t1_epochs = 16;
        o->checkpoint_every = 100;
      }
      DesignRunOptions a0 = a;  // the initial design: a run stopped before its first step
      a0.out = (dir / "a0").string();
      a0.max_steps = 0;
      run_design(runtime(), a0, false);
      const DesignRunResult ra = run_design(runtime(), a, false);
      run_design(runtime(), b, false);
      const std::vector<double> l0 = design_point_losses(runtime(), a, read_design(a0.out + "/design.h5").height_m);
      const std::vector<double> la = design_point_losses(runtime(), a, read_design(a.out + "/design.h5").height_m);
      const std::vector<double> lb = design_point_losses(runtime(), a, read_design(b.out + "/design.h5").height_m);
      REQUIRE(la.size() == 3);
      REQUIRE(lb.size() == 3);
      CHECK(la == ra.point_losses);  // what range.csv holds
      const auto mean = [](const std::vector<double>& v) { return (v[0] + v[1] + v[2]) / 3; };
      const auto worst = [](const std::vector<double>& v) { return *std::max_element(v.begin(), v.end()); };
      for (std::size_t p = 0; p < 3; ++p)
        MESSAGE("seed " << seed << ", point " << p << " (" << cfg.object_points[p].distance_m << " m): initial " << l0[p]
                        << ", trained over the range " << la[p] << ", trained at 0.008 m " << lb[p]);
      MESSAGE("seed " << seed << ": mean over the range " << mean(l0) << " -> " << mean(la) << " (range), " << mean(lb)
                      << " (middle); worst " << worst(l0) << " -> " << worst(la) << " (range), " << worst(lb) << " (middle)");
      CHECK(mean(la) < mean(l0));
    }
    fs::remove_all(dir);
  }
}
