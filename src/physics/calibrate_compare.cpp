// Measured against simulated PSF stacks, band by band (calibrate.hpp: compare_psf_stacks).
#include "qdo/physics/calibrate.hpp"

#include <algorithm>
#include <cmath>
#include <utility>
#include <vector>

#include "qdo/runtime/error.hpp"

namespace qdo {

std::vector<PsfBandComparison> compare_psf_stacks(const RealStack& a, const RealStack& b) {
  if (a.planes != b.planes || a.rows != b.rows || a.cols != b.cols)
    throw InputError("compare_psf_stacks: stacks of different shapes");
  const std::size_t n = a.rows * a.cols;
  std::vector<PsfBandComparison> out(a.planes);
  auto centroid = [&](const RealStack& st, std::size_t p, double& cy, double& cx) {
    double t = 0;
    cy = cx = 0;
    for (std::size_t y = 0; y < st.rows; ++y)
      for (std::size_t x = 0; x < st.cols; ++x) {
        const double v = st(p, y, x);
        t += v;
        cy += v * double(y);
        cx += v * double(x);
      }
    if (t > 0) cy /= t, cx /= t;
    return t;
  };
  auto ee80 = [&](const RealStack& st, std::size_t p, double cy, double cx, double tot) {
    std::vector<std::pair<double, double>> rv;
    for (std::size_t y = 0; y < st.rows; ++y)
      for (std::size_t x = 0; x < st.cols; ++x) rv.push_back({std::hypot(double(y) - cy, double(x) - cx), st(p, y, x)});
    std::sort(rv.begin(), rv.end());
    double acc = 0;
    for (const auto& e : rv)
      if ((acc += e.second) >= 0.8 * tot) return e.first;
    return rv.empty() ? 0.0 : rv.back().first;
  };
  for (std::size_t p = 0; p < a.planes; ++p) {
    double ma = 0, mb = 0;
    for (std::size_t i = 0; i < n; ++i) ma += a.data[p * n + i], mb += b.data[p * n + i];
    ma /= double(n), mb /= double(n);
    double sab = 0, saa = 0, sbb = 0;
    for (std::size_t i = 0; i < n; ++i) {
      const double da = a.data[p * n + i] - ma, db = b.data[p * n + i] - mb;
      sab += da * db, saa += da * da, sbb += db * db;
    }
    out[p].correlation = saa > 0 && sbb > 0 ? sab / std::sqrt(saa * sbb) : 0;
    double ay, ax, by, bx;
    const double ta = centroid(a, p, ay, ax), tb = centroid(b, p, by, bx);
    out[p].ee80_measured_px = ee80(a, p, ay, ax, ta);
    out[p].ee80_simulated_px = ee80(b, p, by, bx, tb);
    out[p].centroid_offset_px = std::hypot(ay - by, ax - bx);
  }
  return out;
}

}  // namespace qdo
