// The CPU FFT used by the double-precision reference paths (FFTW3), with one process-wide lock
// around FFTW's planner, which is not thread-safe.
#pragma once
#include "qdo/runtime/types.hpp"

namespace qdo {

// In-place 2-D DFT of every plane of `s` (planes x rows x cols, row-major). forward: e^{-i2π...},
// unscaled; inverse: e^{+i2π...}, divided by rows*cols when scale_inverse (else unscaled).
void fftw2(ComplexStack& s, bool forward, bool scale_inverse = true);

// The real-input transforms: x (planes x rows x cols, real) -> the non-redundant half of each
// plane's forward DFT, planes x rows x (cols/2 + 1) (column kx of the full spectrum for kx <=
// cols/2; the rest is the conjugate of the mirror frequency), unscaled.
ComplexStack rfftw2(const RealStack& x);
// The inverse of rfftw2 (divided by rows * cols): a half spectrum planes x rows x (cols/2 + 1),
// taken as the half of a Hermitian spectrum, -> planes x rows x cols real. half is overwritten.
RealStack irfftw2(ComplexStack& half, std::size_t cols);

}  // namespace qdo
