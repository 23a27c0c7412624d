// bench_fit: one as-built fit (include/qdo/asbuilt/fit.hpp, `qdo fit`) with the time per stage.
//
// The case: a 4-level lens for 550 nm on --preset (wrapped levels), its level depths off by +15, -20, +10 nm, z off
// by 1.6 % and the relief offset by (0.3, -0.2) DOE pixels, the PSF stack simulated through it
// with Gaussian noise of --noise (default 0.1 %) of each band's peak per pixel; fitted with levels,z,offset in float64.
// Reports (medians of --repeats after --warmup runs, with half the min-max spread beside each):
//   PSF evaluation    heights -> bands x S x S model stack on the same simulator (the baseline unit)
//   new simulator     a Simulator for a new (z, d) and its first PSF: what a distance's difference costs
//   adjoint gradient  one PSF evaluation + psf_sensor_vjp + the shifts' and levels' chain
//   Jacobian          2 p central-difference evaluations (the z columns rebuild the simulator)
//   writing           fit.h5-sized HDF5 (three stacks) + design.h5
//   whole fit         fit_as_built, once from the centroid start alone and once with the default
//                     starts, each with its own per-stage split, iterations and counts
//   whole fit on the model window   the same truth simulated and fitted on the window qdo fit
//                     uses by default (--model-padding auto, option_inputs.hpp), once
//   whole fit with overlay      the same stack and default starts with levels,z,offset,overlay
//                     (each mask's own overlay, fit.hpp; the truth has none, so the loss's minimum in
//                     each overlay lies on its kink): what the overlay's 4 parameters cost, once
//   whole fit from raw frames   the truth's stack (no added noise) through a simulated sweep
//                     (capture_psf_sweep: RGGB, 12 bits, read noise 2 DN, 20000 electrons at full
//                     scale, one frame per band), reduced (reduce_psf_frames) and fitted on the
//                     frames themselves (fit_as_built_raw, fit_raw.hpp), once
// Speed is never asserted; this program only reports.
//
// Usage: bench_fit [--preset small|paper] [--repeats 3] [--warmup 1] [--noise 1e-3] [--out FILE.md]
// Device: QDO_DEVICE (see runtime.hpp); kernel disk cache: QDO_CACHE_DIR.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/asbuilt/fit.hpp"
#include "qdo/asbuilt/fit_raw.hpp"
#include "qdo/design/option_inputs.hpp"
#include "qdo/design/psf_spec.hpp"
#include "qdo/asbuilt/psf_sweep_capture.hpp"
#include "qdo/physics/calibrate.hpp"
#include "qdo/data/io.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/simulator.hpp"

#include "bench_util.hpp"

using namespace qdo;
using qdo::bench::fmt;
using qdo::bench::Timing;
using qdo::bench::time_it;

namespace {

std::string row(const std::string& stage, const Timing& t, double unit) {
  return "| " + stage + " | " + fmt("%.3f", t.median) + " +- " + fmt("%.3f", 0.5 * (t.max - t.min)) + " | " + fmt("%.1f", t.median / unit) +
         " | " + std::to_string(t.runs) + " |\n";
}

}  // namespace

int main(int argc, char** argv) try {
  std::string preset = "small", out;
  int repeats = 3, warmup = 1;
  double noise = 1e-3;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    const auto next = [&]() -> std::string {
      if (i + 1 >= argc) throw InputError("bench_fit: " + a + " needs a value");
      return argv[++i];
    };
    if (a == "--preset")
      preset = next();
    else if (a == "--repeats")
      repeats = std::stoi(next());
    else if (a == "--warmup")
      warmup = std::stoi(next());
    else if (a == "--noise")
      noise = std::stod(next());
    else if (a == "--out")
      out = next();
    else
      throw InputError("bench_fit: unknown option " + a + " (--preset, --repeats, --warmup, --out)");
  }
  if (repeats < 1 || warmup < 0) throw InputError("bench_fit: --repeats >= 1, --warmup >= 0");
  const SystemConfig cfg = preset_config(preset);
  Runtime rt;
  Quantizer q;
  q.levels = 4;
  q.placement = Placement::Wrapped;  // levels 0, h/4, h/2, 3h/4: a 550 nm lens uses all four
  Design d;
  d.height_m = quantize_heights(lens_design(cfg, 550), cfg.h_max_m(), q);
  d.pitch_m = cfg.pitch_m;
  d.levels_m = q.level_heights_m(cfg.h_max_m());
  const std::vector<std::string> params = {"levels", "z", "offset"};
  AsBuiltModel model(rt, cfg, Precision::F64, d, params);
  const std::vector<double> truth = {d.levels_m[1] + 15e-9, d.levels_m[2] - 20e-9, d.levels_m[3] + 10e-9,
                                     cfg.sensor_distance_m * 1.016, 0.3 * cfg.pitch_m, -0.2 * cfg.pitch_m};
  // Gaussian noise of `noise` x each band's peak per pixel, seed 1 (bands x S x S, in place).
  const auto add_noise = [noise](RealStack& st) {
    std::mt19937_64 rng(1);
    std::normal_distribution<double> n(0.0, 1.0);
    const std::size_t plane = st.rows * st.cols;
    for (std::size_t b = 0; b < st.planes; ++b) {
      double peak = 0;
      for (std::size_t i = 0; i < plane; ++i) peak = std::max(peak, st.data[b * plane + i]);
      for (std::size_t i = 0; i < plane; ++i) st.data[b * plane + i] += noise * peak * n(rng);
    }
  };
  RealStack meas = model.evaluate(truth);
  add_noise(meas);
  const std::vector<double> theta = model.design_values();
  const double loss_truth = model.loss(truth, meas), loss_design = model.loss(theta, meas);
  std::printf("bench_fit: preset %s (N = %zu, %zu bands, S = %zu), device %s, float64, %d repeats after %d warm-up\n", preset.c_str(),
              cfg.n, cfg.bands, cfg.sensor_size_px(), rt.info().name.c_str(), repeats, warmup);
  (void)model.evaluate(theta);  // the model's simulator at the design's z
  const Timing psf = time_it(warmup, repeats, [&] { (void)model.evaluate(theta); });
  // A new simulator is set up lazily: its cost shows in its first PSF.
  const Map2D h = model.heights(theta);
  const Timing build = time_it(warmup, repeats, [&] {
    Simulator s(rt, cfg, Precision::F64);
    s.set_heights(h);
    s.compute_psf();
    (void)s.psf_sensor();
  });
  std::vector<double> g;
  const Timing grad = time_it(warmup, repeats, [&] { (void)model.adjoint_gradient(theta, meas, g); });
  const Timing jac = time_it(std::min(warmup, 1), repeats, [&] { (void)model.jacobian(theta); });
  const std::string dir = (std::filesystem::temp_directory_path() / ("qdo_bench_fit_" + std::to_string(std::random_device{}()))).string();
  std::filesystem::create_directories(dir);
  const std::size_t s = cfg.sensor_size_px();
  const Timing write = time_it(warmup, repeats, [&] {
    std::vector<H5Dataset> ds;
    for (const char* n : {"/psf_fit", "/psf_measured", "/psf_design"}) ds.push_back({n, {cfg.bands, s, s}, meas.data, {}, {}});
    h5_write(dir + "/fit.h5", ds);
    write_design(dir + "/design.h5", d);
  });
  std::filesystem::remove_all(dir);
  FitOptions opt;
  opt.parameters = params;
  opt.progress = [](const std::string& l) { std::fprintf(stderr, "%s\n", l.c_str()); };
  // The whole fit twice: from the centroid start alone (--lateral-starts 1), then with the default
  // starts (the offset scans and the short fits from starts in different basins).
  opt.lateral_starts = 1;
  auto t0 = qdo::bench::Clock::now();
  const FitResult r1 = fit_as_built(rt, cfg, Precision::F64, d, meas, opt);
  const double whole1 = qdo::bench::seconds_since(t0);
  opt.lateral_starts = FitOptions{}.lateral_starts;
  t0 = qdo::bench::Clock::now();
  const FitResult r = fit_as_built(rt, cfg, Precision::F64, d, meas, opt);
  const double whole = qdo::bench::seconds_since(t0);
  // The same with each mask's own overlay.
  FitOptions with_overlay = opt;
  with_overlay.parameters.push_back("overlay");
  t0 = qdo::bench::Clock::now();
  const FitResult ro = fit_as_built(rt, cfg, Precision::F64, d, meas, with_overlay);
  const double whole_overlay = qdo::bench::seconds_since(t0);
  double worst_level_shift_nm = 0, worst_overlay_um = 0;
  for (const FitValue& v : ro.values) {
    if (v.name.rfind("level", 0) == 0)
      for (const FitValue& w : r.values)
        if (w.name == v.name) worst_level_shift_nm = std::max(worst_level_shift_nm, std::fabs(v.value - w.value) * 1e9);
    if (v.name.size() > 2 && v.name[0] == 'o') worst_overlay_um = std::max(worst_overlay_um, std::fabs(v.value) * 1e6);
  }
  // The same fit on the model window qdo fit uses by default (--model-padding auto: the transfer
  // function sampled in every band up to 5 % beyond z), on the truth simulated with that window.
  SystemConfig wcfg = cfg;
  (void)apply_model_padding(wcfg, TextOptions{}, cfg.sensor_distance_m);  // qdo fit's own rule
  RealStack wmeas = AsBuiltModel(rt, wcfg, Precision::F64, d, params).evaluate(truth);
  add_noise(wmeas);
  t0 = qdo::bench::Clock::now();
  const FitResult rw = fit_as_built(rt, wcfg, Precision::F64, d, wmeas, opt);
  const double whole_window = qdo::bench::seconds_since(t0);
  // The whole fit from raw frames: a sweep of the true camera through a raw sensor, the window at
  // the sweep's axis (no registration to fit), the same parameters.
  SystemConfig rcfg = cfg;
  rcfg.cfa = Cfa::RGGB;
  rcfg.bit_depth = 12;
  rcfg.black_level_dn = 64;
  rcfg.read_noise_sigma = 0.0005;
  rcfg.full_well_photons = 20000;
  const std::string raw_dir = dir + "_raw";
  std::filesystem::create_directories(raw_dir);
  PsfInput in;
  in.spec.kind = PsfSpec::Kind::File;
  in.spec.value = "the true camera";
  in.stack = model.evaluate(truth);
  PsfSweepCaptureSpec sweep;
  sweep.frame_px = s + 32;
  const PsfSweepCaptureResult swept = capture_psf_sweep(rt, rcfg, Precision::F64, in, sweep, raw_dir);
  CalibrationOptions window;
  window.centre = CentreRule::given;
  window.centre_row = swept.geometry.centre_row;
  window.centre_col = swept.geometry.centre_col;
  t0 = qdo::bench::Clock::now();
  const RawPsfWindows windows = reduce_psf_frames(rcfg, raw_dir + "/frames", raw_dir + "/darks", window);
  const double reduce_s = qdo::bench::seconds_since(t0);
  t0 = qdo::bench::Clock::now();
  const RawFitResult rr = fit_as_built_raw(rt, rcfg, Precision::F64, d, windows, opt);
  const double whole_raw = qdo::bench::seconds_since(t0);
  std::filesystem::remove_all(raw_dir);

  std::ostringstream md;
  md << "bench_fit: preset " << preset << " (N = " << cfg.n << ", " << cfg.bands << " bands, S = " << s << "), " << rt.info().name
     << ", float64; fit levels,z,offset (6 parameters)\n\n";
  md << "| stage | median s (+- half spread) | in PSF evaluations | runs |\n|---|---|---|---|\n";
  md << row("PSF evaluation (baseline)", psf, psf.median);
  md << row("new simulator + its first PSF (a new z or d)", build, psf.median);
  md << row("adjoint gradient (PSF + VJP + chain)", grad, psf.median);
  md << row("Jacobian (12 central differences, 2 simulator builds)", jac, psf.median);
  md << row("writing fit.h5 stacks + design.h5", write, psf.median);
  md << "\nwhole fit from the centroid start alone, once: " << fmt("%.2f", whole1) << " s, " << r1.iterations << " iterations, "
     << r1.times.psf_evaluations << " PSF evaluations, loss " << fmt("%.4e", r1.loss_final) << "\n";
  md << "whole fit with the default starts, once: " << fmt("%.2f", whole) << " s, " << r.iterations << " iterations (" << (r.converged ? "converged" : "limit")
     << "): PSF " << fmt("%.2f", r.times.psf_s) << " s, adjoint " << fmt("%.2f", r.times.vjp_s) << " s, Jacobian "
     << fmt("%.2f", r.times.jacobian_s) << " s, solve " << fmt("%.3f", r.times.solve_s) << " s; " << r.times.psf_evaluations
     << " PSF evaluations, " << r.times.vjps << " adjoints, " << r.times.simulators_built << " simulators\n";
  md << "whole fit with the default starts on the model window qdo fit uses by default (padding " << wcfg.padding_px << " px, window "
     << PropagationGeometry::from_config(wcfg).m << " against " << PropagationGeometry::from_config(cfg).m
     << "; the truth simulated with it), once: " << fmt("%.2f", whole_window) << " s, " << rw.iterations << " iterations ("
     << (rw.converged ? "converged" : "limit") << "), " << rw.times.psf_evaluations << " PSF evaluations; worst level error "
     << fmt("%.3f", [&] {
          double w = 0;
          for (std::size_t k = 0; k < 3; ++k) w = std::max(w, std::fabs(rw.values[k].value - truth[k]) * 1e9);
          return w;
        }())
     << " nm\n";
  md << "whole fit with overlay (levels,z,offset,overlay: " << ro.values.size() << " parameters), once: " << fmt("%.2f", whole_overlay)
     << " s, " << ro.iterations << " iterations (" << (ro.converged ? "converged" : "limit") << "), " << ro.times.psf_evaluations
     << " PSF evaluations; loss " << fmt("%.4e", ro.loss_final) << "; levels within " << fmt("%.3f", worst_level_shift_nm)
     << " nm of the fit without overlay, overlays within " << fmt("%.4f", worst_overlay_um) << " um of 0 (the truth)\n";
  md << "whole fit from raw frames (12-bit RGGB sweep, read noise 2 DN, 20000 electrons), once: reading and reducing "
     << fmt("%.2f", reduce_s) << " s, fit " << fmt("%.2f", whole_raw) << " s, " << rr.fit.iterations << " iterations ("
     << (rr.fit.converged ? "converged" : "limit") << "), " << rr.fit.times.psf_evaluations
     << " PSF evaluations, reduced chi^2 " << fmt("%.3f", rr.fit.residual_sigma * rr.fit.residual_sigma) << "\n";
  md << "loss: design " << fmt("%.4e", loss_design) << ", truth " << fmt("%.4e", loss_truth) << ", fit " << fmt("%.4e", r.loss_final)
     << "\nrecovered:";
  for (std::size_t k = 0; k < truth.size(); ++k) {
    const FitValue& v = r.values[k];
    const double u = v.name == "z" || v.name == "dx" || v.name == "dy" ? 1e6 : 1e9;
    md << " " << v.name << " " << fmt("%.3f", v.value * u) << " +- " << fmt("%.3f", v.sigma * u) << " (true " << fmt("%.3f", truth[k] * u)
       << ")";
  }
  md << "  [units: nm for levels, um for z, dx, dy]\n";
  std::fputs(md.str().c_str(), stdout);
  if (!out.empty()) std::ofstream(out) << md.str();
  return 0;
} catch (const std::exception& e) {
  std::fprintf(stderr, "bench_fit: %s\n", e.what());
  return 2;
}
