// read_cube (HDF5 or MATLAB, band-axis layout, scale) and the rules every scene passes:
// conform_band_axis (the file's band axis against the configured grid) and conform_radiance.
#include <algorithm>
#include <cmath>
#include <iostream>
#include <sstream>

#include "data/io_internal.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"

namespace qdo {
using namespace io_detail;

// Output: (bands, H, W) row-major, divided by the scale. See io.hpp for the layout rules.
RealStack read_cube(const std::string& path, const CubeReadOptions& opt) {
  if (opt.layout != "auto" && opt.layout != "bhw" && opt.layout != "hwb")
    reject("layout", opt.layout, "\"auto\", \"bhw\" or \"hwb\"");
  if (!(opt.scale >= 0) || !std::isfinite(opt.scale)) reject("scale", opt.scale, "0 (auto) or a finite value > 0");
  require_file(path);
  const bool is_mat = looks_like_mat(path);
  if (!opt.wavelengths_nm.empty() && opt.expected_bands != 0 && opt.expected_bands != opt.wavelengths_nm.size())
    reject("expected_bands", opt.expected_bands,
           "0 or the number of wavelengths_nm (" + std::to_string(opt.wavelengths_nm.size()) + ")");
  RawArray raw, axis;
  if (is_mat) {
    raw = read_mat_raw(path, opt.key, &axis);
  } else {
    H5Dataset d = h5_read_impl(path, opt.key.empty() ? "/cube" : opt.key, std::size_t(1) << 31, &raw.kind);
    raw.key = d.name;
    raw.dims = d.shape;
    raw.data = std::move(d.data);
    // The band axis: beside the cube in its group, else at the root.
    const std::string group = raw.key.substr(0, raw.key.find_last_of('/') + 1);
    for (const std::string& prefix : {group, std::string("/")}) {
      for (const char* name : kBandAxisNames) {
        if (!axis.key.empty() || !h5_has(path, prefix + name)) continue;
        H5Dataset a = h5_read_impl(path, prefix + name, 65536, nullptr);
        if (!is_vector_shape(a.shape, a.data.size()))
          fail(path, "dataset '" + a.name + "'",
               "a band axis must be a numeric vector of wavelengths in nm (found shape " + shape_str(a.shape) + ")");
        axis.key = a.name;
        axis.dims = a.shape;
        axis.data = std::move(a.data);
      }
    }
  }
  const std::string what = std::string(is_mat ? "variable '" : "dataset '") + raw.key + "'";
  if (raw.dims.size() != 3)
    fail(path, what, "shape " + shape_str(raw.dims) + " is not a 3-D cube (H x W x bands or bands x H x W)");
  const std::vector<std::size_t>& d = raw.dims;
  if (d[0] == 0 || d[1] == 0 || d[2] == 0) fail(path, what, "shape " + shape_str(d) + " is empty");

  // Band axis: 0 ("bhw") or 2 ("hwb"). Compared with a configured grid, a file with its own
  // band axis has that many bands (conform_band_axis compares the grids below).
  std::size_t band_axis = 0;
  const bool use_axis = !axis.key.empty() && !opt.wavelengths_nm.empty();
  const std::size_t nb = use_axis ? axis.data.size() : (opt.expected_bands ? opt.expected_bands : opt.wavelengths_nm.size());
  if (opt.layout == "auto") {
    if (nb > 0) {
      const std::size_t first = is_mat ? 2 : 0, second = is_mat ? 0 : 2;
      if (d[first] == nb) band_axis = first;
      else if (d[second] == nb) band_axis = second;
      else fail(path, what, "shape " + shape_str(d) + " has no band axis of length " + std::to_string(nb) + " (bands expected)");
    } else {
      band_axis = is_mat ? 2 : 0;
    }
  } else {
    band_axis = opt.layout == "bhw" ? 0 : 2;
    if (nb > 0 && d[band_axis] != nb)
      fail(path, what, "shape " + shape_str(d) + " with layout " + opt.layout + " has " + std::to_string(d[band_axis]) +
                           " bands, " + std::to_string(nb) + " bands expected");
  }
  const std::size_t bad = count_nonfinite(raw.data);
  if (bad) fail(path, what, std::to_string(bad) + " non-finite values");

  double scale = opt.scale;
  if (scale == 0) {
    const std::string base = raw.key.substr(raw.key.find_last_of('/') == std::string::npos ? 0 : raw.key.find_last_of('/') + 1);
    const double maxv = raw.data.empty() ? 0.0 : *std::max_element(raw.data.begin(), raw.data.end());
    if (base == "rad" && maxv <= 4095) scale = 4095;
    else scale = raw.kind.integer ? raw.kind.max : 1.0;
  }

  // (i, j, k) -> source index, in the file's memory order.
  const std::size_t d0 = d[0], d1 = d[1], d2 = d[2];
  auto src = [&](std::size_t i, std::size_t j, std::size_t k) {
    return raw.column_major ? i + d0 * (j + d1 * k) : (i * d1 + j) * d2 + k;
  };
  RealStack out = band_axis == 0 ? RealStack(d0, d1, d2) : RealStack(d2, d0, d1);
  for (std::size_t i = 0; i < d0; ++i)
    for (std::size_t j = 0; j < d1; ++j)
      for (std::size_t k = 0; k < d2; ++k) {
        const double v = raw.data[src(i, j, k)] / scale;
        if (band_axis == 0) out(i, j, k) = v;
        else out(k, i, j) = v;
      }
  if (axis.key.empty() || opt.wavelengths_nm.empty()) return out;
  const std::string awhat = std::string(is_mat ? "variable '" : "dataset '") + axis.key + "'";
  return conform_band_axis(out, axis.data, opt.wavelengths_nm, opt.resample_bands, "file '" + path + "': " + awhat);
}

namespace {

// "31 bands, 400 ... 700 nm (step 10)" or the list when it is short or irregular.
std::string grid_str(const std::vector<double>& nm) {
  std::ostringstream o;
  o << nm.size() << (nm.size() == 1 ? " band" : " bands");
  if (nm.empty()) return o.str();
  o << ", " << nm.front();
  if (nm.size() > 1) {
    const double step = (nm.back() - nm.front()) / double(nm.size() - 1);
    bool regular = true;
    for (std::size_t k = 1; k < nm.size(); ++k)
      if (std::fabs(nm[k] - nm[k - 1] - step) > 1e-6 * std::fabs(step) + 1e-9) regular = false;
    if (regular) {
      o << " ... " << nm.back() << " nm (step " << step << ")";
    } else if (nm.size() <= 8) {
      for (std::size_t k = 1; k < nm.size(); ++k) o << ", " << nm[k];
      o << " nm";
    } else {
      o << ", " << nm[1] << ", ... " << nm.back() << " nm (irregular)";
    }
  } else {
    o << " nm";
  }
  return o.str();
}

}  // namespace

RealStack conform_band_axis(const RealStack& cube, const std::vector<double>& file_nm,
                            const std::vector<double>& grid_nm, bool resample, const std::string& origin) {
  auto refuse = [&](const std::string& problem) { throw InputError(origin + ": " + problem); };
  if (file_nm.size() != cube.planes)
    refuse("the band axis has " + std::to_string(file_nm.size()) + " wavelengths but the cube has " +
           std::to_string(cube.planes) + " bands");
  for (std::size_t k = 0; k < file_nm.size(); ++k)
    if (!std::isfinite(file_nm[k]) || file_nm[k] < kBandAxisMinNm || file_nm[k] > kBandAxisMaxNm)
      refuse("band axis value " + std::to_string(k) + " = " + std::to_string(file_nm[k]) + " is not a wavelength in nm (allowed: " +
             std::to_string(int(kBandAxisMinNm)) + " to " + std::to_string(int(kBandAxisMaxNm)) + " nm; µm or metres are not converted)");
  const bool ascending = file_nm.size() < 2 || file_nm[1] > file_nm[0];
  for (std::size_t k = 1; k < file_nm.size(); ++k)
    if (ascending ? !(file_nm[k] > file_nm[k - 1]) : !(file_nm[k] < file_nm[k - 1]))
      refuse("the band axis (" + grid_str(file_nm) + ") is not strictly monotonic at index " + std::to_string(k));
  if (grid_nm.empty()) return cube;
  bool same = file_nm.size() == grid_nm.size();
  for (std::size_t k = 0; same && k < grid_nm.size(); ++k) same = std::fabs(file_nm[k] - grid_nm[k]) <= kBandAxisToleranceNm;
  if (same) return cube;
  const std::string both = "the file's bands are " + grid_str(file_nm) + (ascending ? "" : " (descending)") +
                           ", the configuration's " + grid_str(grid_nm);
  if (!resample)
    refuse(both + "; they differ by more than " + std::to_string(kBandAxisToleranceNm).substr(0, 3) +
           " nm. Configure the same bands, or resample the cube onto the configured ones (--resample-bands)");
  // Linear interpolation along wavelength, per pixel, onto the configured grid, which must
  // lie inside the file's range (no extrapolation).
  std::vector<std::size_t> order(file_nm.size());
  for (std::size_t k = 0; k < order.size(); ++k) order[k] = ascending ? k : order.size() - 1 - k;
  std::vector<double> x(order.size());
  for (std::size_t k = 0; k < order.size(); ++k) x[k] = file_nm[order[k]];
  const double lo = x.front() - kBandAxisToleranceNm, hi = x.back() + kBandAxisToleranceNm;
  for (double g : grid_nm)
    if (g < lo || g > hi)
      refuse(both + "; " + std::to_string(g) + " nm lies outside the file's range, and bands are not extrapolated");
  RealStack out(grid_nm.size(), cube.rows, cube.cols);
  const std::size_t px = cube.rows * cube.cols;
  for (std::size_t b = 0; b < grid_nm.size(); ++b) {
    const double g = std::min(std::max(grid_nm[b], x.front()), x.back());
    std::size_t j = std::size_t(std::upper_bound(x.begin(), x.end(), g) - x.begin());
    j = std::min(std::max<std::size_t>(j, 1), x.size() - 1);
    const std::size_t k0 = x.size() == 1 ? 0 : j - 1, k1 = x.size() == 1 ? 0 : j;
    const double t = x.size() == 1 ? 0.0 : (g - x[k0]) / (x[k1] - x[k0]);
    const double* p0 = cube.plane(order[k0]);
    const double* p1 = cube.plane(order[k1]);
    double* q = out.plane(b);
    for (std::size_t i = 0; i < px; ++i) q[i] = (1 - t) * p0[i] + t * p1[i];
  }
  std::cerr << "qdo: note: " << origin << ": resampled from " << grid_str(file_nm) << (ascending ? "" : " (descending)")
            << " onto the configured " << grid_str(grid_nm) << " by linear interpolation\n";
  return out;
}

RadianceReport conform_radiance(RealStack& cube, const std::string& origin) {
  RadianceReport r;
  double mn = 0, mx = 0;
  for (std::size_t i = 0; i < cube.data.size(); ++i) {
    const double v = cube.data[i];
    if (!std::isfinite(v)) throw InputError(origin + ": value " + std::to_string(i) + " is not finite");
    if (i == 0 || v < mn) mn = v;
    if (i == 0 || v > mx) mx = v;
    if (v < 0) ++r.negative;
  }
  r.min = mn;
  r.max = mx;
  if (mn < -kRadianceNegativeTolerance) {
    std::ostringstream o;
    o << origin << ": " << r.negative << " negative radiance values, down to " << mn
      << " (full scale 1); values below " << -kRadianceNegativeTolerance
      << " are refused (wrong data type, offset or scale?). Allowed: 0 to 1 after the format's scale";
    throw InputError(o.str());
  }
  if (r.negative) {
    for (double& v : cube.data) v = std::max(v, 0.0);
    std::cerr << "qdo: note: " << origin << ": " << r.negative << " slightly negative values (down to " << mn
              << ", noise of a dark-frame subtraction) clipped to 0\n";
  }
  if (mx > 1.0 + kRadianceOverTolerance) {
    r.divided_by = mx;
    for (double& v : cube.data) v /= mx;
    std::cerr << "qdo: note: " << origin << ": values up to " << mx
              << " times full scale (HDR or unscaled data) divided by that maximum, so the brightest value is 1\n";
  } else if (mx > 1.0) {
    for (double& v : cube.data) v = std::min(v, 1.0);
  }
  return r;
}

}  // namespace qdo
