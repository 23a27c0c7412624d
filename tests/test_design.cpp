// Design optimisation: a few steps lower the objective, determinism, exactly L fabricated heights,
// the STE gradient, the device-resident objective path, the radial PSF path. The end-to-end
// gradients in every mode against finite differences (float64 kernels) are rows of the adjoint
// table (tests/adjoint_table.hpp), built here and run by the `adjoint` suite.
#include <cmath>
#include <memory>
#include <random>
#include <set>
#include <string>

#include "adjoint_table.hpp"
#include "common.hpp"
#include "qdo/physics/adjoint.hpp"
#include "qdo/design/design.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/decode/wiener.hpp"
#include "qdo/decode/wiener_device.hpp"

using namespace qdo;
using namespace qdo::test;

namespace {

struct Fixture {
  SystemConfig cfg = tiny_config(32, 3);
  Precision prec = runtime().has_fp64() ? Precision::F64 : Precision::F32;
  RealStack target;
  Fixture() {
    Simulator s(runtime(), cfg, prec);
    s.set_heights(lens_design(cfg, 500));
    s.compute_psf();
    target = s.psf_sensor();
  }
};

DesignOptions options(DesignMode m) {
  DesignOptions o;
  o.mode = m;
  o.parameterization = Parameterization::Radial;
  o.quantizer.levels = 4;
  o.steps_per_epoch = 2;
  o.t0_epochs = 1;
  o.t1_epochs = 5;
  o.seed = 3;
  o.psf_path = PsfPath::TwoD;  // the cases below check the 2-D path; the radial path has its own cases
  return o;
}


}  // namespace

// End-to-end gradients (the design loop's, through the device in float64) against central
// differences, in every mode, on the 2-D and the radial PSF paths: the loss as a function of the
// weights w (and, for QDO+A, of the offsets a_1..a_3) at a mid-schedule state (0 < alpha < 1).
// Quantized modes are piecewise smooth; a step of 1e-7 in w (0.08 pm) crosses a level boundary
// with negligible probability. Within 1e-5 of the entry plus 1e-9.
QDO_ADJOINT_ROWS(design, "design loop") {
  REQUIRE(runtime().has_fp64());  // gradient checks run in double (PoCL has fp64)
  const auto f = std::make_shared<const Fixture>();
  const auto obj = std::make_shared<const PsfObjective>(psf_target_objective(f->target));
  struct Run {
    Simulator sim;
    Designer d;
    DesignState s;
    Run(const Fixture& fx, const DesignOptions& o) : sim(runtime(), fx.cfg, fx.prec), d(sim, o) {}
  };
  std::vector<Stage> rows;
  const auto add = [&](DesignMode m, bool radial) {
    DesignOptions o = options(m);
    if (radial) o.psf_path = PsfPath::Radial;
    const auto run = std::make_shared<Run>(*f, o);
    if (radial) REQUIRE(run->d.uses_radial());
    run->s = run->d.initial_state(start_params(f->cfg, 5));
    run->s.step = 6;  // mid-schedule: 0 < alpha < 1
    run->s.offsets = {0.0, 0.3, -0.2, 0.1};
    const std::string path = radial ? "radial" : "2-D";
    const auto tolerances = [](Stage& st, double step) {
      st.fd_tol = 0;
      st.fd_step = step;
      st.dir_rel = st.probe_rel = 1e-5;
      st.dir_abs = st.probe_abs = 1e-9;
      st.g0 = {1.0};
    };
    Stage w("design " + to_string(m) + ", " + path + " path: weights -> loss", run->s.w.size(), 1);
    w.forward = [run, obj](const std::vector<double>& x) {
      DesignState st = run->s;
      st.w = x;
      return std::vector<double>{run->d.gradient(st, *obj).report.loss};
    };
    w.vjp = [run, obj](const std::vector<double>& x, const std::vector<double>& g) {
      DesignState st = run->s;
      st.w = x;
      std::vector<double> gw = run->d.gradient(st, *obj).g_w;
      for (double& v : gw) v *= g[0];
      return gw;
    };
    w.x0 = run->s.w;
    tolerances(w, 1e-7);
    w.probes = radial ? std::vector<std::size_t>{0, 2, 5, 9, 13} : std::vector<std::size_t>{1, 4, 7, 10, 13};
    rows.push_back(w);
    if (m != DesignMode::QDOA) return;
    Stage a("design " + to_string(m) + ", " + path + " path: offsets a_1..a_3 -> loss", 3, 1);
    a.forward = [run, obj](const std::vector<double>& x) {
      DesignState st = run->s;
      st.offsets = {0.0, x[0], x[1], x[2]};
      return std::vector<double>{run->d.gradient(st, *obj).report.loss};
    };
    a.vjp = [run, obj](const std::vector<double>& x, const std::vector<double>& g) {
      DesignState st = run->s;
      st.offsets = {0.0, x[0], x[1], x[2]};
      const std::vector<double> go = run->d.gradient(st, *obj).g_offsets;
      return std::vector<double>{go[1] * g[0], go[2] * g[0], go[3] * g[0]};
    };
    a.x0 = {0.3, -0.2, 0.1};
    tolerances(a, 1e-6);
    a.probes = {0, 1, 2};
    rows.push_back(a);
  };
  for (DesignMode m : {DesignMode::Full, DesignMode::DO, DesignMode::QDO, DesignMode::QDOA}) add(m, false);
  for (DesignMode m : {DesignMode::Full, DesignMode::QDO, DesignMode::QDOA}) add(m, true);
  return rows;
}

TEST_SUITE("design") {
  TEST_CASE("STE: the gradient is that of the full-precision chain evaluated at the quantized heights") {
    Fixture f;
    const PsfObjective obj = psf_target_objective(f.target);
    // STE: the gradient is that of the full-precision chain evaluated at the quantized heights.
    Simulator sim(runtime(), f.cfg, f.prec);
    Designer d(sim, options(DesignMode::STE));
    const DesignState s = d.initial_state(start_params(f.cfg, 6));
    const auto g = d.gradient(s, obj);
    const Map2D hq = d.fabricated_heights(s);
    sim.set_heights(hq);
    sim.compute_psf();
    RealStack gp;
    obj(sim.psf_sensor(), gp);
    std::vector<double> want = ref::expand_parameters_vjp(Parameterization::Radial, d.params_m(s), f.cfg.n, f.cfg.h_max_m(),
                                                          sim.psf_sensor_vjp(gp));
    for (double& v : want) v *= f.cfg.h_max_m() / 2;
    CHECK(diff(g.g_w, want).rel_l2 <= 1e-12);
  }

  TEST_CASE("a few optimiser steps lower the objective; runs are deterministic; L fabricated heights") {
    Fixture f;
    const PsfObjective obj = psf_target_objective(f.target);
    for (DesignMode m : {DesignMode::Full, DesignMode::QDOA}) {
      CAPTURE(to_string(m));
      Simulator sim(runtime(), f.cfg, f.prec);
      DesignOptions o = options(m);
      o.lr_optics = 0.05;
      o.height_noise_m = m == DesignMode::QDOA ? 20e-9 : 0.0;
      Designer d(sim, o);
      DesignState s = d.initial_state(start_params(f.cfg, 7));
      const double first = d.step(s, obj).loss;
      double last = first;
      for (int i = 0; i < 15; ++i) last = d.step(s, obj).loss;
      CAPTURE(first);
      CAPTURE(last);
      CHECK(last < 0.9 * first);
      // Same seed, same device and build: bit-identical state.
      Simulator sim2(runtime(), f.cfg, f.prec);
      Designer d2(sim2, o);
      DesignState s2 = d2.initial_state(start_params(f.cfg, 7));
      for (int i = 0; i < 16; ++i) d2.step(s2, obj);
      CHECK(s2.w == s.w);
      CHECK(s2.offsets == s.offsets);
      if (m == DesignMode::QDOA) {
        const Map2D fab = d.fabricated_heights(s);
        const std::set<double> distinct(fab.data.begin(), fab.data.end());
        const auto table = d.quantizer(s).level_heights_m(f.cfg.h_max_m());
        CHECK(distinct.size() <= 4);
        for (double v : distinct) CHECK(std::find(table.begin(), table.end(), v) != table.end());
      }
    }
  }

  TEST_CASE("the device-resident objective path gives the host path's numbers, 2-D and radial") {
    // Designer::gradient with a DevicePsfObjective: the PSF, the Wiener objective and the PSF
    // adjoint stay on the device. Against the same DeviceObjective called through host copies
    // (float32 survives the double round trip exactly), every step must be bit-identical.
    Fixture f;
    std::mt19937_64 rng(11);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    std::vector<RealStack> scenes;
    for (int k = 0; k < 4; ++k) {
      RealStack sc(f.cfg.bands, 12, 12);
      for (double& v : sc.data) v = 0.2 + 0.8 * u(rng);
      scenes.push_back(std::move(sc));
    }
    const wiener::SpectralPrior prior = wiener::estimate_prior(scenes, 4);
    const Eigen::MatrixXd srf = sensor_response(f.cfg);
    const std::size_t s_px = f.cfg.sensor_size_px();
    for (Precision p : device_precisions(runtime())) {
      if (p == Precision::F32 && !runtime().has_fp64()) continue;  // the objective's f64 accumulation
      for (DesignMode m : {DesignMode::Full, DesignMode::QDOA}) {
        CAPTURE(to_string(p));
        CAPTURE(to_string(m));
        wiener::DeviceObjective dev(runtime(), p, srf, prior, 1e-2, s_px);
        const PsfObjective host = [&dev](const RealStack& psf, RealStack& g) {
          wiener::PsfObjective r = dev.expected(psf);
          g = std::move(r.grad_psf);
          return r.value;
        };
        const DevicePsfObjective resident = [&dev](const cl::Buffer& psf, cl::Buffer& g) { return dev.expected(psf, g); };
        int host_calls = 0;
        const PsfObjective counting = [&](const RealStack& psf, RealStack& g) {
          ++host_calls;
          return host(psf, g);
        };
        DesignOptions o = options(m);
        o.height_noise_m = m == DesignMode::QDOA ? 20e-9 : 0.0;
        Simulator sim_a(runtime(), f.cfg, p), sim_b(runtime(), f.cfg, p);
        Designer da(sim_a, o), db(sim_b, o);
        DesignState sa = da.initial_state(start_params(f.cfg, 5)), sb = db.initial_state(start_params(f.cfg, 5));
        for (int i = 0; i < 4; ++i) {
          const StepReport ra = da.step(sa, host);
          const StepReport rb = db.step(sb, counting, &resident);
          CHECK(ra.loss == rb.loss);
          CHECK(ra.loss_aq == rb.loss_aq);
        }
        CHECK(host_calls == 0);
        CHECK(sa.w == sb.w);
        CHECK(sa.offsets == sb.offsets);
        // The radial path likewise: its device form against the host form, step for step.
        DesignOptions orad = o;
        orad.psf_path = PsfPath::Radial;
        Simulator sim_r(runtime(), f.cfg, p), sim_r2(runtime(), f.cfg, p);
        Designer dr(sim_r, orad), dr2(sim_r2, orad);
        REQUIRE(dr.uses_radial());
        DesignState sr = dr.initial_state(start_params(f.cfg, 5)), sr2 = dr2.initial_state(start_params(f.cfg, 5));
        for (int i = 0; i < 4; ++i) CHECK(dr.step(sr, host).loss == dr2.step(sr2, counting, &resident).loss);
        CHECK(host_calls == 0);
        CHECK(sr.w == sr2.w);
        CHECK(sr.offsets == sr2.offsets);
      }
    }
    // The simulator's device-gradient adjoint equals the host form, and refuses a short buffer.
    for (Precision p : device_precisions(runtime())) {
      Simulator sim(runtime(), f.cfg, p);
      sim.set_heights(lens_design(f.cfg, 520));
      sim.compute_psf();
      RealStack g(f.cfg.bands, s_px, s_px);
      for (double& v : g.data) v = u(rng) - 0.5;
      const std::size_t rsz = p == Precision::F64 ? 8 : 4;
      cl::Buffer gbuf(runtime().context(), CL_MEM_READ_WRITE, g.size() * rsz);
      runtime().write_reals(gbuf, g.data.data(), g.size(), p);
      RealStack g_rounded(g.planes, g.rows, g.cols);  // what the device holds (float32 rounding)
      runtime().read_reals(gbuf, g_rounded.data.data(), g.size(), p);
      const Map2D want = sim.psf_sensor_vjp(g_rounded);
      CHECK(sim.psf_sensor_vjp(gbuf).data == want.data);
      std::vector<double> after(g.size());
      runtime().read_reals(gbuf, after.data(), g.size(), p);
      CHECK(after == g_rounded.data);  // the input buffer is not modified
      cl::Buffer small(runtime().context(), CL_MEM_READ_WRITE, rsz);
      CHECK_THROWS_WITH_AS(sim.psf_sensor_vjp(small), doctest::Contains("g_psf_sensor buffer"), InputError);
    }
  }

  TEST_CASE("radial PSF path: auto selection, rejection, option strings") {
    Fixture f;
    Simulator sim(runtime(), f.cfg, f.prec);
    DesignOptions o = options(DesignMode::Full);
    o.psf_path = PsfPath::Auto;
    CHECK(Designer(sim, o).uses_radial());
    o.parameterization = Parameterization::Quad;
    CHECK_FALSE(Designer(sim, o).uses_radial());
    o.psf_path = PsfPath::Radial;
    CHECK_THROWS_AS((void)Designer(sim, o).uses_radial(), InputError);
    o.parameterization = Parameterization::Radial;
    o.psf_path = PsfPath::TwoD;
    CHECK_FALSE(Designer(sim, o).uses_radial());
    for (PsfPath p : {PsfPath::Auto, PsfPath::TwoD, PsfPath::Radial}) CHECK(psf_path_from_string(to_string(p)) == p);
    CHECK_THROWS_AS(psf_path_from_string("3d"), InputError);
    o.psf_path = PsfPath::Radial;
    o.radial.node_oversample = 0;
    CHECK_THROWS_AS((void)Designer(sim, o).uses_radial(), InputError);
  }

  TEST_CASE("radial PSF path: the full-precision gradient is the engine's ring gradient times h_max / 2") {
    Fixture f;
    REQUIRE(f.prec == Precision::F64);
    const PsfObjective obj = psf_target_objective(f.target);
    Simulator sim(runtime(), f.cfg, f.prec);
    DesignOptions o = options(DesignMode::Full);
    o.psf_path = PsfPath::Radial;
    Designer d(sim, o);
    REQUIRE(d.uses_radial());
    DesignState s = d.initial_state(start_params(f.cfg, 5));
    s.step = 6;
    s.offsets = {0.0, 0.3, -0.2, 0.1};
    const auto g = d.gradient(s, obj);
    // Full precision: dL/dw_k = dL/dh_k (the engine's ring gradient) * h_max / 2 (w inside (-1, 1)).
    RadialEngine& e = *d.radial_engine();
    const auto rings = ring_heights_of_map(d.training_heights(s));
    e.compute_psf(rings);
    RealStack gp;
    obj(e.psf_sensor(), gp);
    std::vector<double> want = e.psf_sensor_vjp(gp);
    for (double& v : want) v *= f.cfg.h_max_m() / 2;
    CHECK(diff(g.g_w, want).rel_l2 <= 1e-12);
  }

  TEST_CASE("radial PSF path: steps lower the objective, deterministic with per-ring height noise, close to 2-D") {
    Fixture f;
    const PsfObjective obj = psf_target_objective(f.target);
    DesignOptions o = options(DesignMode::QDOA);
    o.psf_path = PsfPath::Radial;
    o.lr_optics = 0.05;
    o.height_noise_m = 20e-9;
    Simulator sim(runtime(), f.cfg, f.prec), sim2(runtime(), f.cfg, f.prec);
    Designer d(sim, o), d2(sim2, o);
    DesignState s = d.initial_state(start_params(f.cfg, 7)), s2 = d2.initial_state(start_params(f.cfg, 7));
    const double first = d.step(s, obj).loss;
    double last = first;
    for (int i = 0; i < 15; ++i) last = d.step(s, obj).loss;
    for (int i = 0; i < 16; ++i) d2.step(s2, obj);
    CAPTURE(first);
    CAPTURE(last);
    CHECK(last < 0.9 * first);
    CHECK(s2.w == s.w);
    CHECK(s2.offsets == s.offsets);
    // The radial and 2-D gradients of the same state point the same way (the engines differ by the
    // 2-D path's discretisation, a few per cent of the PSF at this size).
    DesignOptions o2 = o;
    o2.psf_path = PsfPath::TwoD;
    o.height_noise_m = o2.height_noise_m = 0;
    Simulator sim3(runtime(), f.cfg, f.prec), sim4(runtime(), f.cfg, f.prec);
    Designer dr(sim3, o), d2d(sim4, o2);
    const DesignState st = dr.initial_state(start_params(f.cfg, 8));
    const auto gr = dr.gradient(st, obj).g_w, g2 = d2d.gradient(st, obj).g_w;
    double ab = 0, aa = 0, bb = 0;
    for (std::size_t k = 0; k < gr.size(); ++k) {
      ab += gr[k] * g2[k];
      aa += gr[k] * gr[k];
      bb += g2[k] * g2[k];
    }
    MESSAGE("cosine(radial gradient, 2-D gradient) = " << ab / std::sqrt(aa * bb));
    CHECK(ab / std::sqrt(aa * bb) > 0.8);
  }

  TEST_CASE("height noise on the 2-D path: each step sees its own seeded draw, the same for the same seed and step") {
    Fixture f;
    const PsfObjective obj = psf_target_objective(f.target);
    DesignOptions o = options(DesignMode::QDOA);
    o.psf_path = PsfPath::TwoD;
    o.height_noise_m = 20e-9;
    DesignOptions quiet = o;
    quiet.height_noise_m = 0;
    Simulator sa(runtime(), f.cfg, f.prec), sb(runtime(), f.cfg, f.prec), sc(runtime(), f.cfg, f.prec);
    Designer noisy(sa, o), again(sb, o), clean(sc, quiet);
    const DesignState st = noisy.initial_state(start_params(f.cfg, 9));
    const Designer::Gradient gn = noisy.gradient(st, obj), ga = again.gradient(st, obj), gc = clean.gradient(st, obj);
    // The same seed and step draw the same noise; without noise the loss is another number.
    CHECK(gn.report.loss == ga.report.loss);
    CHECK(gn.g_w == ga.g_w);
    CAPTURE(gn.report.loss);
    CAPTURE(gc.report.loss);
    CHECK(std::fabs(gn.report.loss - gc.report.loss) > 1e-9 * std::fabs(gc.report.loss));
    // Another step draws another sample.
    DesignState st2 = st;
    st2.step = st.step + 1;
    CHECK(noisy.gradient(st2, obj).report.loss != gn.report.loss);
  }
}
