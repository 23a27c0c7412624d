// qdo fit: the as-built DOE (fit.hpp) from a design and a measured PSF stack, or from the raw
// point-source frames themselves (fit_raw.hpp: --frames, --darks) -> DIR/fit.h5,
// fit.json, design.h5 (the as-built relief), config.json (the as-built geometry), fit.png
// (measured, fitted and design PSF per band) and residual.png (relative residual per band).
// The work is fit_report.hpp's: this file turns the options into its inputs and prints.
#include <chrono>
#include <cstdio>
#include <cstdlib>

#include "cli.hpp"
#include "options.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/asbuilt/fit.hpp"
#include "qdo/asbuilt/fit_raw.hpp"
#include "qdo/asbuilt/fit_report.hpp"
#include "qdo/physics/calibrate.hpp"
#include "qdo/runtime/runtime.hpp"

namespace qdo::cli {

static int cmd_fit(const Args& a) {
  const SystemConfig cfg = load_config(a);
  // The data: a calibrated stack (--psf) or the raw frames (--frames with --darks), one of them.
  const bool raw = a.has("frames");
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
  for (const char* k : {"darks", "white", "centre"})
    if (!raw && a.has(k))
      reject(std::string("--") + k, a.get(k),
             "only with --frames (the raw frames); a --psf stack is calibrated already");
  CalibrationOptions copt;
  copt.white_dir = a.get("white");
  if (a.has("centre")) {
    const auto v = split_items(a.get("centre"));
    if (v.size() != 2) reject("--centre", a.get("centre"), "ROW,COL: the frame pixel of the optical axis");
    copt.has_centre = true;
    copt.centre_row = parse_int("--centre", v[0], 0, 1 << 20);
    copt.centre_col = parse_int("--centre", v[1], 0, 1 << 20);
  }
  FitOptions opt;
  if (a.has("fit") && a.get("fit").find_first_not_of(" ,") == std::string::npos)
    reject("--fit", a.get("fit"), "one or more of levels, masks, scale, z, d, offset, shift, aperture (omit --fit for the default set)");
  opt.max_iterations = parse_int("--iterations", a.get("iterations"), 1, 1000);
  opt.tolerance = parse_double("--tolerance", a.get("tolerance"), 0, 1, "", false);
  const Precision p = precision_from_string(a.get("precision"));
  // The design (--design), the default set, the measured stack (--psf) and the set's check: before any work.
  FitProblem problem;
  if (raw) {
    problem.design = read_fit_design(cfg, a.get("design"));
    problem.parameters = split_items(a.get("fit"));
    if (problem.parameters.empty()) problem.parameters = default_fit_parameters(problem.design);
    check_fit_parameters(cfg, problem.design, problem.parameters);
  } else {
    problem = load_fit_problem(cfg, a.get("design"), a.get("psf"), split_items(a.get("fit")));
  }
  opt.parameters = problem.parameters;
  if (a.get("lateral-starts") == "auto") {
    opt.lateral_starts = 0;
  } else {
    char* end = nullptr;
    const std::string& v = a.get("lateral-starts");
    const long k = std::strtol(v.c_str(), &end, 10);
    if (v.empty() || *end || k < 1 || k > 15) reject("--lateral-starts", v, "auto or an integer in [1, 15]");
    opt.lateral_starts = int(k);
  }
  opt.refine_starts = parse_int("--refine-starts", a.get("refine-starts"), 1, 16);
  // NAME=VALUE,...: the names the fit prints, checked against the fitted set before any work.
  if (a.has("start")) opt.start = parse_fit_starts(cfg, problem.design, opt.parameters, a.get("start"));
  // The raw frames read and checked as qdo calibrate checks them (every refusal names the file),
  // reduced to each band's window, before any device work.
  RawPsfWindows windows;
  if (raw) {
    windows = reduce_psf_frames(cfg, a.get("frames"), a.get("darks"), copt);
    for (const auto& n : windows.calibration.notes) std::printf("note: %s\n", n.c_str());
    std::printf(
        "raw frames: %zu bands from %s (%zu frames, %zu darks), window %zu x %zu at frame (row %ld, column %ld), "
        "%zu usable pixels\n",
        cfg.bands, a.get("frames").c_str(), windows.calibration.files.size(), windows.calibration.darks.size(),
        windows.s, windows.s, windows.top, windows.left, windows.usable);
  }
  const std::string dir = out_dir(a);
  Runtime rt(a.get("device"));
  opt.progress = [](const std::string& l) {
    std::printf("%s\n", l.c_str());
    std::fflush(stdout);
  };
  const auto t0 = std::chrono::steady_clock::now();
  FitResult r;
  RealStack measured;  // the report's measured stack: the --psf stack, or each raw pixel's own estimate
  if (raw) {
    RawFitResult rr = fit_as_built_raw(rt, cfg, p, problem.design, windows, opt);
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
  const std::string source = raw ? "raw frames " + a.get("frames") + ", darks " + a.get("darks") +
                                       (a.has("white") ? ", white " + a.get("white") : std::string())
                                 : a.get("psf");
  const bool written = write_fit_outputs(dir, cfg, measured, r, {a.get("design"), source}, fit_s);
  const double out_s = seconds_since(t1);

  for (const std::string& line : fit_summary_lines(cfg, r, fit_s, out_s)) std::printf("%s\n", line.c_str());
  if (!r.converged)
    std::fprintf(stderr, "qdo fit: NOT CONVERGED: the iteration limit (--iterations %d) ended the fit; the values and sigmas above "
                         "are not a minimum: raise --iterations, or start elsewhere (--start, --lateral-starts)\n",
                 opt.max_iterations);
  if (!written)
    throw AccuracyError("the fit ended at loss " + to_str(r.loss_final) + ", above the design's own " + to_str(r.loss_design) +
                        ": no as-built design is written (nothing in --out " + a.get("out") + "); start nearer the truth (--start in "
                        "the parameter's unit, e.g. dx=1.5um), raise --iterations or try more starts (--lateral-starts)");
  std::printf("wrote %s/fit.h5, fit.json, design.h5, config.json, fit.png, residual.png\n", dir.c_str());
  return 0;
}

namespace {
// qdo fit: its entry in the command table (help order 60).
const RegisterCommand registered_fit(60, [] {
  using namespace opts;
  CommandSpec c{"fit",
                   "the as-built DOE: fit a design's level depths (or mask depths, or a height scale), DOE-sensor distance, object "
                   "distance, lateral offset and aperture to a measured PSF stack (--psf) or to the raw point-source frames themselves "
                   "(--frames, --darks) by Levenberg-Marquardt through the adjoints -> "
                   "DIR/fit.h5, fit.json (values, 1-sigma, correlation, residual per band), design.h5 (as built), config.json, fit.png, "
                   "residual.png",
                   "", "",
                   {preset(), config(),
                    opt("design", "the design that was built: a design .h5 file (its /levels_m defines each pixel's level), a run folder "
                                  "(its design.h5), lens:NM or flat (required)"),
                    opt("psf", "the measured PSF stack: psf.h5 as qdo calibrate (or qdo psf) writes it, for the configuration's bands and "
                               "sensor grid (checked) (required, unless --frames)"),
                    opt("frames", "instead of --psf: the folder of raw point-source frames qdo calibrate reads (<anything>_<nm>nm.png "
                                  "or .tif, one or more per band); the fit then compares the raw frames themselves through the sensor "
                                  "model (mosaic, response, gains, black level, bit depth), each pixel weighted by its Poisson-Gaussian "
                                  "variance, each band's source power solved in closed form"),
                    opt("darks", "with --frames: the folder of dark frames taken as the frames were (required with --frames)"),
                    opt("white", "with --frames: the folder of white (flat-field) frames, as qdo calibrate --white: each pixel's "
                                 "gain measured (default: none, gains 1)"),
                    opt("centre", "with --frames: ROW,COL, the frame pixel of the optical axis, the window's centre (default: the "
                                  "centroid of all bands, as qdo calibrate)"),
                    opt("fit", "parameters, comma-separated: levels (the L-1 depths of levels 1..L-1, m; level 0 held: a piston is "
                               "invisible), masks (the log2 L mask depths of a qdo+m design, m), scale (one factor on all heights; not with "
                               "levels or masks), z (DOE-sensor distance, m), d (object distance, m; nearly degenerate with z, so not in the "
                               "default), offset (dx, dy: the relief against the aperture, m), shift (sx, sy: registration of the measured "
                               "stack, sensor px; a nuisance), aperture (radius, m, by a walk of the loss in half-pixel steps) (default: levels,z,offset for a "
                               "quantized design, else scale,z,offset)"),
                    opt("iterations", "most Levenberg-Marquardt iterations, an integer in [1, 1000]", "30"),
                    opt("lateral-starts", "auto: scans of the offset along x, then y, twice, an eighth of a DOE pixel apart, over the "
                                          "centroid's reach plus 1.5 DOE px, and the mirrors of the lowest (a DOE's PSF has narrow mirror "
                                          "minima the centroid start does not tell apart; the shift alone: a grid half a sensor px apart); "
                                          "K: a K x K grid over the centroid's reach plus 1 sensor px; 1: the centroid difference alone; "
                                          "auto or an integer in [1, 15]", "auto"),
                    opt("refine-starts", "M: short fits (3 iterations) from M starts in different basins (the lowest, its "
                                         "mirrors, the next lowest), the fit going on from the lowest; 1: the lowest start alone; "
                                         "an integer in [1, 16]", "4"),
                    opt("start", "NAME=VALUE,...: start values of fitted parameters by the names the fit prints (level1, z, dx, sx, ...), "
                                 "lengths in metres or with a unit (550nm, 1.5um, 12.5mm), sx and sy in sensor px, scale plain; bounded by "
                                 "the aperture, the sensor window, a factor 10 on z and d (default: the design's, the centroid for offset or shift)"),
                    opt("tolerance", "stop when an accepted step lowers the loss by less than this fraction, in [0, 1]", "1e-7"),
                    opt("precision", "floating-point precision on the device: f32 or f64 (the fit's central differences want f64)", "f64"),
                    device(), out_dir_opt()},
                   cmd_fit};
  c.memory_advice = "a smaller configuration (n, bands) or --precision f32";
  return c;
});
}  // namespace

}  // namespace qdo::cli
