// The psf.h5 writer (psf_file.hpp): the contract's /psf_sensor and /wavelengths_nm, each
// writer's own datasets, one atomic h5_write.
#include "qdo/data/psf_file.hpp"

#include <algorithm>
#include <cmath>
#include <utility>

#include "qdo/runtime/error.hpp"

namespace qdo {

RealStack SensorStack::central(std::size_t crop) const {
  const std::size_t h = std::min(crop, rows), w = std::min(crop, cols), y0 = (rows - h) / 2, x0 = (cols - w) / 2;
  RealStack out(planes, h, w);
  for (std::size_t b = 0; b < planes; ++b)
    for (std::size_t y = 0; y < h; ++y)
      for (std::size_t x = 0; x < w; ++x) out(b, y, x) = at((b * rows + y0 + y) * cols + x0 + x);
  return out;
}

PsfFile psf_file_for(const SystemConfig& cfg, const SensorStack& psf_sensor) {
  PsfFile f;
  f.psf_sensor = psf_sensor;
  f.points = cfg.point_count();
  f.wavelengths_nm = cfg.wavelengths_nm();
  f.pitch_m = cfg.sensor_pitch_m;
  f.root_attrs["config"] = config_to_json_text(cfg);
  return f;
}

void write_psf_file(const std::string& path, PsfFile f) {
  const SensorStack& s = f.psf_sensor;
  if ((s.f64 == nullptr) == (s.f32 == nullptr))
    reject("psf_sensor", s.f64 ? "both a double and a float32 stack" : "no values", "exactly one of a double or a float32 stack");
  if (s.planes == 0 || s.rows == 0 || s.cols == 0)
    reject("psf_sensor", to_str(s.planes) + " x " + to_str(s.rows) + " x " + to_str(s.cols), "a non-empty stack of planes");
  if (s.f64 && s.f64->size() != s.size())
    reject("psf_sensor", to_str(s.f64->size()) + " values",
           to_str(s.planes) + " x " + to_str(s.rows) + " x " + to_str(s.cols) + " = " + to_str(s.size()) + " values");
  if (f.points == 0 || s.planes % f.points != 0)
    reject("points", f.points, "a count > 0 that divides the stack's " + to_str(s.planes) + " planes (points x bands)");
  const std::size_t bands = s.planes / f.points;
  if (f.wavelengths_nm.size() != bands)
    reject("wavelengths_nm", f.wavelengths_nm.size(), "one wavelength per band (" + std::to_string(bands) + ")");
  if (!(f.pitch_m > 0) || !std::isfinite(f.pitch_m)) reject("pitch_m", f.pitch_m, "a finite pitch > 0 in metres");
  for (const H5Dataset& e : f.extra)
    if (e.name == "/psf_sensor" || e.name == "/wavelengths_nm")
      reject("extra dataset", e.name, "a dataset other than the PSF file's own /psf_sensor and /wavelengths_nm");

  std::vector<H5Dataset> ds;
  ds.reserve(2 + f.extra.size());
  const std::vector<std::size_t> shape =
      f.points > 1 ? std::vector<std::size_t>{f.points, bands, s.rows, s.cols} : std::vector<std::size_t>{bands, s.rows, s.cols};
  ds.push_back({"/psf_sensor", shape, {}, std::move(f.num_attrs), {{"units", "fraction of band energy per sensor pixel"}}});
  H5Dataset& p = ds.back();
  p.num_attrs["pitch_m"] = f.pitch_m;
  if (s.f32) {  // the mapped float32 values themselves
    p.f32_view = s.f32;
    p.f32_count = s.size();
  } else {
    p.view = s.f64;
  }
  p.float32 = f.float32 || s.f32;
  p.compress = f.compress;
  ds.push_back({"/wavelengths_nm", {bands}, std::move(f.wavelengths_nm), {}, {{"units", "nm"}}});
  for (H5Dataset& e : f.extra) ds.push_back(std::move(e));
  h5_write(path, ds, f.root_attrs);
}

}  // namespace qdo
