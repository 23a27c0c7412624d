// The simulated monochromator sweep (psf_sweep_capture.hpp): the plan on the host, the PSF on the
// device, the raw frames and darks through the sensor as built (ref::raw_forward) on the host.
#include "qdo/asbuilt/psf_sweep_capture.hpp"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <string>

#include "qdo/data/figure.hpp"
#include "qdo/data/io.hpp"
#include "qdo/asbuilt/raw_capture.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/util.hpp"

namespace qdo {

PsfSweepGeometry plan_psf_sweep_capture(const SystemConfig& cfg, const PsfSweepCaptureSpec& spec) {
  check_raw_capture_config(cfg, spec.config_label.name);
  PsfSweepGeometry g;
  g.psf_px = cfg.sensor_size_px();
  const std::size_t S = g.psf_px;
  g.frame_px = spec.frame_px == 0 ? S + 64 : spec.frame_px;
  const std::size_t F = g.frame_px;
  if (F < S || F > 8192) reject("frame_px", F, "an integer in [" + to_str(S) + ", 8192] (at least the sensor PSF size S)");
  if (!(spec.peak > 0 && spec.peak <= 1)) reject("peak", spec.peak, "a fraction of full well in (0, 1]");
  if (spec.darks < 1 || spec.darks > 1000) reject("darks", spec.darks, "an integer in [1, 1000]");
  g.centre_row = long(F / 2);
  g.centre_col = long(F / 2);
  if (spec.centre) {
    g.centre_row = spec.centre->first;
    g.centre_col = spec.centre->second;
  }
  const long half = long(S / 2), cy = g.centre_row, cx = g.centre_col;
  if (cy < half || cx < half || cy - half + long(S) > long(F) || cx - half + long(S) > long(F))
    reject(spec.centre_label.name, spec.centre_label.text.empty() ? to_str(cy) + "," + to_str(cx) : spec.centre_label.text,
           "a centre whose S x S PSF window (S = " + to_str(S) + ") lies inside the " + to_str(F) + " x " + to_str(F) +
               " frame: rows and columns in [" + to_str(half) + ", " + to_str(long(F) - long(S) + half) + "]");
  return g;
}

namespace {

void add_counts(RawCounts& sum, const RawCounts& c) {
  sum.saturated += c.saturated;
  sum.floored += c.floored;
  sum.total += c.total;
}

}  // namespace

PsfSweepCaptureResult capture_psf_sweep(Runtime& rt, const SystemConfig& cfg, Precision p, const PsfInput& in,
                                        const PsfSweepCaptureSpec& spec, const std::string& dir,
                                        const std::function<void(std::size_t band, double seconds)>& progress) {
  PsfSweepCaptureResult r;
  r.geometry = plan_psf_sweep_capture(cfg, spec);
  const std::size_t S = r.geometry.psf_px, F = r.geometry.frame_px;
  const std::size_t top = std::size_t(r.geometry.centre_row - long(S / 2)), left = std::size_t(r.geometry.centre_col - long(S / 2));
  SpecPsfSource src = make_psf_source(rt, cfg, p, in);
  src.compute();
  r.psf = src.source().psf_sensor();
  r.psf_description = src.source().describe();
  const RealStack& psf = r.psf;
  const Eigen::MatrixXd srf = sensor_response(cfg);
  r.wavelengths_nm = cfg.wavelengths_nm();
  const std::vector<double>& wl = r.wavelengths_nm;
  namespace fs = std::filesystem;
  fs::create_directories(dir + "/frames");
  fs::create_directories(dir + "/darks");
  r.amplitude.assign(cfg.bands, 0.0);
  r.peak_dn.assign(cfg.bands, 0.0);
  RealStack crops(cfg.bands, S, S);  // the frames' S x S windows, black removed (the figure)
  const auto t0 = std::chrono::steady_clock::now();
  for (std::size_t b = 0; b < cfg.bands; ++b) {
    const double top_psf = *std::max_element(psf.plane(b), psf.plane(b) + S * S);
    const double top_srf = std::max({srf(0, long(b)), srf(1, long(b)), srf(2, long(b))});
    if (!(top_psf > 0) || !(top_srf > 0))
      reject(spec.psf_label.name, spec.psf_label.text.empty() ? in.spec.value : spec.psf_label.text,
             "a PSF with light in every band (band " + to_str(wl[b]) + " nm is dark)");
    r.amplitude[b] = spec.peak / top_psf;
    RealStack rgb(3, F, F);
    for (std::size_t c = 0; c < 3; ++c)
      for (std::size_t y = 0; y < S; ++y)
        for (std::size_t x = 0; x < S; ++x)
          rgb(c, top + y, left + x) = r.amplitude[b] * psf(b, y, x) * srf(long(c), long(b)) / top_srf;
    const ref::RawFrame f = ref::raw_forward(rgb, cfg, b);
    add_counts(r.frames, f.counts);
    r.frames_saturated += f.counts.saturated > 0 ? 1 : 0;
    r.peak_dn[b] = *std::max_element(f.raw.data.begin(), f.raw.data.end());
    for (std::size_t y = 0; y < S; ++y)
      for (std::size_t x = 0; x < S; ++x) crops(b, y, x) = std::max(0.0, f.raw(0, top + y, left + x) - cfg.black_level_dn);
    char name[64];
    std::snprintf(name, sizeof name, "/frames/psf_%gnm.png", wl[b]);
    write_png16_gray(dir + name, raw_plane_map(f.raw));
    if (progress) progress(b, seconds_since(t0));
  }
  for (std::size_t k = 0; k < spec.darks; ++k) {
    const ref::RawFrame f = ref::raw_forward(RealStack(3, F, F), cfg, cfg.bands + k);
    add_counts(r.darks, f.counts);
    write_png16_gray(dir + "/darks/dark_" + std::to_string(k) + ".png", raw_plane_map(f.raw));
  }
  r.seconds = seconds_since(t0);
  write_psf(dir + "/psf.h5", psf, wl, cfg.sensor_pitch_m);
  h5_write(dir + "/sweep.h5",
           {{"/wavelengths_nm", {cfg.bands}, wl, {}, {{"units", "nm"}}},
            {"/amplitude", {cfg.bands}, r.amplitude, {}, {{"units", "full well per unit of the unit-sum PSF (brightest colour)"}}},
            {"/peak_dn", {cfg.bands}, r.peak_dn, {}, {{"units", "DN, the frame's largest code value"}}}},
           {{"config", config_to_json_text(cfg)},
            {"source", spec.provenance},
            {"design", spec.design},
            {"frame_size", to_str(F)},
            {"centre_row_col", to_str(r.geometry.centre_row) + "," + to_str(r.geometry.centre_col)},
            {"peak", to_str(spec.peak)},
            {"darks", to_str(spec.darks)},
            {"saturated", to_str(r.frames.saturated)},
            {"floored", to_str(r.frames.floored + r.darks.floored)}});
  write_psf_figure(dir + "/frames.png", "PSF sweep frames above the black level, around the axis", crops, wl, cfg.sensor_pitch_m,
                   std::min<std::size_t>(S, 96));
  return r;
}

}  // namespace qdo
