// The FFT interface: batched, in-place, complex-interleaved 2-D transforms on device buffers.
// Three backends behind one interface (FftBackend in runtime.hpp): clFFT (src/runtime/fft_clfft.cpp),
// VkFFT's OpenCL backend (src/runtime/fft_vkfft.cpp) and FFTW on CPU devices (src/runtime/fft_fftw.cpp). Plans are baked once and cached by the Runtime
// (Runtime::fft); the backend is chosen per Runtime (constructor argument or QDO_FFT).
#pragma once
#include <CL/opencl.hpp>

#include <cstddef>
#include <memory>
#include <string>

#include "qdo/runtime.hpp"

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

// Fused, pruned propagation on a CPU device's own buffers (FFTW, src/runtime/propagate_fftw.cpp),
// used by Simulator::run_propagation when the FFT backend is FFTW and the field is zero-padded.
// One call propagates `planes` fields of M x M complex values (interleaved, the precision given
// at construction, row-major, plane b at complex offset b * M * M) whose samples sit in
// [0, N)^2 (rows and columns >= N of the input are never read), by one transfer function per plane:
//   1. each of the N data rows: copied with zeros beyond column N, transformed (length M);
//   2. per block of columns: the N data rows gathered (zeros below), column transform, the
//      transfer function, its sampling energies and the 1/M² scale, inverse column transform,
//      rows [0, N) scattered back;
//   3. each of the N data rows: inverse transform, columns [0, N) written back, and the crop's
//      intensity |U|² and its sum when asked for.
// 2-D circular propagation of the padded field restricted to the [0, N)^2 crop, with 5/6 of the
// 1-D transforms of an unpruned 2-D pair at N = 2M/3 and the column passes cache-resident; planes run
// in parallel on the device's compute units. Output: field rows [0, N), columns [0, N) hold the
// propagated samples; the rest of the plane is scratch (undefined).
class HostPropagator {
 public:
  virtual ~HostPropagator() = default;
  HostPropagator(const HostPropagator&) = delete;
  HostPropagator& operator=(const HostPropagator&) = delete;

  // The transfer function as Simulator keeps it: `separable` (Fresnel): planes x M table t with
  // TF(ky, kx) = t[ky] t[kx]; otherwise planes x M x M (FFT order on both axes).
  struct Tf {
    const cl::Buffer* table = nullptr;
    bool separable = true;
  };
  // Optional outputs (null: not computed).
  struct Outputs {
    // Sampling energies per plane, as the tf_energy_* kernels and finalize_sums3 give them:
    // energy3 (planes x 3 reals) = (Σ|spec|², the part with |f| index > klim[b] on either axis,
    // Σ|spec · TF|² unscaled); klim: planes integers, host memory.
    cl::Buffer* energy3 = nullptr;
    const int* klim = nullptr;
    // The crop's intensity |U|² (planes x N x N reals) and its per-plane sums (planes reals).
    cl::Buffer* intensity = nullptr;
    cl::Buffer* crop_sums = nullptr;
  };
  // Optional input in place of the field's own [0, N)^2 block (the Simulator's PSF adjoint):
  // row y of plane b becomes, for x < N,
  //   2 · (A g A^T)[y][x] · U[b][y][x],   (A g A^T)[y][x] = Σ_ty Σ_tx w[y][ty] w[x][tx] g[b][start[y] + ty][start[x] + tx]
  // i.e. the transposed area resampling of the sensor-grid gradient g (planes x S x S reals; taps
  // outside [0, S) have weight 0 and are read clamped) followed by the vector-Jacobian product of
  // |U|² with U the forward's propagated field (planes x M x M complex, crop [0, N)^2). start: N
  // ints; w: N x taps reals (AreaWeights::transposed()).
  // With y_sensor and sensor_sums (planes x S x S and planes reals) g is first taken through the
  // vector-Jacobian product of the per-plane normalisation y = x / Σx:
  //   g <- (g - <g, y>) / Σx   (0 where Σx <= 0).
  struct IntensityAdjointInput {
    const cl::Buffer* g_sensor = nullptr;
    const cl::Buffer* u = nullptr;
    std::size_t s = 0, taps = 0;
    const int* start = nullptr;
    const double* w = nullptr;
    const cl::Buffer* y_sensor = nullptr;
    const cl::Buffer* sensor_sums = nullptr;
  };
  // Blocks until done (the queue is finished first: the buffers are mapped); one call at a time
  // per object (its per-thread arrays are members; separate objects may run concurrently). field must hold
  // planes x M x M complex values; the tables as above. With `in`, field's contents are not
  // read (only written).
  virtual void run(cl::Buffer& field, const Tf& tf, const Outputs& out, const IntensityAdjointInput* in) = 0;
  void run(cl::Buffer& field, const Tf& tf, const Outputs& out) { run(field, tf, out, nullptr); }
  // Forward only, planes [first, first + count) of the planes given at construction, with
  // `field` holding just those planes (count x M x M complex, plane first + i at complex offset
  // i * M * M): the streamed PSF of Simulator::set_keep_field(false), which reuses one small field
  // buffer for all planes. The transfer-function table and the outputs are indexed by the global
  // plane as in run(); outputs of other planes are left as they are. The same arithmetic as run(),
  // so each plane's results are bit-identical to it. InputError unless first + count <= planes.
  virtual void run_planes(cl::Buffer& field, std::size_t first, std::size_t count, const Tf& tf, const Outputs& out) = 0;
  // How many planes run at once (one per thread): the natural `count` for run_planes.
  virtual std::size_t threads() const = 0;

  std::size_t m() const { return m_; }
  std::size_t n() const { return n_; }
  std::size_t planes() const { return planes_; }
  Precision precision() const { return precision_; }
  double bake_seconds() const { return bake_seconds_; }  // FFTW planning (wisdom makes it ~0)

 protected:
  HostPropagator(std::size_t m, std::size_t n, std::size_t planes, Precision p)
      : m_(m), n_(n), planes_(planes), precision_(p) {}
  std::size_t m_, n_, planes_;
  Precision precision_;
  double bake_seconds_ = 0;
};

// A HostPropagator for rt's device; DeviceError unless the device is a CPU; InputError unless
// 0 < n < m and planes >= 1.
std::unique_ptr<HostPropagator> make_host_propagator(Runtime& rt, std::size_t m, std::size_t n, std::size_t planes,
                                                     Precision p);

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
