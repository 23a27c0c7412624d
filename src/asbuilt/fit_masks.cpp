// The relief of a quantized design's lithography masks, each moved by its own overlay (fit.hpp,
// parameter "overlay"): the masks of a design (fit_mask_set, overlay_parameter_names are in
// fit_parameters.cpp), the relief and its vector-Jacobian product.
#include <algorithm>
#include <string>
#include <vector>

#include "qdo/runtime/error.hpp"

#include "fit_internal.hpp"

namespace qdo::fit_detail {

namespace {

// Mask m's opening moved by (ox, oy) metres as area fractions (N x N; shift_bilinear, exact for an
// opening of whole pixels), or its derivative along axis 1 (x) or 0 (y).
std::vector<double> moved_opening(const FitMaskSet& ms, std::size_t m, double ox_m, double oy_m, double pitch_m, int derivative_axis = -1) {
  const std::vector<double> open(ms.open[m].begin(), ms.open[m].end());
  const double sx = ox_m / pitch_m, sy = oy_m / pitch_m;
  if (derivative_axis < 0) return sx == 0 && sy == 0 ? open : shift_bilinear(open, 1, ms.n, ms.n, sx, sy);
  return shift_bilinear_derivative(open, 1, ms.n, ms.n, sx, sy, derivative_axis);
}

void check_sizes(const FitMaskSet& ms, std::size_t etch, std::size_t ox, std::size_t oy) {
  const std::size_t K = ms.open.size();
  if (etch != K || ox != K || oy != K)
    throw Error("mask_relief: " + std::to_string(K) + " masks, " + std::to_string(etch) + " etch depths, " + std::to_string(ox) + " and " +
                std::to_string(oy) + " overlays");
}

}  // namespace

std::vector<double> mask_etch_depths(const FitMaskSet& ms, const std::vector<double>& lev, const std::vector<double>& masks, double& top) {
  const std::size_t K = ms.open.size();
  std::vector<double> e(K, 0.0);
  if (ms.binary) {
    if (masks.size() != K) throw Error("mask_etch_depths: " + std::to_string(masks.size()) + " mask depths for " + std::to_string(K) + " masks");
    top = 0;
    for (std::size_t j = 0; j < K; ++j) top += e[j] = masks[j];
    return e;
  }
  top = lev.at(ms.order.at(0));
  for (std::size_t m = 1; m <= K; ++m) e[m - 1] = lev.at(ms.order[m - 1]) - lev.at(ms.order[m]);
  return e;
}

void mask_etch_depths_vjp(const FitMaskSet& ms, double g_top, const std::vector<double>& g_etch, std::vector<double>& g_lev,
                          std::vector<double>& g_masks) {
  const std::size_t K = ms.open.size();
  if (ms.binary) {
    for (std::size_t j = 0; j < K; ++j) g_masks.at(j) += g_top + g_etch.at(j);
    return;
  }
  g_lev.at(ms.order.at(0)) += g_top;
  for (std::size_t m = 1; m <= K; ++m) {
    g_lev.at(ms.order[m - 1]) += g_etch.at(m - 1);
    g_lev.at(ms.order[m]) -= g_etch.at(m - 1);
  }
}

std::vector<double> mask_relief(const FitMaskSet& ms, const std::vector<double>& etch_m, double top_m, const std::vector<double>& ox_m,
                                const std::vector<double>& oy_m, double pitch_m) {
  check_sizes(ms, etch_m.size(), ox_m.size(), oy_m.size());
  std::vector<double> h(ms.n * ms.n, top_m);
  for (std::size_t m = 0; m < etch_m.size(); ++m) {
    const std::vector<double> a = moved_opening(ms, m, ox_m[m], oy_m[m], pitch_m);
    for (std::size_t i = 0; i < h.size(); ++i) h[i] -= etch_m[m] * a[i];
  }
  return h;
}

void mask_relief_vjp(const FitMaskSet& ms, const std::vector<double>& etch_m, const std::vector<double>& ox_m,
                     const std::vector<double>& oy_m, double pitch_m, const std::vector<double>& g_h, double& g_top,
                     std::vector<double>& g_etch, std::vector<double>& g_ox, std::vector<double>& g_oy) {
  check_sizes(ms, etch_m.size(), ox_m.size(), oy_m.size());
  const std::size_t K = etch_m.size(), nn = ms.n * ms.n;
  if (g_h.size() != nn) throw Error("mask_relief_vjp: the gradient holds " + std::to_string(g_h.size()) + " values, expected N x N");
  g_top = 0;
  for (double g : g_h) g_top += g;
  g_etch.assign(K, 0.0);
  g_ox.assign(K, 0.0);
  g_oy.assign(K, 0.0);
  for (std::size_t mk = 0; mk < K; ++mk) {
    const std::vector<double> a = moved_opening(ms, mk, ox_m[mk], oy_m[mk], pitch_m);
    for (std::size_t i = 0; i < nn; ++i) g_etch[mk] -= g_h[i] * a[i];
    if (mk == 0) continue;  // the first mask defines the alignment: no overlay
    const std::vector<double> ax = moved_opening(ms, mk, ox_m[mk], oy_m[mk], pitch_m, 1),
                              ay = moved_opening(ms, mk, ox_m[mk], oy_m[mk], pitch_m, 0);
    for (std::size_t i = 0; i < nn; ++i) {
      g_ox[mk] -= etch_m[mk] * g_h[i] * ax[i] / pitch_m;
      g_oy[mk] -= etch_m[mk] * g_h[i] * ay[i] / pitch_m;
    }
  }
}

}  // namespace qdo::fit_detail
