// The CPU FFT used by the double-precision reference paths (FFTW3), with one process-wide lock
// around FFTW's planner, which is not thread-safe.
#pragma once
#include "qdo/runtime/types.hpp"

namespace qdo {

// In-place 2-D DFT of every plane of `s` (planes x rows x cols, row-major). forward: e^{-i2π...},
// unscaled; inverse: e^{+i2π...}, divided by rows*cols when scale_inverse (else unscaled).
void fftw2(ComplexStack& s, bool forward, bool scale_inverse = true);

}  // namespace qdo
