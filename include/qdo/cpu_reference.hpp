// The CPU reference path: every physics stage in plain double precision (FFTW for FFTs,
// Eigen for small dense algebra). Slow and simple on purpose; the OpenCL kernels are tested
// against it. Conventions (Goodman): forward FFT e^{-i2π(fx x + fy y)}, inverse normalised by
// 1/M², diverging spherical wave exp(+ik r), DOE factor exp(+i k (n-1) H), Fresnel transfer
// function exp(-iπ λ z (fx² + fy²)) (the constant exp(ikz) dropped; the angular spectrum
// transfer function drops it too, so both are directly comparable).
#pragma once
#include <Eigen/Dense>

#include "qdo/config.hpp"
#include "qdo/optics.hpp"
#include "qdo/types.hpp"

namespace qdo::ref {

// Field just after the DOE for every band, in the zero-padded window: shape bands x M x M,
// (b, y, x) row-major; zero outside the circular aperture and outside the N x N DOE.
// Phase k (sqrt(r² + d²) - d) + k (n_b - 1) H, the first term written r²/(sqrt(r²+d²)+d)
// so no large constant k·d enters (REFERENCE §1 precision pitfall).
ComplexStack doe_field(const SystemConfig& cfg, const Map2D& height_m, const PropagationGeometry& g);

// In-place circular propagation of a bands x M x M field over z_m (negative z goes back).
// wavelengths_nm has one entry per plane. Also fills `sampling` (if given) per band:
// the spectral energy beyond the transfer function's reliable limit.
void propagate(ComplexStack& field, const std::vector<double>& wavelengths_nm, double pitch_m, double z_m,
               Propagator method, std::vector<BandSampling>* sampling = nullptr);

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

// Per-band convolution of a cube (bands x H x W) with a PSF stack (bands x S x S, optical axis
// at (S/2, S/2)). Linear: zero-padded, output H x W aligned with the input ("same").
// Circular: periodic over the H x W scene (PSF folded onto H x W; the Wiener decoder's model, not the
// release's image formation, which mirror-pads and shifts: docs/physics.md).
RealStack convolve(const RealStack& cube, const RealStack& psf, ConvolutionMode mode);

// Eq. 7 without noise: rgb(c, y, x) = sum_b srf(c, b) * cube(b, y, x); srf is 3 x B with
// rows already normalised to unit sum (sensor_response()).
RealStack sensor_integrate(const RealStack& blurred, const Eigen::MatrixXd& srf);
// Shot noise (Poisson with full_well_photons at value 1; skipped when 0) then Gaussian read
// noise (sigma in full-scale units), element (c, y, x) of scene k in a batch drawing counter
// ((k*H*W) + y*W + x)*3 + c.
void add_noise(RealStack& rgb, double read_noise_sigma, double full_well_photons, unsigned long long seed,
               std::size_t scene_index = 0);

// A direct (O(N^4)) Fresnel diffraction integral of an N x N field at pitch_m over z_m, in the
// same convention as the transfer function (constant exp(ikz) dropped): for tests.
ComplexStack fresnel_integral_direct(const ComplexStack& field, double wavelength_nm, double pitch_m, double z_m);

}  // namespace qdo::ref
