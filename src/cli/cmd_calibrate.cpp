// qdo calibrate: measured PSFs from captures (calibrate.hpp) -> DIR/psf.h5 in the layout of
// `qdo psf`, psf.png, and with --design the comparison with the design's simulated stack.
#include <cstdio>
#include <filesystem>
#include <memory>
#include <utility>

#include "cli.hpp"
#include "qdo/data/figure.hpp"
#include "qdo/physics/calibrate.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"
#include "qdo/data/psf_file.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/physics/simulator.hpp"

namespace qdo::cli {

int cmd_calibrate(const Args& a) {
  const SystemConfig cfg = load_config(a);
  if (!a.has("frames")) throw InputError("argument '--frames' is required: the folder of PSF frames (psf_<nm>nm.png)");
  if (!a.has("darks")) throw InputError("argument '--darks' is required: the folder of dark frames (*.png)");
  CalibrationOptions opt;
  opt.white_dir = a.get("white");
  opt.hot_sigma = parse_double("--hot-sigma", a.get("hot-sigma"), 1, 1e6, "noise sigmas", false);
  opt.min_snr = parse_double("--min-snr", a.get("min-snr"), 0, 1e12, "", false);
  opt.min_response = parse_double("--min-response", a.get("min-response"), 0, 1, "", true);
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
  std::string files;
  for (const auto& f : r.files) files += (files.empty() ? "" : ";") + std::filesystem::path(f).filename().string();
  std::string darks;
  for (const auto& f : r.darks) darks += (darks.empty() ? "" : ";") + std::filesystem::path(f).filename().string();
  // The contract's /psf_sensor and /wavelengths_nm (one measured point: bands x S x S), and the
  // calibration's own datasets and provenance.
  PsfFile f = psf_file_for(cfg, SensorStack(r.psf));
  f.points = 1;
  f.extra.push_back({"/frame_wavelengths_nm", {cfg.bands}, r.wavelengths_nm, {}, {{"units", "nm, from the file names"}}});
  f.extra.push_back({"/peak_snr", {cfg.bands}, r.peak_snr, {}, {{"units", "peak / noise sigma"}}});
  f.extra.push_back({"/noise_dn", {cfg.bands}, r.noise_dn, {}, {{"units", "DN"}}});
  f.extra.push_back({"/background_dn", {cfg.bands}, r.background_dn, {}, {{"units", "DN, each frame's background after the mean dark"}}});
  if (!r.whites.empty())
    f.extra.push_back({"/white_channel_gains", {3}, {r.channel_gains.begin(), r.channel_gains.end()}, {},
                       {{"units", "R, G, B: each colour's mean white signal over the white's mean (divided out with each pixel's)"}}});
  std::string notes;
  for (const auto& n : r.notes) {
    std::printf("note: %s\n", n.c_str());
    notes += (notes.empty() ? "" : "\n") + n;
  }
  f.root_attrs.insert({{"design", "measured"},
                       {"source", "qdo calibrate"},
                       {"frames_dir", a.get("frames")},
                       {"frames", files},
                       {"darks_dir", a.get("darks")},
                       {"darks", darks},
                       {"dark_count", std::to_string(r.darks.size())},
                       {"hot_pixels_replaced", std::to_string(r.hot_pixels)},
                       {"centre_row_col", std::to_string(r.centre_row) + "," + std::to_string(r.centre_col)},
                       {"frame_rows_cols", std::to_string(r.frame_rows) + "," + std::to_string(r.frame_cols)},
                       {"white_dir", a.get("white")},
                       {"white_count", std::to_string(r.whites.size())},
                       {"notes", notes}});
  write_psf_file(dir + "/psf.h5", std::move(f));
  const std::size_t crop = std::min<std::size_t>(96, s);
  write_psf_figure(dir + "/psf.png", "Measured PSF stack from " + a.get("frames"), r.psf, cfg.wavelengths_nm(), cfg.sensor_pitch_m, crop);
  std::printf("calibrated %zu bands from %s (%zu dark frames, %zu hot pixels replaced), centre (row %ld, column %ld) of %zu x %zu, "
              "S = %zu\n",
              cfg.bands, a.get("frames").c_str(), r.darks.size(), r.hot_pixels, r.centre_row, r.centre_col, r.frame_rows, r.frame_cols, s);
  std::printf("seconds:");
  for (const auto& [step, sec] : r.seconds) std::printf(" [%s] %.4f", step.c_str(), sec);
  std::printf("\n");
  if (design.empty()) {
    std::printf("wrote %s/psf.h5, psf.png\n", dir.c_str());
    return 0;
  }
  Runtime rt(a.get("device"));
  Simulator sim(rt, cfg, p);
  sim.set_keep_field(false);
  sim.set_heights(h);
  sim.compute_psf();
  const RealStack simulated = sim.psf_sensor();
  const auto cmp = compare_psf_stacks(r.psf, simulated);
  CsvText csv({"wavelength_nm", "correlation", "ee80_measured_px", "ee80_simulated_px", "centroid_offset_px"});
  const auto wl = cfg.wavelengths_nm();
  double mean_corr = 0;
  for (std::size_t b = 0; b < cfg.bands; ++b) {
    csv.row({to_str(wl[b]), to_str(cmp[b].correlation), to_str(cmp[b].ee80_measured_px), to_str(cmp[b].ee80_simulated_px),
             to_str(cmp[b].centroid_offset_px)});
    mean_corr += cmp[b].correlation / double(cfg.bands);
  }
  write_text_atomic(dir + "/compare.csv", csv.str());
  // compare.png: measured and simulated side by side for up to 8 bands, evenly spaced.
  {
    const std::size_t shown = std::min<std::size_t>(8, cfg.bands);
    RealStack pairs(2 * shown, s, s);
    std::vector<std::string> titles;
    for (std::size_t k = 0; k < shown; ++k) {
      const std::size_t b = shown > 1 ? k * (cfg.bands - 1) / (shown - 1) : 0;
      std::copy(r.psf.plane(b), r.psf.plane(b) + r.psf.plane_size(), pairs.plane(2 * k));
      std::copy(simulated.plane(b), simulated.plane(b) + simulated.plane_size(), pairs.plane(2 * k + 1));
      titles.push_back("measured " + to_str(wl[b]) + " nm");
      titles.push_back("simulated " + to_str(wl[b]) + " nm");
    }
    write_psf_panels(dir + "/compare.png", "Measured against simulated PSFs: " + design, pairs, titles, cfg.sensor_pitch_m, crop);
  }
  std::printf("against the design %s: mean correlation %.4f over %zu bands\nwrote %s/psf.h5, psf.png, compare.csv, compare.png\n",
              design.c_str(), mean_corr, cfg.bands, dir.c_str());
  return 0;
}

}  // namespace qdo::cli
