// The PSF outputs of `qdo psf` and `qdo simulate` (psf_outputs.hpp).
#include "psf_outputs.hpp"

#include <algorithm>
#include <future>

#include "qdo/config.hpp"
#include "qdo/error.hpp"
#include "qdo/io.hpp"
#include "qdo/scenes.hpp"

namespace qdo::cli {

// --save: extra outputs of psf and simulate, comma-separated; today only "native" (the native-grid PSF
// stack /psf_native in psf.h5, bands x N x N: the largest output, off by default).
bool save_native(const Args& a) {
  bool native = false;
  for (const auto& s : split_list(a.get("save"))) {
    if (s == "native") native = true;
    else reject("--save", s, "a comma-separated list of: native");
  }
  return native;
}

RealStack SensorStack::central(std::size_t crop) const {
  const std::size_t h = std::min(crop, rows), w = std::min(crop, cols), y0 = (rows - h) / 2, x0 = (cols - w) / 2;
  RealStack out(planes, h, w);
  for (std::size_t b = 0; b < planes; ++b)
    for (std::size_t y = 0; y < h; ++y)
      for (std::size_t x = 0; x < w; ++x) {
        const std::size_t at = (b * rows + y0 + y) * cols + x0 + x;
        out(b, y, x) = f32 ? double(f32[at]) : (*f64)[at];
      }
  return out;
}

// DIR/psf.h5: the sensor PSF stack psf_s (bands x S x S), the native-grid stack when `native`,
// wavelengths, sampling, heights. The PSF stacks are stored in the run's precision: float32 for
// an f32 run (exactly the device's values, half the bytes), float64 for f64. Reads the device
// (call it on the thread that owns the simulator).
void write_psf_h5(Simulator& sim, const SensorStack& psf_s, const Map2D& h, const std::string& dir, const std::string& tag,
                  bool native, bool compress) {
  const SystemConfig& cfg = sim.config();
  const bool f32 = sim.precision() == Precision::F32;
  std::vector<H5Dataset> ds;
  if (native) {
    const RealStack psf = sim.psf_native();
    ds.push_back({"/psf_native", {psf.planes, psf.rows, psf.cols}, psf.data, {{"pitch_m", cfg.pitch_m}}, {{"units", "fraction of band energy per sample"}}});
    ds.back().float32 = f32;
    ds.back().compress = compress;
  }
  ds.push_back({"/psf_sensor", {psf_s.planes, psf_s.rows, psf_s.cols}, {}, {{"pitch_m", cfg.sensor_pitch_m}},
                {{"units", "fraction of band energy per sensor pixel"}}});
  // Written from psf_s itself (the figures read it meanwhile).
  if (psf_s.f32) {
    ds.back().f32_view = psf_s.f32;
    ds.back().f32_count = psf_s.planes * psf_s.rows * psf_s.cols;
  } else {
    ds.back().view = psf_s.f64;
  }
  ds.back().float32 = f32 || psf_s.f32;
  ds.back().compress = compress;
  ds.push_back({"/wavelengths_nm", {cfg.bands}, cfg.wavelengths_nm(), {}, {{"units", "nm"}}});
  std::vector<double> alias, outside;
  for (const auto& b : sim.sampling().bands) {
    alias.push_back(b.aliased_energy_fraction);
    outside.push_back(b.energy_outside_window);
  }
  ds.push_back({"/aliased_energy_fraction", {cfg.bands}, alias, {}, {{"units", "fraction"}}});
  ds.push_back({"/energy_outside_window", {cfg.bands}, outside, {}, {{"units", "fraction"}}});
  ds.push_back({"/height_m", {h.rows, h.cols}, h.data, {{"pitch_m", cfg.pitch_m}}, {{"units", "m"}}});
  ds.back().compress = few_distinct_values(h.data);  // as in design files: quantized maps only
  h5_write(dir + "/psf.h5", ds, {{"config", config_to_json_text(cfg)}, {"design", tag}, {"precision", to_string(sim.precision())}});
}

// DIR/psf.png (montage of the sensor PSF stack) and DIR/design.png (height map). Host only.
// design.png is a preview at most 512 px per side (every k-th sample, k = ceil(N / 512): every
// 2nd at N = 1024); the heights themselves are in the HDF5 files. The two figures are drawn on two
// threads (libpng is reentrant).
void write_psf_figures(const SystemConfig& cfg, const SensorStack& psf_s, const Map2D& h, const std::string& dir) {
  auto montage = std::async(std::launch::async, [&] {
    // The montage shows the central 96 x 96 of each plane: only that part is converted.
    const RealStack crop = psf_s.central(96);
    write_montage_png(dir + "/psf.png", crop, cfg.wavelengths_nm(), 0.5, 0);  // 0: the whole (cropped) stack
  });
  const std::size_t k = (std::max(h.rows, h.cols) + 511) / 512;
  try {
    if (k <= 1) {
      write_map_png(dir + "/design.png", h);
    } else {
      Map2D small((h.rows + k - 1) / k, (h.cols + k - 1) / k);
      for (std::size_t y = 0; y < small.rows; ++y)
        for (std::size_t x = 0; x < small.cols; ++x) small(y, x) = h(y * k, x * k);
      write_map_png(dir + "/design.png", small);
    }
  } catch (...) {
    montage.wait();
    throw;
  }
  montage.get();
}

// Runs `figures` (PNG writers only: libpng is reentrant) on a second thread while `data` (every
// HDF5 writer, one at a time: the HDF5 library is not built thread-safe, and any device read)
// runs on this one; after both have stopped, rethrows the first failure (data's first).
void write_concurrently(const std::function<void()>& data, const std::function<void()>& figures) {
  auto fig = std::async(std::launch::async, figures);
  try {
    data();
  } catch (...) {
    fig.wait();
    throw;
  }
  fig.get();
}

}  // namespace qdo::cli
