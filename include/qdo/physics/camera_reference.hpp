// CPU reference of the camera's per-band convolution (kernels/camera.cl), in double with FFTW,
// and its adjoints to the PSF stack and to the scene (the sensor integration is
// sensor_reference.hpp's).
#pragma once
#include <cstddef>

#include "qdo/data/config.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo::ref {

// Per-band convolution of a cube (bands x H x W) with a PSF stack (bands x S x S, optical axis
// at (S/2, S/2)). Linear: zero-padded, output H x W aligned with the input ("same").
// Circular: periodic over the H x W scene (PSF folded onto H x W; the Wiener decoder's model, not the
// release's image formation, which mirror-pads and shifts: docs/physics.md).
RealStack convolve(const RealStack& cube, const RealStack& psf, ConvolutionMode mode);

// VJP of ref::convolve with respect to the PSF stack: cube bands x H x W, g_out bands x H x W ->
// bands x S x S (correlation of the output gradient with the scene, then the transpose of the
// wrap/fold). Linear in the PSF, so <convolve(cube, psf), g> = <psf, convolve_vjp_psf(cube, g)>.
RealStack convolve_vjp_psf(const RealStack& cube, const RealStack& g_out, std::size_t psf_size, ConvolutionMode mode);
// VJP of ref::convolve with respect to the scene: psf bands x S x S (axis at S/2), g_out
// bands x H x W -> bands x H x W, the correlation g_x[b](q) = sum over PSF offsets t of
// g_out[b](q + t) psf[b](S/2 + t) (q + t outside the scene contributes nothing in linear mode,
// wraps modulo H x W in circular mode). Direct sums, O(B H W S^2): for tests.
RealStack convolve_vjp_scene(const RealStack& psf, const RealStack& g_out, ConvolutionMode mode);

}  // namespace qdo::ref
