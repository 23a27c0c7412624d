// The FFT interface: batched, in-place, complex-interleaved 2-D transforms on device buffers.
// One backend today (clFFT); plans are baked once and cached by the Runtime.
#pragma once
#include <CL/opencl.hpp>

#include <cstddef>

#include "qdo/runtime.hpp"

namespace qdo {

// Process-wide FFT library setup (idempotent). Called by every Runtime's constructor.
void ensure_fft_library();

class FftPlan {
 public:
  // `batch` transforms of rows x cols complex values (interleaved re, im in precision p),
  // contiguous: transform t occupies elements [t*rows*cols, (t+1)*rows*cols).
  FftPlan(Runtime& rt, std::size_t rows, std::size_t cols, std::size_t batch, Precision p);
  ~FftPlan();
  FftPlan(const FftPlan&) = delete;
  FftPlan& operator=(const FftPlan&) = delete;

  // Enqueues an in-place transform of `data` (at least batch*rows*cols complex values).
  // Forward: e^{-i2π(...)} unscaled; inverse: scaled by 1/(rows*cols).
  void forward(cl::Buffer& data);
  void inverse(cl::Buffer& data);

  double bake_seconds() const { return bake_seconds_; }
  std::size_t rows() const { return rows_; }
  std::size_t cols() const { return cols_; }
  std::size_t batch() const { return batch_; }

 private:
  void run(cl::Buffer& data, bool forward);
  Runtime& rt_;
  std::size_t rows_, cols_, batch_;
  std::size_t handle_ = 0;
  cl::Buffer tmp_;
  double bake_seconds_ = 0;
};

}  // namespace qdo
