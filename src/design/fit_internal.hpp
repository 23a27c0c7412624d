// Private to the as-built fit (fit_model.cpp, fit.cpp): timing and number formatting.
#pragma once
#include <chrono>
#include <cstdio>
#include <string>

namespace qdo::fit_detail {

// Seconds since t0.
inline double since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// One number through a printf format ("%.3g").
inline std::string fmt(const char* f, double v) {
  char b[64];
  std::snprintf(b, sizeof b, f, v);
  return b;
}

}  // namespace qdo::fit_detail
