// The FFT interface: batched, in-place, complex-interleaved 2-D transforms on device buffers.
// Three backends behind one interface (FftBackend in runtime.hpp): clFFT (src/runtime/fft_clfft.cpp),
// VkFFT's OpenCL backend (src/runtime/fft_vkfft.cpp) and FFTW on CPU devices (src/runtime/fft_fftw.cpp). Plans are baked once and cached by the Runtime
// (Runtime::fft); the backend is chosen per Runtime (constructor argument or QDO_FFT).
#pragma once
#include <CL/opencl.hpp>

#include <cstddef>
#include <memory>
#include <string>

#include "qdo/runtime/runtime.hpp"

namespace qdo {

// Process-wide FFT library setup (idempotent; clFFT's clfftSetup). Called by every Runtime's
// constructor so the library outlives every Runtime.
void ensure_fft_library();

// VkFFT's version as VkFFTGetVersion() reports it, e.g. "1.2.26".
std::string vkfft_version();
// FFTW's version string, e.g. "fftw-3.3.10-sse2-avx".
std::string fftw_library_version();

class FftPlan {
 public:
  virtual ~FftPlan() = default;
  FftPlan(const FftPlan&) = delete;
  FftPlan& operator=(const FftPlan&) = delete;

  // Enqueue an in-place transform of `data` on the Runtime's queue (asynchronous, like every
  // kernel). Layout: `batch` transforms of rows x cols complex values, interleaved (re, im) in
  // the plan's precision, row-major, contiguous: element (t, y, x) at complex index
  // (t * rows + y) * cols + x. `data` must hold at least bytes() bytes (else InputError).
  // Forward: X(ky,kx) = sum x(y,x) e^{-i2π(ky·y/rows + kx·x/cols)}, unscaled.
  // Inverse: e^{+i2π(...)}, scaled by 1/(rows*cols), so inverse(forward(x)) = x.
  // With a zero-padding hint (zero_pad().any()) see FftZeroPad for what is read and written.
  void forward(cl::Buffer& data);
  void inverse(cl::Buffer& data);

  double bake_seconds() const { return bake_seconds_; }  // plan creation (kernel builds included)
  std::size_t rows() const { return rows_; }
  std::size_t cols() const { return cols_; }
  std::size_t batch() const { return batch_; }
  Precision precision() const { return precision_; }
  FftBackend backend() const { return backend_; }
  const FftZeroPad& zero_pad() const { return zero_pad_; }
  // batch * rows * cols complex values of the plan's precision.
  std::size_t bytes() const { return batch_ * rows_ * cols_ * 2 * real_size(precision_); }

 protected:
  FftPlan(FftBackend backend, std::size_t rows, std::size_t cols, std::size_t batch, Precision p,
          const FftZeroPad& zero_pad)
      : backend_(backend), rows_(rows), cols_(cols), batch_(batch), precision_(p), zero_pad_(zero_pad) {}
  virtual void run(cl::Buffer& data, bool forward) = 0;
  double bake_seconds_ = 0;

 private:
  void check_buffer(const cl::Buffer& data) const;
  FftBackend backend_;
  std::size_t rows_, cols_, batch_;
  Precision precision_;
  FftZeroPad zero_pad_;
};

namespace detail {
// Backend factories, called by Runtime::fft after it validated the arguments.
std::unique_ptr<FftPlan> make_clfft_plan(Runtime& rt, std::size_t rows, std::size_t cols, std::size_t batch,
                                         Precision p, const FftZeroPad& zero_pad);
std::unique_ptr<FftPlan> make_vkfft_plan(Runtime& rt, std::size_t rows, std::size_t cols, std::size_t batch,
                                         Precision p, const FftZeroPad& zero_pad);
std::unique_ptr<FftPlan> make_fftw_plan(Runtime& rt, std::size_t rows, std::size_t cols, std::size_t batch,
                                        Precision p, const FftZeroPad& zero_pad);
}  // namespace detail

}  // namespace qdo
