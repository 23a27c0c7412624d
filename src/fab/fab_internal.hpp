// Helpers shared by the fab sources (src/fab/*.cpp): number and pixel
// formatting for messages and the mask sheet, and the level limit of each scheme. Private to
// the library (not installed); the public API is include/qdo/fab/fab.hpp.
#pragma once
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

#include "qdo/runtime/error.hpp"
#include "qdo/fab/fab.hpp"

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

// The mask plan of a scheme name as qdo tolerance and qdo fabricate take it: binary, nested,
// greyscale, or auto (binary when the levels allow it, else nested); `note` says which and why.
inline MaskPlan plan_masks_named(const Design& d, const SystemConfig& cfg, const std::string& scheme, const Constraints& c,
                                 std::string& note) {
  if (scheme != "auto") {
    note = scheme;
    return plan_masks(d, cfg, scheme_from_string(scheme), c);
  }
  try {
    MaskPlan p = plan_masks(d, cfg, Scheme::Binary, c);
    note = "auto: binary-coded masks";
    return p;
  } catch (const InputError& e) {
    note = std::string("auto: nested masks (binary not possible: ") + e.what() + ")";
    return plan_masks(d, cfg, Scheme::Nested, c);
  }
}

// The errors of trial k of the tolerance study (seed): per mask an etch depth error uniform in
// [-depth_m, depth_m] (stream 1), and per mask after the first (which defines the alignment
// marks; none for one greyscale write) an overlay shift per axis uniform in [-overlay_m,
// overlay_m] (streams 2, 3). One draw sequence for qdo tolerance and qdo fabricate.
inline void draw_trial_errors(std::uint64_t seed, std::size_t k, const MaskPlan& plan, double depth_m, double overlay_m,
                              std::vector<double>& depth_error_m, std::vector<double>& shift_x_m, std::vector<double>& shift_y_m) {
  const std::size_t K = plan.masks.size();
  const bool single_write = plan.scheme == Scheme::Greyscale;
  depth_error_m.assign(K, 0.0);
  shift_x_m.assign(K, 0.0);
  shift_y_m.assign(K, 0.0);
  for (std::size_t m = 0; m < K; ++m) {
    depth_error_m[m] = depth_m * sym_uniform(seed, 1, k * K + m);
    const bool moves = m > 0 && !single_write;
    shift_x_m[m] = moves ? overlay_m * sym_uniform(seed, 2, k * K + m) : 0.0;
    shift_y_m[m] = moves ? overlay_m * sym_uniform(seed, 3, k * K + m) : 0.0;
  }
}

inline int scheme_max_levels(Scheme s) { return s == Scheme::Greyscale ? kMaxMaskLayers : 16; }

}  // namespace qdo::fab
