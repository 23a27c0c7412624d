// qdo calibrate: measured PSFs from captures (calibrate.hpp) -> DIR/psf.h5 in the layout of
// `qdo psf`, psf.png, and with --design the comparison with the design's simulated stack
// (calibration_outputs.hpp, which also reads the options and reports); this file claims --out,
// opens the device for the comparison and prints.
#include <cstdio>
#include <string>

#include "cli.hpp"
#include "qdo/asbuilt/calibration_outputs.hpp"
#include "qdo/runtime/runtime.hpp"

namespace qdo::cli {

static int cmd_calibrate(const Args& a) {
  const CalibrateRequest q = calibrate_request_from_options(a);  // every option checked, the design read
  const std::string dir = out_dir(a);
  const CalibrationRun r = run_calibration(q, dir);
  std::fputs(r.report.c_str(), stdout);
  if (q.design.empty()) return 0;
  Runtime rt(a.get("device"));
  std::fputs(compare_calibration_report(rt, q, r.result, dir).c_str(), stdout);
  return 0;
}

// qdo calibrate: its entry in the command table (help order 50).
const RegisterCommand registered_calibrate(50, [] {
  using namespace opts;
  return CommandSpec{"calibrate",
                   "measured PSFs from captures: a folder of point-source frames, one per band (16-bit PNG or TIFF, psf_<nm>nm.png), "
                   "and dark frames -> DIR/psf.h5 (the layout of qdo psf), psf.png; with --design compare.csv, compare.png",
                   "", "",
                   concat({preset(), config(), opt("frames", "folder of PSF frames: 16-bit grayscale PNG or TIFF raw frames named <anything>_<nm>nm.png|.tif, one "
                                                      "or more per configured band (several of one band are exposures, averaged) (required)"),
                    opt("darks", "folder of dark frames (16-bit grayscale PNG or TIFF, same exposure; averaged) (required)"),
                    opt("white", "folder of white (flat-field) frames: a uniformly lit, spectrally flat white target filling the view, the "
                                 "frames' size (averaged, dark subtracted); every frame is divided by its white signal over the white's "
                                 "mean (colour gains and pixel response measured; psf.h5 /white_channel_gains) (default: none)"),
                    opt("design", "design to compare with: lens:NM, flat, a design .h5 file or a run folder (its design.h5)"),
                    opt("floor-sigma", "signal-mask threshold: a window is kept when its mean stands this many sigmas above its noise; pixels in no kept window are set to 0", "4"),
                    opt("mask-windows", "the signal mask's window widths in px, odd, ascending: each tests the light the smaller ones did not keep (5 alone: a compact PSF; larger ones keep a DOE's faint wide halo)", "5,11,23"),
                    opt("background", "background removed after the dark: ring (the median of the S x S crop's outer 2-pixel ring) "
                                      "or none (the dark only; for a PSF with energy out to the crop's edge)",
                        "ring"),
                    opt("centre", "where the S x S window is centred: auto (the frame's centre pixel, where a camera and a simulator put the optical axis, when the light's centroid lies within 4 px of it; else the centroid, with a note), centroid (of all bands), frame, or ROW,COL: the frame pixel of the optical axis", "auto"),
                    precision(), device(), out_dir_opt()}, frame_reduction_options()),
                   cmd_calibrate, false,
                   "frames cropped closer to the PSF, or fewer bands in the configuration"};
});

}  // namespace qdo::cli
