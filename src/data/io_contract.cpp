// The contract files on HDF5 (io.hpp, "Contract helpers"): design, PSF stack, cube and RGB files,
// written and read through the checked HDF5 layer (io_hdf5.cpp).
#include <cmath>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "data/io_internal.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"
#include "qdo/data/psf_file.hpp"

namespace qdo {
using namespace io_detail;
namespace {

void require_finite(const std::string& path, const std::string& what, const std::vector<double>& v) {
  const std::size_t bad = count_nonfinite(v);
  if (bad) fail(path, what, std::to_string(bad) + " non-finite values");
}

}  // namespace

// =========================================================================================
// Contract helpers
// =========================================================================================

void write_design(const std::string& path, const Design& d, const std::map<std::string, std::string>& provenance) {
  if (!(d.pitch_m > 0) || !std::isfinite(d.pitch_m)) reject("pitch_m", d.pitch_m, "a finite pitch > 0 in metres");
  if (d.height_m.rows != d.height_m.cols || d.height_m.rows == 0)
    reject("height_m", std::to_string(d.height_m.rows) + " x " + std::to_string(d.height_m.cols),
           "a non-empty square N x N map");
  H5Dataset h{"/height_m", {d.height_m.rows, d.height_m.cols}, d.height_m.data, {{"pitch_m", d.pitch_m}},
              {{"units", "m"}}};
  // A quantized map holds L distinct values: deflate shrinks it (4 levels at N = 1024: 8.4 MB ->
  // 1.2 MB); a continuous one barely shrinks and is written as it is.
  h.compress = few_distinct_values(d.height_m.data);
  std::vector<H5Dataset> sets{h};
  if (!d.levels_m.empty()) sets.push_back({"/levels_m", {d.levels_m.size()}, d.levels_m, {}, {{"units", "m"}}});
  h5_write(path, sets, provenance);
}

Design read_design(const std::string& path) {
  const H5Dataset h = h5_read(path, "/height_m");
  const std::string what = "dataset '/height_m'";
  if (h.shape.size() != 2 || h.shape[0] != h.shape[1] || h.shape[0] == 0)
    fail(path, what, "shape " + shape_str(h.shape) + " is not a square N x N map");
  require_finite(path, what, h.data);
  const auto it = h.num_attrs.find("pitch_m");
  if (it == h.num_attrs.end()) fail(path, what, "attribute 'pitch_m' is missing");
  if (!(it->second > 0) || !std::isfinite(it->second))
    fail(path, what, "attribute 'pitch_m' = " + to_str(it->second) + " is invalid (must be finite and > 0)");
  Design d;
  d.height_m = Map2D(h.shape[0], h.shape[1]);
  d.height_m.data = h.data;
  d.pitch_m = it->second;
  if (h5_has(path, "/levels_m")) {
    const H5Dataset l = h5_read(path, "/levels_m");
    if (l.shape.size() != 1) fail(path, "dataset '/levels_m'", "shape " + shape_str(l.shape) + " is not 1-D");
    require_finite(path, "dataset '/levels_m'", l.data);
    d.levels_m = l.data;
  }
  return d;
}

void write_psf(const std::string& path, const RealStack& psf, const std::vector<double>& wavelengths_nm,
               double pitch_m, const std::map<std::string, double>& extra_num_attrs) {
  PsfFile f;
  f.psf_sensor = SensorStack(psf);
  f.wavelengths_nm = wavelengths_nm;
  f.pitch_m = pitch_m;
  f.num_attrs = extra_num_attrs;
  write_psf_file(path, std::move(f));
}

PsfStackFile read_psf_stack_file(const std::string& path) {
  require_file(path);
  PsfStackFile f;
  f.dataset = h5_has(path, "/psf_sensor") ? "/psf_sensor" : h5_has(path, "/psf") ? "/psf" : "";
  if (f.dataset.empty()) fail(path, "", "no dataset '/psf_sensor' (a PSF stack as qdo psf writes it)");
  const std::string what = "dataset '" + f.dataset + "'";
  H5Dataset d = h5_read(path, f.dataset);
  if (d.shape.size() == 4)
    fail(path, what, "shape " + shape_str(d.shape) + " holds " + to_str(d.shape[0]) +
                         " object points (qdo psf with several points); one camera PSF is one point's bands x S x S: "
                         "rerun qdo psf with that point alone");
  if (d.shape.size() != 3 || d.shape[1] != d.shape[2] || d.shape[0] == 0 || d.shape[1] == 0)
    fail(path, what, "shape " + shape_str(d.shape) + " is not a stack of square planes (bands x S x S)");
  if (const std::size_t bad = count_nonfinite(d.data)) fail(path, what, to_str(bad) + " values are NaN or Inf");
  const auto it = d.num_attrs.find("pitch_m");
  if (it == d.num_attrs.end()) fail(path, what, "attribute 'pitch_m' is missing");
  if (!(it->second > 0) || !std::isfinite(it->second))
    fail(path, what, "attribute 'pitch_m' = " + to_str(it->second) + " is invalid (must be finite and > 0)");
  f.pitch_m = it->second;
  if (!h5_has(path, "/wavelengths_nm")) fail(path, "", "no dataset '/wavelengths_nm' beside " + what);
  const H5Dataset w = h5_read(path, "/wavelengths_nm", 1 << 20);
  if (w.shape.size() != 1 || w.shape[0] != d.shape[0])
    fail(path, "dataset '/wavelengths_nm'", "shape " + shape_str(w.shape) + ": one wavelength per plane of " + what + " (" +
                                              to_str(d.shape[0]) + ") expected");
  if (count_nonfinite(w.data)) fail(path, "dataset '/wavelengths_nm'", "NaN or Inf values");
  f.wavelengths_nm = w.data;
  f.psf_sensor = RealStack(d.shape[0], d.shape[1], d.shape[2]);
  f.psf_sensor.data = std::move(d.data);
  return f;
}

void write_cube(const std::string& path, const RealStack& cube, const std::vector<double>& wavelengths_nm) {
  if (wavelengths_nm.size() != cube.planes)
    reject("wavelengths_nm", wavelengths_nm.size(), "one wavelength per cube band (" + std::to_string(cube.planes) + ")");
  h5_write(path, {H5Dataset{"/cube", {cube.planes, cube.rows, cube.cols}, cube.data, {}, {}},
                  H5Dataset{"/wavelengths_nm", {wavelengths_nm.size()}, wavelengths_nm, {}, {{"units", "nm"}}}});
}

void write_rgb(const std::string& path, const RealStack& rgb, const std::map<std::string, double>& attrs) {
  if (rgb.planes != 3) reject("rgb planes", rgb.planes, "exactly 3 (R, G, B)");
  h5_write(path, {H5Dataset{"/rgb", {rgb.planes, rgb.rows, rgb.cols}, rgb.data, attrs, {}}});
}

}  // namespace qdo
