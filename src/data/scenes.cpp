#include "qdo/data/scenes.hpp"

#include <algorithm>
#include <cmath>
#include <filesystem>

#include "qdo/data/datasets.hpp"
#include "qdo/runtime/embedded.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"

namespace qdo {

std::vector<double> interpolate_spectrum(const std::vector<double>& wl_nm, const std::vector<double>& values,
                                         const std::vector<double>& at_nm, const std::string& what) {
  std::vector<double> out;
  for (double w : at_nm) {
    if (wl_nm.empty() || w < wl_nm.front() - 1e-9 || w > wl_nm.back() + 1e-9)
      reject("wavelengths", w, what + " is tabulated from " + to_str(wl_nm.empty() ? 0 : wl_nm.front()) + " to " +
                                   to_str(wl_nm.empty() ? 0 : wl_nm.back()) + " nm");
    std::size_t r = 1;
    while (r < wl_nm.size() - 1 && wl_nm[r] < w) ++r;
    if (wl_nm.size() == 1) {
      out.push_back(values[0]);
      continue;
    }
    const double f = std::clamp((w - wl_nm[r - 1]) / (wl_nm[r] - wl_nm[r - 1]), 0.0, 1.0);
    out.push_back((1 - f) * values[r - 1] + f * values[r]);
  }
  return out;
}

RealStack builtin_chart_scene(const SystemConfig& cfg) {
  const auto bands = cfg.wavelengths_nm();
  const CsvTable d65 = parse_csv(embedded_file("cie_d65_400-700nm_10nm.csv"), "built-in D65 table");
  const CsvTable cc = parse_csv(embedded_file("colorchecker24_400-700nm_10nm.csv"), "built-in ColorChecker table");
  std::vector<double> illum = interpolate_spectrum(d65.column("wavelength_nm"), d65.column("relative_power"), bands, "D65");
  const double peak = *std::max_element(d65.column("relative_power").begin(), d65.column("relative_power").end());
  for (double& v : illum) v /= peak;
  // ColorChecker: columns are wavelengths (header "400".."700"), rows are patches.
  std::vector<double> cc_wl;
  for (std::size_t c = 1; c < cc.header.size(); ++c) cc_wl.push_back(std::stod(cc.header[c]));
  const std::size_t patches = cc.columns[0].size();
  std::vector<std::vector<double>> refl(patches);
  for (std::size_t p = 0; p < patches; ++p) {
    std::vector<double> r;
    for (std::size_t c = 1; c < cc.header.size(); ++c) r.push_back(cc.columns[c][p]);
    refl[p] = interpolate_spectrum(cc_wl, r, bands, "the ColorChecker table");
  }
  const std::size_t s = cfg.scene_size_px;
  RealStack cube(bands.size(), s, s, 0.0);
  const double margin = 0.08 * double(s), cell_w = (double(s) - 2 * margin) / 6.0, cell_h = (double(s) - 2 * margin) / 4.0;
  for (std::size_t y = 0; y < s; ++y) {
    const double shade = 0.75 + 0.25 * double(y) / double(s);
    for (std::size_t x = 0; x < s; ++x) {
      const double u = (double(x) - margin) / cell_w, v = (double(y) - margin) / cell_h;
      double gap_u = u - std::floor(u), gap_v = v - std::floor(v);
      const bool inside = u >= 0 && u < 6 && v >= 0 && v < 4 && gap_u > 0.08 && gap_u < 0.92 && gap_v > 0.08 && gap_v < 0.92;
      for (std::size_t b = 0; b < bands.size(); ++b) {
        const double r = inside ? refl[static_cast<std::size_t>(v) * 6 + static_cast<std::size_t>(u)][b] : 0.03;
        cube(b, y, x) = shade * r * illum[b];
      }
    }
  }
  // Three bright white dots along the top margin.
  for (int k = 1; k <= 3; ++k) {
    const std::size_t cx = std::size_t(double(s) * k / 4.0), cy = std::size_t(margin / 2);
    for (std::size_t b = 0; b < bands.size(); ++b) cube(b, cy, cx) = 1.0;
  }
  return cube;
}

RealStack read_scene(const SystemConfig& cfg, const std::string& path, const std::string& key, bool resample_bands,
                     const std::string& key_argument) {
  if (path == "builtin") return builtin_chart_scene(cfg);
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec)) {  // a CAVE folder of PNG bands, as --data takes
    if (!key.empty()) reject(key_argument, key, "omitted for a PNG band folder (" + path + ")");
    RealStack png = read_png_band_folder(path, cfg.bands);
    conform_radiance(png, "folder '" + path + "'");
    return png;
  }
  CubeReadOptions o;
  o.key = key;
  o.expected_bands = cfg.bands;
  o.wavelengths_nm = cfg.wavelengths_nm();
  o.resample_bands = resample_bands;
  RealStack cube = read_cube(path, o);
  conform_radiance(cube, "file '" + path + "'");
  return cube;
}

}  // namespace qdo
