// clFFT backend of FftPlan (see fft.hpp for the layout and conventions). clFFT needs one
// process-wide clfftSetup/clfftTeardown pair; a function-local static guard provides it.
#include <clFFT.h>

#include <chrono>
#include <memory>

#include "qdo/runtime/error.hpp"
#include "qdo/runtime/fft.hpp"

namespace qdo {
namespace {

void check(clfftStatus s, const char* what, std::size_t rows, std::size_t cols) {
  if (s != CLFFT_SUCCESS)
    throw DeviceError(std::string("clFFT ") + what + " failed for a " + std::to_string(rows) + " x " +
                      std::to_string(cols) + " plan: " + cl_error_name(static_cast<int>(s)));
}

struct ClfftLibrary {
  ClfftLibrary() {
    clfftSetupData d;
    clfftInitSetupData(&d);
    if (clfftSetup(&d) != CLFFT_SUCCESS) throw DeviceError("clfftSetup failed");
  }
  ~ClfftLibrary() { clfftTeardown(); }
  ClfftLibrary(const ClfftLibrary&) = delete;
  ClfftLibrary& operator=(const ClfftLibrary&) = delete;
};

}  // namespace

// Constructed on first use; the Runtime calls it before anything else, so the library
// outlives every Runtime (statics die in reverse order of construction).
void ensure_fft_library() { static ClfftLibrary lib; }

namespace {

// clFFT has no zero-padding option: a hinted plan computes the full transform, which is exact
// for input that is zero outside the data rectangle and writes a superset on inverse.
class ClfftPlan final : public FftPlan {
 public:
  ClfftPlan(Runtime& rt, std::size_t rows, std::size_t cols, std::size_t batch, Precision p,
            const FftZeroPad& zero_pad)
      : FftPlan(FftBackend::ClFFT, rows, cols, batch, p, zero_pad), rt_(rt) {
    ensure_fft_library();
    const auto t0 = std::chrono::steady_clock::now();
    size_t lens[2] = {cols, rows};  // clFFT: lengths[0] is the fastest-varying (x) dimension
    check(clfftCreateDefaultPlan(&handle_.h, rt.context()(), CLFFT_2D, lens), "create", rows, cols);
    const clfftPlanHandle h = handle_.h;
    check(clfftSetPlanPrecision(h, p == Precision::F64 ? CLFFT_DOUBLE : CLFFT_SINGLE), "precision", rows, cols);
    check(clfftSetLayout(h, CLFFT_COMPLEX_INTERLEAVED, CLFFT_COMPLEX_INTERLEAVED), "layout", rows, cols);
    check(clfftSetResultLocation(h, CLFFT_INPLACE), "placement", rows, cols);
    check(clfftSetPlanBatchSize(h, batch), "batch", rows, cols);
    check(clfftSetPlanDistance(h, rows * cols, rows * cols), "distance", rows, cols);
    size_t strides[2] = {1, cols};
    check(clfftSetPlanInStride(h, CLFFT_2D, strides), "stride", rows, cols);
    check(clfftSetPlanOutStride(h, CLFFT_2D, strides), "stride", rows, cols);
    cl_command_queue q = rt.queue()();
    check(clfftBakePlan(h, 1, &q, nullptr, nullptr), "bake", rows, cols);
    size_t tmp_bytes = 0;
    check(clfftGetTmpBufSize(h, &tmp_bytes), "tmp size", rows, cols);
    if (tmp_bytes) tmp_ = cl::Buffer(rt.context(), CL_MEM_READ_WRITE, tmp_bytes);
    rt.queue().finish();
    bake_seconds_ = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  }

 private:
  void run(cl::Buffer& data, bool fwd) override {
    cl_command_queue q = rt_.queue()();
    cl_mem m = data();
    cl_mem tmp = tmp_() ? tmp_() : nullptr;
    check(clfftEnqueueTransform(handle_.h, fwd ? CLFFT_FORWARD : CLFFT_BACKWARD, 1, &q, 0, nullptr, nullptr, &m,
                                nullptr, tmp),
          "transform", rows(), cols());
  }
  // Owns the clFFT plan (destroyed also when the constructor throws after creating it).
  struct Handle {
    clfftPlanHandle h = 0;
    Handle() = default;
    Handle(const Handle&) = delete;
    Handle& operator=(const Handle&) = delete;
    ~Handle() {
      if (h) clfftDestroyPlan(&h);
    }
  };
  Runtime& rt_;
  Handle handle_;
  cl::Buffer tmp_;
};

}  // namespace

namespace detail {
std::unique_ptr<FftPlan> make_clfft_plan(Runtime& rt, std::size_t rows, std::size_t cols, std::size_t batch,
                                         Precision p, const FftZeroPad& zero_pad) {
  return std::make_unique<ClfftPlan>(rt, rows, cols, batch, p, zero_pad);
}
}  // namespace detail

}  // namespace qdo
