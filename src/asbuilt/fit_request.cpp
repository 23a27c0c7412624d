// qdo fit as a library call (fit_request.hpp): the options read and every input checked, then the
// fit and its report.
#include "qdo/asbuilt/fit_request.hpp"

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <utility>

#include "qdo/asbuilt/calibration_outputs.hpp"
#include "qdo/design/option_inputs.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/strprintf.hpp"
#include "qdo/runtime/util.hpp"

namespace qdo {

FitRequest fit_request_from_options(const TextOptions& a) {
  FitRequest q;
  q.cfg = config_from_options(a);
  const SystemConfig& cfg = q.cfg;
  // The data: a calibrated stack (--psf) or the raw frames (--frames with --darks), one of them.
  const bool raw = a.has("frames");
  q.frames = a.get("frames");
  q.darks = a.get("darks");
  q.white = a.get("white");
  if (raw && a.has("psf"))
    reject("--psf", a.get("psf"),
           "either --psf (a calibrated PSF stack) or --frames with --darks (the raw point-source frames), not both");
  if (!raw && !a.has("psf"))
    reject("--psf", "(missing)",
           "the measured PSF stack: psf.h5 as qdo calibrate or qdo psf writes it; or the raw point-source frames: "
           "--frames DIR --darks DIR");
  if (raw && !a.has("darks"))
    reject("--darks", "(missing)",
           "the folder of dark frames taken as the --frames were (same exposure and temperature)");
  for (const char* k : {"darks", "white", "centre", "hot-sigma", "min-snr", "min-response"})
    if (!raw && a.has(k))
      reject(std::string("--") + k, a.get(k),
             "only with --frames (the raw frames); a --psf stack is calibrated already");
  frame_reduction_from_options(a, q.calibration);  // the frames reduced as qdo calibrate reduces them
  FitOptions& opt = q.options;
  if (a.has("fit") && a.get("fit").find_first_not_of(" ,") == std::string::npos)
    reject("--fit", a.get("fit"),
           "one or more of levels, masks, scale, z, d, offset, shift, overlay, aperture (omit --fit for the default set)");
  opt.max_iterations = parse_int("--iterations", a.get("iterations", "30"), 1, 1000);
  opt.tolerance = parse_double("--tolerance", a.get("tolerance", "1e-7"), 0, 1, "", false);
  q.precision = precision_from_string(a.get("precision", "f64"));
  // The design (--design, the design that was built), the default set, the measured stack (--psf,
  // a PSF spec read as every command reads a PSF file) and the set's check: before any work.
  q.design = PsfSpec{PsfSpec::Kind::Design, a.get("design"), "--design"};
  q.measured = raw ? PsfSpec{PsfSpec::Kind::Run, "", "--psf"} : PsfSpec{PsfSpec::Kind::File, a.get("psf"), "--psf"};
  FitProblem& problem = q.problem;
  problem.design = read_fit_design(cfg, q.design.value, q.design.argument);
  problem.parameters = split_items(a.get("fit"));
  if (problem.parameters.empty()) problem.parameters = default_fit_parameters(problem.design);
  if (!raw) problem.measured = read_psf_input(q.measured, cfg).stack;
  check_fit_parameters(cfg, problem.design, problem.parameters);
  opt.parameters = problem.parameters;
  if (a.get("lateral-starts", "auto") == "auto") {
    opt.lateral_starts = 0;
  } else {
    char* end = nullptr;
    const std::string v = a.get("lateral-starts");
    const long k = std::strtol(v.c_str(), &end, 10);
    if (v.empty() || *end || k < 1 || k > 15) reject("--lateral-starts", v, "auto or an integer in [1, 15]");
    opt.lateral_starts = int(k);
  }
  opt.refine_starts = parse_int("--refine-starts", a.get("refine-starts", "4"), 1, 16);
  // NAME=VALUE,...: the names the fit prints, checked against the fitted set before any work.
  if (a.has("start")) opt.start = parse_fit_starts(cfg, problem.design, opt.parameters, a.get("start"));
  // The model's window: by default wide enough to sample the transfer function in every band up to
  // 5 % beyond the configuration's z (or the z start, when longer); a real camera is no aliased model.
  double z_m = cfg.sensor_distance_m;
  for (const auto& s : opt.start)
    if (s.first == "z") z_m = std::max(z_m, s.second);
  const std::string padded = apply_model_padding(q.cfg, a, z_m);
  if (!padded.empty()) q.notes.push_back(padded);
  // The raw frames read and checked as qdo calibrate checks them (every refusal names the file),
  // reduced to each band's window, before any device work.
  if (raw) {
    RawPsfWindows& windows = q.windows;
    windows = reduce_psf_frames(cfg, q.frames, q.darks, q.calibration);
    for (const auto& n : windows.calibration.notes) q.notes.push_back("note: " + n);
    q.notes.push_back(strprintf(
        "raw frames: %zu bands from %s (%zu frames, %zu darks), window %zu x %zu at frame (row %ld, column %ld), "
        "centred on (row %ld, column %ld): %s; %zu usable pixels",
        cfg.bands, q.frames.c_str(), windows.calibration.files.size(), windows.calibration.darks.size(), windows.s,
        windows.s, windows.top, windows.left, windows.calibration.centre_row, windows.calibration.centre_col,
        windows.calibration.centre_rule.c_str(), windows.usable));
  }
  return q;
}

FitReport run_fit_request(Runtime& rt, const FitRequest& q, const std::string& dir,
                          const std::function<void(const std::string&)>& say) {
  const SystemConfig& cfg = q.cfg;
  const Precision p = q.precision;
  const FitProblem& problem = q.problem;
  const bool raw = !q.frames.empty();
  FitOptions opt = q.options;
  opt.progress = say;
  const auto t0 = std::chrono::steady_clock::now();
  FitResult r;
  RealStack measured;  // the report's measured stack: the --psf stack, or each raw pixel's own estimate
  if (raw) {
    RawFitResult rr = fit_as_built_raw(rt, cfg, p, problem.design, q.windows, opt);
    r = std::move(rr.fit);
    measured = std::move(rr.measured_psf);
  } else {
    r = fit_as_built(rt, cfg, p, problem.design, problem.measured, opt);
    measured = problem.measured;
  }
  const double fit_s = seconds_since(t0);
  const auto t1 = std::chrono::steady_clock::now();
  // An as-built design that explains the measurement worse than the design itself is no result:
  // the command fails (exit 3) and, as on any failure, --out keeps nothing of it.
  const std::string source =
      raw ? "raw frames " + q.frames + ", darks " + q.darks + (q.white.empty() ? std::string() : ", white " + q.white)
          : q.measured.value;
  // The fitted model's sampling, as `qdo psf` reports it for the as-built design and configuration:
  // a transfer function the window under-samples is model error the fit meets as misfit
  // (docs/built-camera.md, "Limits today").
  std::string sampling;
  {
    Simulator sim(rt, r.as_built_config, p);
    sim.set_heights(r.as_built.height_m);
    sim.compute_psf();
    sampling = sim.sampling().summary();
  }
  FitSources sources{q.design.value, source, sampling};
  if (raw) {
    const CalibrationResult& c = q.windows.calibration;
    sources.centre_row_col = to_str(c.centre_row) + "," + to_str(c.centre_col);
    sources.centre_rule = c.centre_rule;
  }
  FitReport rep;
  rep.written = write_fit_outputs(dir, cfg, measured, r, sources, fit_s);
  const double out_s = seconds_since(t1);

  for (const std::string& line : fit_summary_lines(cfg, r, fit_s, out_s)) rep.text += line + "\n";
  rep.text += "the fitted model's " + sampling + "\n";
  if (!r.converged)
    rep.warning = strprintf(
        "NOT CONVERGED: the iteration limit (--iterations %d) ended the fit; the values and sigmas above "
        "are not a minimum: raise --iterations, or start elsewhere (--start, --lateral-starts)",
        opt.max_iterations);
  if (!rep.written)
    rep.refusal = "the fit ended at loss " + to_str(r.loss_final) + ", above the design's own " +
                  to_str(r.loss_design) + ": no as-built design is written (nothing in --out " + dir +
                  "); start nearer the truth (--start in "
                  "the parameter's unit, e.g. dx=1.5um), raise --iterations or try more starts (--lateral-starts)";
  else
    rep.text += "wrote " + dir + "/fit.h5, fit.json, design.h5, config.json, psf.h5, fit.png, residual.png\n";
  return rep;
}

}  // namespace qdo
