// Private to the as-built fit (fit_model.cpp, fit_parameters.cpp, fit.cpp, fit_starts.cpp): timing,
// number formatting and the search for the start.
#pragma once
#include <chrono>
#include <cstdio>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "qdo/asbuilt/fit.hpp"

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

// Each pixel's level (N x N row-major): the index of the design level nearest its height (all 0
// for a design without a level table).
std::vector<int> design_level_map(const Design& design);

// Where the fit starts. theta: the design values on entry; on return the lowest start: the
// centroid difference of the measured and design stacks (bands x S x S each) for shift (when
// fitted, else offset), the values of opt.start, then, with opt.lateral_starts != 1, the lowest of
// the lateral grid (K x K, or automatic: scans of the offset an eighth of a DOE pixel apart, a
// half-pixel grid of the shift alone) and the mirrors of the lowest.
struct LateralStarts {
  std::vector<std::pair<double, std::vector<double>>> starts;  // (loss, theta) of each start tried
  std::size_t lateral_index = 0;     // the first lateral parameter (dx, else sx); p without a grid
  double min_separation = 0;         // starts closer than this (the parameter's unit) share a basin
  std::pair<double, double> centroid_shift_px{0, 0};
};
LateralStarts find_lateral_starts(AsBuiltModel& model, const SystemConfig& cfg, const RealStack& measured, const RealStack& design_psf,
                                  const FitOptions& opt, std::vector<double>& theta, const std::function<void(const std::string&)>& say);

}  // namespace qdo::fit_detail
