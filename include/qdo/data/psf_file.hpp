// The one writer of a PSF stack file, psf.h5 (the contract of io.hpp: /psf_sensor with its pitch,
// /wavelengths_nm, the run's provenance as root attributes), which `qdo psf`, `qdo simulate`,
// `qdo calibrate`, a design run and write_psf all go through; read back by read_psf_stack_file.
// Each writer adds its own datasets (the native-grid stack, heights, calibration statistics) to
// the same file through PsfFile::extra.
#pragma once
#include <cstddef>
#include <map>
#include <string>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/data/io.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

// A sensor PSF stack as the psf.h5 writer and the PSF summaries take it, without a copy: `planes`
// planes of rows x cols samples, row-major, plane after plane (sample (p, y, x) at
// (p * rows + y) * cols + x); either host doubles (f64) or float32 values (f32: a float32 device
// stack mapped on the host). Exactly one of the two is set; the caller keeps it alive while the
// view is used.
struct SensorStack {
  std::size_t planes = 0, rows = 0, cols = 0;
  const std::vector<double>* f64 = nullptr;
  const float* f32 = nullptr;
  SensorStack() = default;
  explicit SensorStack(const RealStack& s) : planes(s.planes), rows(s.rows), cols(s.cols), f64(&s.data) {}
  SensorStack(std::size_t p, std::size_t r, std::size_t c, const float* v) : planes(p), rows(r), cols(c), f32(v) {}
  std::size_t size() const { return planes * rows * cols; }
  // Sample `at` (the flat index above) in double.
  double at(std::size_t i) const { return f32 ? double(f32[i]) : (*f64)[i]; }
  // The central crop x crop of every plane (min(crop, rows) x min(crop, cols)), in double:
  // planes x crop x crop (figures).
  RealStack central(std::size_t crop) const;
};

// What one psf.h5 holds beyond its contract's two datasets.
struct PsfFile {
  // /psf_sensor: points x bands planes of S x S (point-major: plane p * bands + b), stored with
  // shape bands x S x S for one object point and points x bands x S x S for several.
  SensorStack psf_sensor;
  std::size_t points = 1;
  std::vector<double> wavelengths_nm;  // /wavelengths_nm: one per band (psf_sensor.planes / points)
  double pitch_m = 0;                  // /psf_sensor's attribute pitch_m: the sensor pixel pitch, metres
  std::map<std::string, double> num_attrs;  // further numeric attributes of /psf_sensor (pitch_m wins)
  bool float32 = false;   // store /psf_sensor as float32 (always when psf_sensor is a float32 stack)
  bool compress = false;  // H5Dataset::compress for /psf_sensor
  // Further datasets of the file (not /psf_sensor or /wavelengths_nm), written after those two;
  // their `view`s and `f32_view`s must stay alive until write_psf_file returns.
  std::vector<H5Dataset> extra;
  // The file's root attributes: provenance ("config": config_to_json_text, "design", "source",
  // "precision", ...); none when empty.
  std::map<std::string, std::string> root_attrs;
};

// The PsfFile of a configuration's stack: cfg's wavelengths, sensor pitch and object-point count
// (psf_sensor then holds cfg.point_count() x cfg.bands planes) and cfg's JSON as root attribute
// "config". The caller adds its datasets and attributes.
PsfFile psf_file_for(const SystemConfig& cfg, const SensorStack& psf_sensor);

// Writes `path` atomically (h5_write: temp file, then rename): /psf_sensor (attributes pitch_m,
// num_attrs; units "fraction of band energy per sensor pixel"), /wavelengths_nm (units "nm"), then
// f.extra, with f.root_attrs at the root. A float32 psf_sensor is written as it is (no conversion,
// no copy), a double one from its vector (no copy); f is a sink (its extra datasets are moved into
// the file's list, not copied). InputError naming the field for a stack without values or of
// another size than points x bands x S x S, a wavelength count other than the bands, a pitch that
// is not finite and > 0, or an extra dataset named /psf_sensor or /wavelengths_nm; NumericalError
// (h5_write) for a non-finite value, before the file is created.
void write_psf_file(const std::string& path, PsfFile f);

}  // namespace qdo
