// Private to src/design: what reconstruct.cpp and capture.cpp (qdo reconstruct's stages) share.
#pragma once

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <sstream>
#include <string>
#include <vector>

#include "qdo/error.hpp"

namespace qdo::reconstruct_detail {

inline double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// A number of `s` in [lo, hi] (lo excluded when lo_open); InputError naming `argument` and the whole value.
inline double number_in(const std::string& s, const std::string& argument, const std::string& whole, double lo, double hi, bool lo_open,
                        const std::string& allowed) {
  char* end = nullptr;
  const double v = std::strtod(s.c_str(), &end);
  if (s.empty() || *end || !std::isfinite(v) || v > hi || (lo_open ? v <= lo : v < lo)) reject(argument, whole, allowed);
  return v;
}

inline std::vector<std::string> split(const std::string& s, char sep) {
  std::vector<std::string> out;
  std::stringstream ss(s);
  for (std::string x; std::getline(ss, x, sep);) out.push_back(x);
  if (!s.empty() && s.back() == sep) out.push_back("");
  return out;
}

}  // namespace qdo::reconstruct_detail
