// qdo fit: the as-built DOE (fit.hpp) from a design and a measured PSF stack, or from the raw
// point-source frames themselves (fit_raw.hpp: --frames, --darks) -> DIR/fit.h5, fit.json,
// design.h5, config.json, psf.h5, fit.png, residual.png. The work is the library's (fit_request.hpp:
// the options read and checked, the fit, its files and report); this file claims --out and prints.
#include <cstdio>
#include <string>

#include "cli.hpp"
#include "qdo/asbuilt/fit_request.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/runtime.hpp"

namespace qdo::cli {

static int cmd_fit(const Args& a) {
  const FitRequest q = fit_request_from_options(a);  // every input read and checked
  for (const std::string& line : q.notes) std::printf("%s\n", line.c_str());
  const std::string dir = out_dir(a);
  Runtime rt(a.get("device"));
  const FitReport r = run_fit_request(rt, q, dir, [](const std::string& l) {
    std::printf("%s\n", l.c_str());
    std::fflush(stdout);
  });
  std::fputs(r.text.c_str(), stdout);
  if (!r.warning.empty()) std::fprintf(stderr, "qdo fit: %s\n", r.warning.c_str());
  if (!r.written) throw AccuracyError(r.refusal);  // exit 3, and --out keeps nothing
  return 0;
}

// qdo fit: its entry in the command table (help order 60).
const RegisterCommand registered_fit(60, [] {
  using namespace opts;
  return CommandSpec{"fit",
                   "the as-built DOE: fit a design's level depths (or mask depths, or a height scale), DOE-sensor distance, object "
                   "distance, lateral offset and aperture to a measured PSF stack (--psf) or to the raw point-source frames themselves "
                   "(--frames, --darks) by Levenberg-Marquardt through the adjoints -> "
                   "DIR/fit.h5, fit.json (values, 1-sigma, correlation, residual per band), design.h5 (as built), config.json, psf.h5 "
                   "(the fitted model in the measurement's window, registration included: --psf for an adapted decoder), fit.png, "
                   "residual.png", "", "",
                   concat({preset(), config(),
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
                    opt("centre", "with --frames: where the window is centred, as qdo calibrate: auto (the frame's centre pixel when the "
                                  "light's centroid lies within 4 px of it, else the centroid), centroid, frame, or ROW,COL: the frame "
                                  "pixel of the optical axis", "auto"),
                    opt("fit", "parameters, comma-separated: levels (the L-1 depths of levels 1..L-1, m; level 0 held: a piston is "
                               "invisible), masks (the log2 L mask depths of a qdo+m design, m), scale (one factor on all heights; not with "
                               "levels or masks), z (DOE-sensor distance, m), d (object distance, m; nearly degenerate with z, so not in the "
                               "default), offset (dx, dy: the relief against the aperture, m), shift (sx, sy: registration, sensor px; a nuisance), "
                               "overlay (oxM, oyM: each lithography mask's own misplacement after the first, m; nested masks over the used levels, "
                               "binary with masks), aperture (radius, m, by a walk in half-pixel steps) (default: levels,z,offset if quantized, else "
                               "scale,z,offset)"),
                    opt("iterations", "most Levenberg-Marquardt iterations, an integer in [1, 1000]", "30"),
                    opt("lateral-starts", "auto: scans of the offset along x, then y, twice, an eighth of a DOE pixel apart, over the "
                                          "centroid's reach plus 1.5 DOE px, and the lowest's mirrors (the shift alone: a grid half a sensor "
                                          "px apart); K: a K x K grid over the centroid's reach plus 1 sensor px; 1: the centroid alone; auto or an integer in [1, 15]", "auto"),
                    opt("refine-starts", "M: short fits (3 iterations) from M starts in different basins (the lowest, its mirrors, the "
                                         "next lowest), the fit going on from the lowest; 1: the lowest alone; an integer in [1, 16]", "4"),
                    opt("start", "NAME=VALUE,...: start values of fitted parameters by the names the fit prints (level1, z, dx, sx, ...), "
                                 "lengths in metres or with a unit (550nm, 1.5um, 12.5mm), sx and sy in sensor px, scale plain; bounded by "
                                 "the aperture, the sensor window, a factor 10 on z and d (default: the design's, the centroid for offset or shift)"),
                    opt("tolerance", "stop when an accepted step lowers the loss by less than this fraction, in [0, 1]", "1e-7"),
                    opt("precision", "floating-point precision on the device: f32 or f64 (the fit's central differences want f64)", "f64"),
                    model_padding(), device(), out_dir_opt()}, frame_reduction_options()),
                   cmd_fit, false,
                   "a smaller configuration (n, bands) or --precision f32"};
});

}  // namespace qdo::cli
