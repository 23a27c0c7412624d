// Adjoints (vector-Jacobian products) of the PSF chain, CPU reference in double.
//
// Gradient convention for complex quantities: g = dL/dRe(z) + i dL/dIm(z). For a complex-linear
// map y = A x this gives g_x = A^H g_y. For the PSF chain (per band b):
//   U1 = A exp(i theta_b),  theta_b = k_b (src(r) + dn_b H)       (doe_field)
//   U2 = F^-1 (T_b . F U1)                                       (propagate; adjoint = propagate over -z)
//   P  = |U2|^2 on the central N x N                              (g_U2 = 2 g_P U2 there, 0 elsewhere)
//   p  = P / sum(P)                                               (g_P = (g_p - <g_p, p>) / sum(P))
//   S  = W p W^T (area resampling)                                (g_p = W^T g_S W)
//   s  = S / sum(S)
//   dL/dH = sum_b k_b dn_b Re(conj(g_U1) i U1)
#pragma once
#include <Eigen/Dense>

#include "qdo/config.hpp"
#include "qdo/doe.hpp"
#include "qdo/optics.hpp"
#include "qdo/types.hpp"

namespace qdo::ref {

// VJP of ref::convolve with respect to the PSF stack: cube bands x H x W, g_out bands x H x W ->
// bands x S x S (correlation of the output gradient with the scene, then the transpose of the
// wrap/fold). Linear in the PSF, so <convolve(cube, psf), g> = <psf, convolve_vjp_psf(cube, g)>.
RealStack convolve_vjp_psf(const RealStack& cube, const RealStack& g_out, std::size_t psf_size, ConvolutionMode mode);
// VJP of ref::convolve with respect to the scene: psf bands x S x S (axis at S/2), g_out
// bands x H x W -> bands x H x W, the correlation g_x[b](q) = sum over PSF offsets t of
// g_out[b](q + t) psf[b](S/2 + t) (q + t outside the scene contributes nothing in linear mode,
// wraps modulo H x W in circular mode). Direct sums, O(B H W S^2): for tests.
RealStack convolve_vjp_scene(const RealStack& psf, const RealStack& g_out, ConvolutionMode mode);
// VJP of ref::sensor_integrate: g_rgb 3 x H x W -> bands x H x W (srf^T g).
RealStack sensor_integrate_vjp(const RealStack& g_rgb, const Eigen::MatrixXd& srf);

// Transpose of area resampling: g (planes x S x S) -> planes x N x N.
RealStack resample_area_adjoint(const RealStack& g, const AreaWeights& w);

// Per-plane normalisation x -> x / sum(x): VJP given the normalised output y and the raw sums.
RealStack normalize_vjp(const RealStack& g_out, const RealStack& y, const std::vector<double>& raw_sums);
// JVP of the same map: dy = (dx - y * sum(dx)) / sum(x).
RealStack normalize_jvp(const RealStack& dx, const RealStack& y, const std::vector<double>& raw_sums);

// dL/dH (N x N) for a gradient of L with respect to the native PSF stack (bands x N x N, each
// band normalised) or the sensor PSF stack (bands x S x S). Recomputes the forward pass.
Map2D psf_native_vjp(const SystemConfig& cfg, const Map2D& height_m, const RealStack& g_psf);
Map2D psf_sensor_vjp(const SystemConfig& cfg, const Map2D& height_m, const RealStack& g_psf_sensor);

// Forward-mode derivative of the sensor PSF stack along dH (bands x S x S), for dot-product tests.
RealStack psf_sensor_jvp(const SystemConfig& cfg, const Map2D& height_m, const Map2D& d_height_m);

// The sensor PSF stack (bands x S x S, normalised) of a height map: ref::psf_stack then area
// resampling and normalisation (the same chain as Simulator::psf_sensor()).
RealStack psf_sensor_stack(const SystemConfig& cfg, const Map2D& height_m);

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
