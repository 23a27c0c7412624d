// Summary numbers of a PSF plane (psf_metrics.hpp).
#include "qdo/physics/psf_metrics.hpp"

#include <algorithm>
#include <cmath>
#include <utility>
#include <vector>

namespace qdo {

double encircled_radius_m(const double* plane, std::size_t rows, std::size_t cols, double pitch_m, double cx_m, double cy_m,
                          double fraction) {
  std::vector<std::pair<double, double>> by_radius;  // (distance to the centre in m, energy)
  by_radius.reserve(rows * cols);
  double total = 0;
  for (std::size_t y = 0; y < rows; ++y)
    for (std::size_t x = 0; x < cols; ++x) {
      const double v = std::max(0.0, plane[y * cols + x]);
      const double dx = (double(x) - double(cols / 2)) * pitch_m - cx_m, dy = (double(y) - double(rows / 2)) * pitch_m - cy_m;
      by_radius.emplace_back(std::hypot(dx, dy), v);
      total += v;
    }
  if (total <= 0) return 0;
  std::sort(by_radius.begin(), by_radius.end());
  const double goal = fraction * total;
  double acc = 0, prev_r = 0;
  for (const auto& [r, v] : by_radius) {
    if (acc + v >= goal) return v > 0 ? prev_r + (r - prev_r) * (goal - acc) / v : r;
    acc += v;
    prev_r = r;
  }
  return by_radius.back().first;
}

PsfPlaneMetrics psf_plane_metrics(const double* plane, std::size_t rows, std::size_t cols, double pitch_m) {
  PsfPlaneMetrics m;
  double sx = 0, sy = 0;
  for (std::size_t y = 0; y < rows; ++y)
    for (std::size_t x = 0; x < cols; ++x) {
      const double v = std::max(0.0, plane[y * cols + x]);
      m.sum += v;
      m.peak = std::max(m.peak, v);
      sx += v * (double(x) - double(cols / 2)) * pitch_m;
      sy += v * (double(y) - double(rows / 2)) * pitch_m;
    }
  if (m.sum <= 0) return m;
  m.centroid_x_m = sx / m.sum;
  m.centroid_y_m = sy / m.sum;
  m.ee80_radius_m = encircled_radius_m(plane, rows, cols, pitch_m, m.centroid_x_m, m.centroid_y_m, 0.8);
  return m;
}

}  // namespace qdo
