// Helpers shared by the per-stage CPU references (src/physics/*_reference.cpp); not installed.
#pragma once
#include <fftw3.h>

#include "qdo/runtime/fftw2.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo::ref::detail {

// In-place batched 2-D FFT of the planes of s; the backward transform is scaled by 1/(rows*cols).
inline void fft2_batch(ComplexStack& s, int sign) { fftw2(s, sign == FFTW_FORWARD, true); }

}  // namespace qdo::ref::detail
