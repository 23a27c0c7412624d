// Private to src/asbuilt: what reconstruct.cpp and capture.cpp (qdo reconstruct's stages) share.
#pragma once

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <sstream>
#include <string>
#include <vector>

#include "qdo/runtime/error.hpp"
#include "qdo/runtime/util.hpp"

namespace qdo::reconstruct_detail {

// A number of `s` in [lo, hi] (lo excluded when lo_open); InputError naming `argument` and the whole value.
inline double number_in(const std::string& s, const std::string& argument, const std::string& whole, double lo, double hi, bool lo_open,
                        const std::string& allowed) {
  char* end = nullptr;
  const double v = std::strtod(s.c_str(), &end);
  if (s.empty() || *end || !std::isfinite(v) || v > hi || (lo_open ? v <= lo : v < lo)) reject(argument, whole, allowed);
  return v;
}

}  // namespace qdo::reconstruct_detail
