// The files of a PSF calibration (calibration_outputs.hpp).
#include "qdo/asbuilt/calibration_outputs.hpp"

#include <algorithm>
#include <filesystem>
#include <utility>

#include "qdo/data/figure.hpp"
#include "qdo/data/io.hpp"
#include "qdo/data/psf_file.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/runtime/error.hpp"

namespace qdo {

namespace {

// The files' names, ";"-separated.
std::string file_names(const std::vector<std::string>& paths) {
  std::string s;
  for (const auto& f : paths) s += (s.empty() ? "" : ";") + std::filesystem::path(f).filename().string();
  return s;
}

}  // namespace

void write_calibration_outputs(const std::string& dir, const SystemConfig& cfg, const CalibrationResult& r,
                               const CalibrationProvenance& prov) {
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
  for (const auto& n : r.notes) notes += (notes.empty() ? "" : "\n") + n;
  f.root_attrs.insert({{"design", "measured"},
                       {"source", prov.source},
                       {"frames_dir", prov.frames_dir},
                       {"frames", file_names(r.files)},
                       {"darks_dir", prov.darks_dir},
                       {"darks", file_names(r.darks)},
                       {"dark_count", std::to_string(r.darks.size())},
                       {"hot_pixels_replaced", std::to_string(r.hot_pixels)},
                       {"centre_row_col", std::to_string(r.centre_row) + "," + std::to_string(r.centre_col)},
                       {"centre_rule", r.centre_rule},
                       {"frame_rows_cols", std::to_string(r.frame_rows) + "," + std::to_string(r.frame_cols)},
                       {"white_dir", prov.white_dir},
                       {"white_count", std::to_string(r.whites.size())},
                       {"notes", notes}});
  if (!prov.signal_mask.empty()) f.root_attrs.insert({"signal_mask", prov.signal_mask});
  write_psf_file(dir + "/psf.h5", std::move(f));
  const std::size_t crop = std::min<std::size_t>(96, r.psf.rows);
  write_psf_figure(dir + "/psf.png", "Measured PSF stack from " + prov.frames_dir, r.psf, cfg.wavelengths_nm(), cfg.sensor_pitch_m,
                   crop);
}

double compare_calibration_with_design(Runtime& rt, const SystemConfig& cfg, Precision p, const RealStack& measured,
                                       const Map2D& heights_m, const std::string& design, const std::string& dir) {
  const std::size_t s = measured.rows;
  Simulator sim(rt, cfg, p);
  sim.set_keep_field(false);
  sim.set_heights(heights_m);
  sim.compute_psf();
  const RealStack simulated = sim.psf_sensor();
  const auto cmp = compare_psf_stacks(measured, simulated);
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
  const std::size_t shown = std::min<std::size_t>(8, cfg.bands);
  RealStack pairs(2 * shown, s, s);
  std::vector<std::string> titles;
  for (std::size_t k = 0; k < shown; ++k) {
    const std::size_t b = shown > 1 ? k * (cfg.bands - 1) / (shown - 1) : 0;
    std::copy(measured.plane(b), measured.plane(b) + measured.plane_size(), pairs.plane(2 * k));
    std::copy(simulated.plane(b), simulated.plane(b) + simulated.plane_size(), pairs.plane(2 * k + 1));
    titles.push_back("measured " + to_str(wl[b]) + " nm");
    titles.push_back("simulated " + to_str(wl[b]) + " nm");
  }
  write_psf_panels(dir + "/compare.png", "Measured against simulated PSFs: " + design, pairs, titles, cfg.sensor_pitch_m,
                   std::min<std::size_t>(96, s));
  return mean_corr;
}

}  // namespace qdo
