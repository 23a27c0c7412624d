// Helpers shared by the fab sources (src/fab/*.cpp): number and pixel
// formatting for messages and the mask sheet, and the level limit of each scheme. Private to
// the library (not installed); the public API is include/qdo/fab.hpp.
#pragma once
#include <cstddef>
#include <cstdint>
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

// The tolerance study's random draws (fab_tolerance.cpp, fab_asbuilt.cpp): uniform in [-1, 1)
// from (seed, stream, index), portable across standard libraries.
inline std::uint64_t splitmix64(std::uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}
inline double sym_uniform(std::uint64_t seed, std::uint64_t stream, std::uint64_t index) {
  const std::uint64_t r = splitmix64(splitmix64(seed ^ splitmix64(stream)) + index);
  return double(r >> 11) * (2.0 / 9007199254740992.0) - 1.0;
}

inline int scheme_max_levels(Scheme s) { return s == Scheme::Greyscale ? kMaxMaskLayers : 16; }

}  // namespace qdo::fab
