#include "qdo/physics/point_psf.hpp"

#include <algorithm>
#include <cmath>

#include "qdo/runtime/error.hpp"

namespace qdo {

RealStack point_planes(const RealStack& stack, std::size_t point, std::size_t bands) {
  if (bands == 0 || stack.planes % bands != 0)
    reject("bands", bands, "a divisor of the stack's " + std::to_string(stack.planes) + " planes (points x bands)");
  const std::size_t points = stack.planes / bands;
  if (point >= points) reject("object point", point, "an index below the stack's " + std::to_string(points) + " points");
  RealStack out(bands, stack.rows, stack.cols);
  const std::size_t n = bands * stack.plane_size();
  std::copy(stack.data.begin() + static_cast<std::ptrdiff_t>(point * n),
            stack.data.begin() + static_cast<std::ptrdiff_t>((point + 1) * n), out.data.begin());
  return out;
}

std::pair<double, double> chief_ray_offset_px(const SystemConfig& c, const ObjectPoint& p) {
  const auto img = chief_ray_image_m(c, p);
  return {img.second / c.sensor_pitch_m, img.first / c.sensor_pitch_m};
}

RealStack shift_planes(const RealStack& stack, long dy_px, long dx_px) {
  RealStack out(stack.planes, stack.rows, stack.cols);
  const long rows = static_cast<long>(stack.rows), cols = static_cast<long>(stack.cols);
  for (std::size_t q = 0; q < stack.planes; ++q)
    for (long y = 0; y < rows; ++y) {
      const long sy = y + dy_px;
      if (sy < 0 || sy >= rows) continue;
      for (long x = 0; x < cols; ++x) {
        const long sx = x + dx_px;
        if (sx < 0 || sx >= cols) continue;
        out(q, static_cast<std::size_t>(y), static_cast<std::size_t>(x)) =
            stack(q, static_cast<std::size_t>(sy), static_cast<std::size_t>(sx));
      }
    }
  return out;
}

RealStack recentre_on_chief_ray(const RealStack& planes, const SystemConfig& c, const ObjectPoint& p, double* lost) {
  if (lost) *lost = 0;
  if (p.on_axis()) return planes;
  const auto off = chief_ray_offset_px(c, p);
  const RealStack out = shift_planes(planes, std::lround(off.first), std::lround(off.second));
  if (lost) {
    for (std::size_t q = 0; q < planes.planes; ++q) {
      double before = 0, after = 0;
      for (std::size_t i = 0; i < planes.plane_size(); ++i) {
        before += planes.plane(q)[i];
        after += out.plane(q)[i];
      }
      if (before > 0) *lost = std::max(*lost, (before - after) / before);
    }
  }
  return out;
}

}  // namespace qdo
