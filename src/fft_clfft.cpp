// clFFT backend of FftPlan. clFFT needs one process-wide clfftSetup/clfftTeardown pair;
// a function-local static guard provides it.
#include <clFFT.h>

#include <chrono>

#include "qdo/error.hpp"
#include "qdo/fft.hpp"

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

FftPlan::FftPlan(Runtime& rt, std::size_t rows, std::size_t cols, std::size_t batch, Precision p)
    : rt_(rt), rows_(rows), cols_(cols), batch_(batch) {
  ensure_fft_library();
  const auto t0 = std::chrono::steady_clock::now();
  clfftPlanHandle h = 0;
  size_t lens[2] = {cols, rows};  // clFFT: lengths[0] is the fastest-varying (x) dimension
  check(clfftCreateDefaultPlan(&h, rt.context()(), CLFFT_2D, lens), "create", rows, cols);
  handle_ = h;
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

FftPlan::~FftPlan() {
  clfftPlanHandle h = handle_;
  if (h) clfftDestroyPlan(&h);
}

void FftPlan::run(cl::Buffer& data, bool fwd) {
  cl_command_queue q = rt_.queue()();
  cl_mem m = data();
  cl_mem tmp = tmp_() ? tmp_() : nullptr;
  check(clfftEnqueueTransform(handle_, fwd ? CLFFT_FORWARD : CLFFT_BACKWARD, 1, &q, 0, nullptr, nullptr, &m, nullptr,
                              tmp),
        "transform", rows_, cols_);
}

void FftPlan::forward(cl::Buffer& data) { run(data, true); }
void FftPlan::inverse(cl::Buffer& data) { run(data, false); }

}  // namespace qdo
