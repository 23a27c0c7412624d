// Private to the as-built fit (fit_model.cpp, fit_parameters.cpp, fit.cpp, fit_starts.cpp, fit_sigma.cpp,
// fit_jacobian.cpp, fit_masks.cpp): timing,
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

// The masks' etch depths (one per mask) and the blank's top (metres; fit_masks.cpp): binary, the
// mask depths and their sum; nested, the steps between the used levels (lev, the level table) in
// ms.order and the highest. Its transpose adds dL/dtop and dL/detch onto g_lev (nested, one per
// level) or g_masks (binary, one per mask).
std::vector<double> mask_etch_depths(const FitMaskSet& ms, const std::vector<double>& lev, const std::vector<double>& masks, double& top);
void mask_etch_depths_vjp(const FitMaskSet& ms, double g_top, const std::vector<double>& g_etch, std::vector<double>& g_lev,
                          std::vector<double>& g_masks);

// The masks' relief (fit_masks.cpp; fit.hpp, parameter "overlay"): top - sum_m etch_m[m] a_m, a_m
// mask m's opening (ms.open[m], N x N) moved by (ox_m[m], oy_m[m]) metres as the area of each DOE
// pixel it covers; N x N row-major, metres. One etch depth and overlay per mask.
std::vector<double> mask_relief(const FitMaskSet& ms, const std::vector<double>& etch_m, double top_m, const std::vector<double>& ox_m,
                                const std::vector<double>& oy_m, double pitch_m);
// Its vector-Jacobian product: from g_h = dL/dh (N x N), dL/dtop, dL/detch_m and dL/dox_m,
// dL/doy_m (per metre; the right derivative on a whole pixel; 0 for the first mask, which holds
// the alignment).
void mask_relief_vjp(const FitMaskSet& ms, const std::vector<double>& etch_m, const std::vector<double>& ox_m,
                     const std::vector<double>& oy_m, double pitch_m, const std::vector<double>& g_h, double& g_top,
                     std::vector<double>& g_etch, std::vector<double>& g_ox, std::vector<double>& g_oy);

// How one column of the fit's Jacobian is differenced (difference_jacobian).
struct JacobianColumn {
  // Plain: central, or with the model at theta one-sided from it when one_sided; a step past the
  // simulator's range (an InputError) backward. Overlay: inside the current DOE pixel cell (the
  // relief kinks at whole pixels). Offset: on the offset's side of a half-pixel switch
  // (move_relief's whole pixels switch there), else as Plain.
  enum class Scheme { Plain, Overlay, Offset };
  Scheme scheme = Scheme::Plain;
  double step = 0;         // the difference step, in the parameter's unit
  bool late = false;       // taken after the others (its evaluations rebuild the simulator or re-integrate)
  bool one_sided = false;  // with the model at theta given: one-sided from it (Plain)
  double pitch_m = 0;      // Overlay, Offset: the DOE pitch
  double axis_m = 0;       // Offset: the configuration's optical-axis offset along the parameter's axis
};
// J (rows x p, the model's values x the parameters) of model at theta, column k as columns[k]
// says; at_theta: model(theta) when known (rows values), which the one-sided columns reuse.
Eigen::MatrixXd difference_jacobian(const std::function<RealStack(const std::vector<double>&)>& model, const std::vector<double>& theta,
                                    const std::vector<JacobianColumn>& columns, std::size_t rows, const RealStack* at_theta);

// The uncertainties at theta (fit_sigma.cpp): res.values (names, units, design values theta0,
// values, curvature sigma, jackknife sigma over jackknife_groups band groups when >= 2), the
// correlation, the degenerate pairs, the condition, residual_sigma (s^2 = 2 loss / dof),
// jackknife_groups and model_psf (the model at theta, bands x S x S). The Jacobian is the model's
// central one at theta; its solve time goes to model.times().
void fit_uncertainties(AsBuiltModel& model, const SystemConfig& cfg, const RealStack& measured, const std::vector<double>& theta,
                       const std::vector<double>& theta0, double loss, double dof, int jackknife_groups, FitResult& res);
// The verdict on sigma (FitResult::sigma_reliable, sigma_unreliable_because) from res.values,
// residual_rel_fit and residual_sigma; with a hint to fit the overlay where the design was made with
// several masks and opt does not fit it.
void fit_sigma_verdict(const Design& design, const FitOptions& opt, FitResult& res);

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
