// Adjoints of the DOE parameterizations and of the quantizer (the host forward maps are
// doe.hpp's expand_parameters and quantize_heights; kernels/doe.cl runs them on the device), in
// double.
#pragma once
#include <cstddef>
#include <vector>

#include "qdo/physics/doe.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo::ref {

// Adjoint of expand_parameters: gradient on the N x N map -> gradient on the parameters
// (sums over the samples each parameter drives; the clamp passes the gradient only where the
// parameter lies strictly inside (0, h_max) or on the side that moves it inward).
std::vector<double> expand_parameters_vjp(Parameterization p, const std::vector<double>& params, std::size_t n,
                                          double h_max_m, const Map2D& g_heights);

// Adjoint of quantize_heights (alpha blending, REFERENCE §2): the gradient reaches H_f only
// through the (1 - alpha) branch, or unchanged with the straight-through estimator (ste = true).
// Also the gradient with respect to the adaptive offsets a_l (size L; a_0's entry is 0):
// dH/da_l = alpha * h_max * 0.5 / denom on samples quantized to level l.
struct QuantizeVjp {
  Map2D g_full;                  // N x N
  std::vector<double> g_offsets; // L
  std::vector<double> g_levels;  // L: dL/du_l for the normalised level values (any level table)
};
QuantizeVjp quantize_vjp(const Map2D& h_full_m, double h_max_m, const Quantizer& q, double alpha, const Map2D& g_out,
                         bool ste = false);

}  // namespace qdo::ref
