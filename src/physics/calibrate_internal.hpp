// Helpers shared by qdo calibrate's steps (calibrate.cpp, calibrate_centre.cpp, calibrate_crop.cpp).
#pragma once
#include <algorithm>
#include <cstddef>
#include <vector>

namespace qdo::calibrate_detail {

// The median of v (the upper one of an even count; 0 when empty).
inline double median_of(std::vector<double> v) {
  if (v.empty()) return 0;
  const std::size_t m = v.size() / 2;
  std::nth_element(v.begin(), v.begin() + long(m), v.end());
  return v[m];
}

}  // namespace qdo::calibrate_detail
