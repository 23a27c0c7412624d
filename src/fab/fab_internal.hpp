// Helpers shared by the fab sources (src/fab/fab_plan.cpp, src/fab/fab_export.cpp): number and pixel
// formatting for messages and the mask sheet, and the level limit of each scheme. Private to
// the library (not installed); the public API is include/qdo/fab.hpp.
#pragma once
#include <cstddef>
#include <cstdio>
#include <string>

#include "qdo/fab.hpp"

namespace qdo::fab {

inline std::string nm(double metres, int digits = 3) {
  char b[64];
  std::snprintf(b, sizeof b, "%.*f", digits, metres * 1e9);
  return b;
}

inline std::string pixel_name(std::size_t idx, std::size_t n) {
  return "pixel (row " + std::to_string(idx / n) + ", col " + std::to_string(idx % n) + ")";
}

inline int scheme_max_levels(Scheme s) { return s == Scheme::Greyscale ? kMaxMaskLayers : 16; }

}  // namespace qdo::fab
