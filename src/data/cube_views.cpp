// Views of a spectral cube (cube_views.hpp): regions, their spectra, the sRGB render.
#include "qdo/data/cube_views.hpp"

#include <algorithm>
#include <cstdlib>

#include "qdo/data/io.hpp"
#include "qdo/data/scenes.hpp"
#include "qdo/runtime/embedded.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/util.hpp"

namespace qdo {

std::string SpectrumRegion::label() const {
  return box ? "box " + to_str(row) + "," + to_str(col) + "," + to_str(rows) + "," + to_str(cols) : "point " + to_str(row) + "," + to_str(col);
}

std::vector<SpectrumRegion> parse_regions(const std::string& s, bool boxes, const std::string& argument) {
  std::vector<SpectrumRegion> out;
  if (s.empty()) return out;
  const std::string allowed = boxes ? "ROW,COL,H,W boxes separated by ';' (integers, H, W >= 1)" : "ROW,COL points separated by ';' (integers >= 0)";
  for (const std::string& item : split_fields(s, ';')) {
    const auto f = split_fields(item, ',');
    if (f.size() != (boxes ? 4u : 2u)) reject(argument, item, allowed);
    std::vector<std::size_t> v;
    for (const std::string& x : f) {
      char* end = nullptr;
      const long long n = std::strtoll(x.c_str(), &end, 10);
      if (x.empty() || *end || n < 0 || n > (1LL << 28)) reject(argument, item, allowed);
      v.push_back(std::size_t(n));
    }
    SpectrumRegion r;
    r.row = v[0];
    r.col = v[1];
    r.box = boxes;
    if (boxes) {
      r.rows = v[2];
      r.cols = v[3];
      if (r.rows == 0 || r.cols == 0) reject(argument, item, allowed);
    }
    out.push_back(r);
  }
  return out;
}

std::vector<std::vector<double>> region_spectra(const RealStack& cube, const std::vector<SpectrumRegion>& regions,
                                                const std::string& argument) {
  std::vector<std::vector<double>> out;
  for (const SpectrumRegion& r : regions) {
    if (r.row + r.rows > cube.rows || r.col + r.cols > cube.cols)
      reject(argument, r.label(), "inside the reconstructed " + to_str(cube.rows) + " x " + to_str(cube.cols) + " image (after --crop)");
    std::vector<double> s(cube.planes, 0.0);
    for (std::size_t b = 0; b < cube.planes; ++b) {
      double sum = 0;
      for (std::size_t y = r.row; y < r.row + r.rows; ++y)
        for (std::size_t x = r.col; x < r.col + r.cols; ++x) sum += cube(b, y, x);
      s[b] = sum / double(r.rows * r.cols);
    }
    out.push_back(std::move(s));
  }
  return out;
}

RealStack render_srgb(const RealStack& cube, const std::vector<double>& wl) {
  const CsvTable t = parse_csv(embedded_file("cie1931_cmf_400-700nm_10nm.csv"), "built-in CIE 1931 table");
  const auto xb = interpolate_spectrum(t.column("wavelength_nm"), t.column("xbar"), wl, "CIE 1931");
  const auto yb = interpolate_spectrum(t.column("wavelength_nm"), t.column("ybar"), wl, "CIE 1931");
  const auto zb = interpolate_spectrum(t.column("wavelength_nm"), t.column("zbar"), wl, "CIE 1931");
  double ysum = 0;
  for (double v : yb) ysum += v;
  const double m[3][3] = {{3.2406, -1.5372, -0.4986}, {-0.9689, 1.8758, 0.0415}, {0.0557, -0.2040, 1.0570}};
  RealStack out(3, cube.rows, cube.cols);
  for (std::size_t p = 0; p < cube.plane_size(); ++p) {
    double xyz[3] = {0, 0, 0};
    for (std::size_t b = 0; b < cube.planes; ++b) {
      const double v = cube.plane(b)[p] / ysum;
      xyz[0] += v * xb[b];
      xyz[1] += v * yb[b];
      xyz[2] += v * zb[b];
    }
    for (int c = 0; c < 3; ++c) out.plane(std::size_t(c))[p] = std::max(0.0, m[c][0] * xyz[0] + m[c][1] * xyz[1] + m[c][2] * xyz[2]);
  }
  return out;
}

}  // namespace qdo
