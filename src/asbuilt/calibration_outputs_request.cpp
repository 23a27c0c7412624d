// qdo calibrate's options read from text, the calibration and its report
// (calibration_outputs.hpp).
#include "qdo/asbuilt/calibration_outputs.hpp"

#include <filesystem>

#include "qdo/design/option_inputs.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/strprintf.hpp"
#include "qdo/runtime/util.hpp"

namespace qdo {

void frame_reduction_from_options(const TextOptions& a, CalibrationOptions& opt) {
  opt.white_dir = a.get("white");
  opt.hot_sigma = parse_double("--hot-sigma", a.get("hot-sigma", "8"), 1, 1e6, "noise sigmas", false);
  opt.min_snr = parse_double("--min-snr", a.get("min-snr", "20"), 0, 1e12, "", false);
  // Given explicitly only: the struct's default (a colour that responds at all is a measurement,
  // weighted by its noise) stands otherwise.
  if (a.has("min-response")) opt.min_response = parse_double("--min-response", a.get("min-response"), 0, 1, "", true);
  const std::string centre = a.get("centre", "auto");
  if (centre == "auto") {
    opt.centre = CentreRule::automatic;
  } else if (centre == "centroid") {
    opt.centre = CentreRule::centroid;
  } else if (centre == "frame") {
    opt.centre = CentreRule::frame;
  } else {
    const auto v = split_items(centre);
    if (v.size() != 2)
      reject("--centre", centre,
             "auto (the frame's centre pixel when the light's centroid lies within " + strprintf("%g", kFrameCentreReachPx) +
                 " px of it, else the centroid), centroid, frame, or ROW,COL: the frame pixel of the optical axis");
    opt.centre = CentreRule::given;
    opt.centre_row = parse_int("--centre", v[0], 0, 1 << 20);
    opt.centre_col = parse_int("--centre", v[1], 0, 1 << 20);
  }
}

CalibrateRequest calibrate_request_from_options(const TextOptions& a) {
  CalibrateRequest q;
  q.cfg = config_from_options(a);
  if (!a.has("frames")) throw InputError("argument '--frames' is required: the folder of PSF frames (psf_<nm>nm.png)");
  if (!a.has("darks")) throw InputError("argument '--darks' is required: the folder of dark frames (*.png)");
  CalibrationOptions& opt = q.options;
  q.frames = a.get("frames");
  q.darks = a.get("darks");
  frame_reduction_from_options(a, opt);
  opt.floor_sigma = parse_double("--floor-sigma", a.get("floor-sigma", "4"), 0, 100, "noise sigmas", false);
  if (a.has("mask-windows")) {
    opt.mask_windows.clear();
    for (const auto& w : split_items(a.get("mask-windows")))
      opt.mask_windows.push_back(std::size_t(parse_int("--mask-windows", w, 3, 255)));
  }
  const std::string bg = a.get("background", "ring");
  if (bg != "ring" && bg != "none")
    reject("--background", bg, "ring (the median of the crop's outer 2-pixel ring) or none");
  opt.ring_background = bg == "ring";
  q.design = a.get("design");
  if (!q.design.empty() && std::filesystem::is_directory(q.design)) q.design += "/design.h5";  // a run folder
  if (!q.design.empty()) q.heights = design_heights_from_spec(q.cfg, q.design, "--design");  // checked before any work
  q.precision = precision_from_string(a.get("precision", "f32"));
  return q;
}

CalibrationRun run_calibration(const CalibrateRequest& q, const std::string& dir) {
  const SystemConfig& cfg = q.cfg;
  CalibrationRun run;
  run.result = calibrate_psf(cfg, q.frames, q.darks, q.options);
  const CalibrationResult& r = run.result;
  std::string& report = run.report;
  const std::size_t s = r.psf.rows;
  for (const auto& n : r.notes) report += "note: " + n + "\n";
  CalibrationProvenance prov;
  prov.source = "qdo calibrate";
  prov.frames_dir = q.frames;
  prov.darks_dir = q.darks;
  prov.white_dir = q.options.white_dir;
  std::string windows;
  for (const std::size_t w : q.options.mask_windows) windows += (windows.empty() ? "" : ",") + std::to_string(w);
  prov.signal_mask = "windows " + windows + " px at " + strprintf("%g", q.options.floor_sigma) + " sigma";
  write_calibration_outputs(dir, cfg, r, prov);
  report += strprintf(
      "calibrated %zu bands from %s (%zu frames, %zu dark frames, %zu hot pixels replaced, %zu of them transient), "
      "centre (row %ld, column %ld) of %zu x %zu, S = %zu: %s\n",
      cfg.bands, q.frames.c_str(), r.files.size(), r.darks.size(), r.hot_pixels, r.transients.size(), r.centre_row,
      r.centre_col, r.frame_rows, r.frame_cols, s, r.centre_rule.c_str());
  report += "seconds:";
  for (const auto& [step, sec] : r.seconds) report += strprintf(" [%s] %.4f", step.c_str(), sec);
  report += "\n";
  if (q.design.empty()) report += "wrote " + dir + "/psf.h5, psf.png\n";
  return run;
}

std::string compare_calibration_report(Runtime& rt, const CalibrateRequest& q, const CalibrationResult& r,
                                       const std::string& dir) {
  const double mean_corr = compare_calibration_with_design(rt, q.cfg, q.precision, r.psf, q.heights, q.design, dir);
  return strprintf(
      "against the design %s: mean correlation %.4f over %zu bands\nwrote %s/psf.h5, psf.png, compare.csv, "
      "compare.png\n",
      q.design.c_str(), mean_corr, q.cfg.bands, dir.c_str());
}

}  // namespace qdo
