// qdo calibrate: measured PSFs from captures (calibrate.hpp) -> DIR/psf.h5 in the layout of
// `qdo psf`, psf.png, and with --design the comparison with the design's simulated stack
// (calibration_outputs.hpp).
#include <cstdio>
#include <filesystem>
#include <memory>
#include <utility>

#include "cli.hpp"
#include "options.hpp"
#include "qdo/asbuilt/calibration_outputs.hpp"
#include "qdo/physics/calibrate.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"
#include "qdo/runtime/runtime.hpp"

namespace qdo::cli {

static int cmd_calibrate(const Args& a) {
  const SystemConfig cfg = load_config(a);
  if (!a.has("frames")) throw InputError("argument '--frames' is required: the folder of PSF frames (psf_<nm>nm.png)");
  if (!a.has("darks")) throw InputError("argument '--darks' is required: the folder of dark frames (*.png)");
  CalibrationOptions opt;
  opt.white_dir = a.get("white");
  opt.hot_sigma = parse_double("--hot-sigma", a.get("hot-sigma"), 1, 1e6, "noise sigmas", false);
  opt.min_snr = parse_double("--min-snr", a.get("min-snr"), 0, 1e12, "", false);
  // Given explicitly only: the struct's default (a colour that responds at all is a measurement,
  // weighted by its noise) stands otherwise.
  if (a.has("min-response")) opt.min_response = parse_double("--min-response", a.get("min-response"), 0, 1, "", true);
  opt.floor_sigma = parse_double("--floor-sigma", a.get("floor-sigma"), 0, 100, "noise sigmas", false);
  const std::string bg = a.get("background");
  if (bg != "ring" && bg != "none") reject("--background", bg, "ring (the median of the crop's outer 2-pixel ring) or none");
  opt.ring_background = bg == "ring";
  if (a.has("centre")) {
    const auto v = split_items(a.get("centre"));
    if (v.size() != 2) reject("--centre", a.get("centre"), "ROW,COL: the frame pixel of the optical axis");
    opt.has_centre = true;
    opt.centre_row = parse_int("--centre", v[0], 0, 1 << 20);
    opt.centre_col = parse_int("--centre", v[1], 0, 1 << 20);
  }
  std::string design = a.get("design");
  if (!design.empty() && std::filesystem::is_directory(design)) design += "/design.h5";  // a run folder
  Map2D h;
  if (!design.empty()) h = load_design(cfg, design);  // checked before any work
  const Precision p = precision_from_string(a.get("precision"));
  const std::string dir = out_dir(a);

  const CalibrationResult r = calibrate_psf(cfg, a.get("frames"), a.get("darks"), opt);
  const std::size_t s = r.psf.rows;
  for (const auto& n : r.notes) std::printf("note: %s\n", n.c_str());
  CalibrationProvenance prov;
  prov.source = "qdo calibrate";
  prov.frames_dir = a.get("frames");
  prov.darks_dir = a.get("darks");
  prov.white_dir = a.get("white");
  write_calibration_outputs(dir, cfg, r, prov);
  std::printf(
      "calibrated %zu bands from %s (%zu frames, %zu dark frames, %zu hot pixels replaced, %zu of them transient), "
      "centre (row %ld, column %ld) of %zu x %zu, S = %zu\n",
      cfg.bands, a.get("frames").c_str(), r.files.size(), r.darks.size(), r.hot_pixels, r.transients.size(),
      r.centre_row, r.centre_col, r.frame_rows, r.frame_cols, s);
  std::printf("seconds:");
  for (const auto& [step, sec] : r.seconds) std::printf(" [%s] %.4f", step.c_str(), sec);
  std::printf("\n");
  if (design.empty()) {
    std::printf("wrote %s/psf.h5, psf.png\n", dir.c_str());
    return 0;
  }
  Runtime rt(a.get("device"));
  const double mean_corr = compare_calibration_with_design(rt, cfg, p, r.psf, h, design, dir);
  std::printf("against the design %s: mean correlation %.4f over %zu bands\nwrote %s/psf.h5, psf.png, compare.csv, compare.png\n",
              design.c_str(), mean_corr, cfg.bands, dir.c_str());
  return 0;
}

namespace {
// qdo calibrate: its entry in the command table (help order 50).
const RegisterCommand registered_calibrate(50, [] {
  using namespace opts;
  CommandSpec c{"calibrate",
                   "measured PSFs from captures: a folder of point-source frames, one per band (16-bit PNG or TIFF, psf_<nm>nm.png), "
                   "and dark frames -> DIR/psf.h5 (the layout of qdo psf), psf.png; with --design compare.csv, compare.png",
                   "", "",
                   {preset(), config(), opt("frames", "folder of PSF frames: 16-bit grayscale PNG or TIFF raw frames named <anything>_<nm>nm.png|.tif, one "
                                                      "or more per configured band (several of one band are exposures, averaged) (required)"),
                    opt("darks", "folder of dark frames (16-bit grayscale PNG or TIFF, same exposure; averaged) (required)"),
                    opt("white", "folder of white (flat-field) frames: a uniformly lit, spectrally flat white target filling the view, the "
                                 "frames' size (averaged, dark subtracted); every frame is divided by its white signal over the white's "
                                 "mean (colour gains and pixel response measured; psf.h5 /white_channel_gains) (default: none)"),
                    opt("design", "design to compare with: lens:NM, flat, a design .h5 file or a run folder (its design.h5)"),
                    opt("hot-sigma", "hot-pixel threshold, in noise sigmas (> 1)", "8"),
                    opt("min-snr", "least peak SNR (peak above the dark / noise sigma) of a band; a darker frame is refused", "20"),
                    opt("min-response", "least relative response, in (0, 1], of a mosaic colour at a band for its pixels to count as "
                                        "a measurement (weaker ones get the estimate of their neighbours; the rest are used, each "
                                        "weighted by its noise)", "0.005"),
                    opt("floor-sigma", "signal-mask threshold: pixels whose 5 x 5 mean is below this many sigmas of its noise (and not within 2 px of one above) are set to 0", "4"),
                    opt("background", "background removed after the dark: ring (the median of the S x S crop's outer 2-pixel ring) "
                                      "or none (the dark only; for a PSF with energy out to the crop's edge)",
                        "ring"),
                    opt("centre", "ROW,COL: the frame pixel of the optical axis (default: the centroid of all bands)"),
                    precision(), device(), out_dir_opt()},
                   cmd_calibrate};
  c.memory_advice = "frames cropped closer to the PSF, or fewer bands in the configuration";
  return c;
});
}  // namespace

}  // namespace qdo::cli
