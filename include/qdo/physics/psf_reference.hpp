// CPU reference of the PSF stage (kernels/psf.cl), in double: |U|² cropped and normalised, area
// resampling to the sensor pitch, and the adjoints of the whole chain heights -> PSF (the
// gradient convention and the chain written out in adjoint.hpp).
// Planes: "bands" below reads points x bands (point-major, plane p * bands + b) when the
// configuration lists object points (config.hpp): every stack and gradient has cfg.point_count()
// x cfg.bands planes, and the gradients of all points add up in dL/dH.
#pragma once
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo::ref {

struct PsfResult {
  RealStack psf;             // bands x N x N on the DOE grid, each band sums to 1
  SamplingReport sampling;
};
// The whole chain: DOE field, propagation over sensor_distance_m, |U|² cropped to N x N,
// normalised per band. Honours cfg.strict_sampling (AccuracyError) after computing.
PsfResult psf_stack(const SystemConfig& cfg, const Map2D& height_m);

// bands x N x N -> bands x S x S by area integration (weights from AreaWeights).
RealStack resample_area(const RealStack& psf, const AreaWeights& w);
// Divides each plane by its sum (planes summing to 0 are left as they are).
void normalize_planes(RealStack& s);

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

}  // namespace qdo::ref
