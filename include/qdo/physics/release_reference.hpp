// CPU reference of the release's image formation (release.hpp describes it step by step), in
// double. The device path is ReleaseImager (release.hpp, kernels/release.cl).
#pragma once
#include <cstddef>

#include "qdo/physics/release.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

namespace ref {
// Bilinear resize of every plane (planes x rows_in x cols_in) to rows x cols, TF2 convention
// (half-pixel centres, edge clamp, no antialias), in double.
RealStack resize_bilinear(const RealStack& x, std::size_t rows, std::size_t cols);
// The release's per-band image formation above, in double, literally (arrays padded, rolled and
// transformed with FFTW): cube bands x S x S, psf_native bands x N x N (used as given; the
// release normalises each band to unit sum) -> bands x S x S.
RealStack release_blur(const RealStack& cube, const RealStack& psf_native);
}  // namespace ref

}  // namespace qdo
