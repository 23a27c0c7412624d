// VkFFT backend of FftPlan (see fft.hpp for the layout and conventions), through VkFFT's
// OpenCL backend (header-only vkFFT.h, Debian libvkfft-dev 1.2.26). This is the only
// translation unit that includes vkFFT.h.
//
// VkFFT generates and builds its OpenCL kernels in initializeVkFFT (the plan's bake time).
// Binary caching: VkFFT's saveApplicationToString / loadApplicationFromString do not work with
// the OpenCL backend of 1.2.26: the save path serialises each program binary with
// sprintf("%s"), which stops at the first NUL byte (a PoCL binary starts "poclbin\0...", so
// 431,719 bytes saved for a 384 x 384 plan hold 7 bytes per kernel), and the load path copies
// codeSize - 2 bytes of each; loading such a string fails with
// VKFFT_ERROR_FAILED_TO_CREATE_PROGRAM. So plans are rebuilt from source in every process;
// with PoCL its own kernel cache (POCL_KERNEL_CACHE, on by default, ~/.cache/pocl/kcache)
// then makes the rebuild cheap (measured in bench_fft's bake column on a warm cache).
#define VKFFT_BACKEND 3
#include <vkFFT.h>

#include <chrono>
#include <cstdint>
#include <memory>
#include <string>

#include "qdo/runtime/error.hpp"
#include "qdo/runtime/fft.hpp"

namespace qdo {
namespace {

std::string vkfft_error_name(VkFFTResult r) {
  switch (r) {
#define QDO_VKFFT_ERR(x) \
  case x:                \
    return std::string(#x) + " (" + std::to_string(static_cast<int>(r)) + ")";
    QDO_VKFFT_ERR(VKFFT_SUCCESS)
    QDO_VKFFT_ERR(VKFFT_ERROR_MALLOC_FAILED)
    QDO_VKFFT_ERR(VKFFT_ERROR_INSUFFICIENT_CODE_BUFFER)
    QDO_VKFFT_ERR(VKFFT_ERROR_INSUFFICIENT_TEMP_BUFFER)
    QDO_VKFFT_ERR(VKFFT_ERROR_PLAN_NOT_INITIALIZED)
    QDO_VKFFT_ERR(VKFFT_ERROR_NULL_TEMP_PASSED)
    QDO_VKFFT_ERR(VKFFT_ERROR_INVALID_PHYSICAL_DEVICE)
    QDO_VKFFT_ERR(VKFFT_ERROR_INVALID_DEVICE)
    QDO_VKFFT_ERR(VKFFT_ERROR_INVALID_QUEUE)
    QDO_VKFFT_ERR(VKFFT_ERROR_INVALID_COMMAND_POOL)
    QDO_VKFFT_ERR(VKFFT_ERROR_INVALID_FENCE)
    QDO_VKFFT_ERR(VKFFT_ERROR_ONLY_FORWARD_FFT_INITIALIZED)
    QDO_VKFFT_ERR(VKFFT_ERROR_ONLY_INVERSE_FFT_INITIALIZED)
    QDO_VKFFT_ERR(VKFFT_ERROR_INVALID_CONTEXT)
    QDO_VKFFT_ERR(VKFFT_ERROR_INVALID_PLATFORM)
    QDO_VKFFT_ERR(VKFFT_ERROR_ENABLED_saveApplicationToString)
    QDO_VKFFT_ERR(VKFFT_ERROR_EMPTY_FILE)
    QDO_VKFFT_ERR(VKFFT_ERROR_EMPTY_FFTdim)
    QDO_VKFFT_ERR(VKFFT_ERROR_EMPTY_size)
    QDO_VKFFT_ERR(VKFFT_ERROR_EMPTY_bufferSize)
    QDO_VKFFT_ERR(VKFFT_ERROR_EMPTY_buffer)
    QDO_VKFFT_ERR(VKFFT_ERROR_EMPTY_tempBufferSize)
    QDO_VKFFT_ERR(VKFFT_ERROR_EMPTY_tempBuffer)
    QDO_VKFFT_ERR(VKFFT_ERROR_EMPTY_inputBufferSize)
    QDO_VKFFT_ERR(VKFFT_ERROR_EMPTY_inputBuffer)
    QDO_VKFFT_ERR(VKFFT_ERROR_EMPTY_outputBufferSize)
    QDO_VKFFT_ERR(VKFFT_ERROR_EMPTY_outputBuffer)
    QDO_VKFFT_ERR(VKFFT_ERROR_EMPTY_kernelSize)
    QDO_VKFFT_ERR(VKFFT_ERROR_EMPTY_kernel)
    QDO_VKFFT_ERR(VKFFT_ERROR_EMPTY_applicationString)
    QDO_VKFFT_ERR(VKFFT_ERROR_EMPRY_useCustomBluesteinPaddingPattern_arrays)
    QDO_VKFFT_ERR(VKFFT_ERROR_UNSUPPORTED_RADIX)
    QDO_VKFFT_ERR(VKFFT_ERROR_UNSUPPORTED_FFT_LENGTH)
    QDO_VKFFT_ERR(VKFFT_ERROR_UNSUPPORTED_FFT_LENGTH_R2C)
    QDO_VKFFT_ERR(VKFFT_ERROR_UNSUPPORTED_FFT_LENGTH_DCT)
    QDO_VKFFT_ERR(VKFFT_ERROR_UNSUPPORTED_FFT_OMIT)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_ALLOCATE)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_MAP_MEMORY)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_ALLOCATE_COMMAND_BUFFERS)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_BEGIN_COMMAND_BUFFER)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_END_COMMAND_BUFFER)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_SUBMIT_QUEUE)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_WAIT_FOR_FENCES)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_RESET_FENCES)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_CREATE_DESCRIPTOR_POOL)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_CREATE_DESCRIPTOR_SET_LAYOUT)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_ALLOCATE_DESCRIPTOR_SETS)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_CREATE_PIPELINE_LAYOUT)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_SHADER_PREPROCESS)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_SHADER_PARSE)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_SHADER_LINK)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_SPIRV_GENERATE)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_CREATE_SHADER_MODULE)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_CREATE_INSTANCE)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_SETUP_DEBUG_MESSENGER)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_FIND_PHYSICAL_DEVICE)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_CREATE_DEVICE)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_CREATE_FENCE)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_CREATE_COMMAND_POOL)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_CREATE_BUFFER)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_ALLOCATE_MEMORY)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_BIND_BUFFER_MEMORY)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_FIND_MEMORY)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_SYNCHRONIZE)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_COPY)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_CREATE_PROGRAM)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_COMPILE_PROGRAM)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_GET_CODE_SIZE)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_GET_CODE)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_DESTROY_PROGRAM)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_LOAD_MODULE)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_GET_FUNCTION)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_SET_DYNAMIC_SHARED_MEMORY)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_MODULE_GET_GLOBAL)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_LAUNCH_KERNEL)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_EVENT_RECORD)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_ADD_NAME_EXPRESSION)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_INITIALIZE)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_SET_DEVICE_ID)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_GET_DEVICE)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_CREATE_CONTEXT)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_CREATE_PIPELINE)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_SET_KERNEL_ARG)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_CREATE_COMMAND_QUEUE)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_RELEASE_COMMAND_QUEUE)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_ENUMERATE_DEVICES)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_GET_ATTRIBUTE)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_CREATE_EVENT)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_CREATE_COMMAND_LIST)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_DESTROY_COMMAND_LIST)
    QDO_VKFFT_ERR(VKFFT_ERROR_FAILED_TO_SUBMIT_BARRIER)
#undef QDO_VKFFT_ERR
  }
  return "VkFFT error " + std::to_string(static_cast<int>(r));
}

void check(VkFFTResult r, const char* what, std::size_t rows, std::size_t cols, std::size_t batch, Precision p) {
  if (r != VKFFT_SUCCESS)
    throw DeviceError("VkFFT " + vkfft_error_name(r) + " in " + what + " of a " + std::to_string(batch) + " x " +
                      std::to_string(rows) + " x " + std::to_string(cols) + " " + to_string(p) + " plan (VkFFT " +
                      vkfft_version() + ")");
}

// Owns a VkFFTApplication: deleteVkFFT releases its programs, kernels and buffers. deleteVkFFT
// zeroes what it frees, so it is safe also after a failed initializeVkFFT (which frees too).
struct VkfftApp {
  VkFFTApplication app{};
  VkfftApp() = default;
  VkfftApp(const VkfftApp&) = delete;
  VkfftApp& operator=(const VkfftApp&) = delete;
  ~VkfftApp() { deleteVkFFT(&app); }
};

class VkfftPlan final : public FftPlan {
 public:
  VkfftPlan(Runtime& rt, std::size_t rows, std::size_t cols, std::size_t batch, Precision p,
            const FftZeroPad& zero_pad)
      : FftPlan(FftBackend::VkFFT, rows, cols, batch, p, zero_pad),
        rt_(rt),
        device_(rt.device()()),
        context_(rt.context()()),
        buffer_bytes_(bytes()),
        app_(std::make_unique<VkfftApp>()) {
    const auto t0 = std::chrono::steady_clock::now();
    // VkFFT keeps the pointers given here (device, context, buffer size, and at launch the
    // queue and buffer), so they point at members, whose addresses are stable.
    VkFFTConfiguration c{};
    c.FFTdim = 2;
    c.size[0] = cols;  // VkFFT: axis 0 is the fastest-varying (x) dimension
    c.size[1] = rows;
    c.numberBatches = batch;
    c.device = &device_;
    c.context = &context_;
    c.bufferSize = &buffer_bytes_;  // the buffer itself is given at launch (launch_.buffer)
    c.doublePrecision = p == Precision::F64 ? 1 : 0;
    c.normalize = 1;  // inverse scaled by 1/(rows*cols)
    if (zero_pad.col_end > zero_pad.col_begin) {
      c.performZeropadding[0] = 1;
      c.fft_zeropad_left[0] = zero_pad.col_begin;
      c.fft_zeropad_right[0] = zero_pad.col_end;
    }
    if (zero_pad.row_end > zero_pad.row_begin) {
      c.performZeropadding[1] = 1;
      c.fft_zeropad_left[1] = zero_pad.row_begin;
      c.fft_zeropad_right[1] = zero_pad.row_end;
    }
    check(initializeVkFFT(&app_->app, c), "initializeVkFFT", rows, cols, batch, p);
    bake_seconds_ = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  }

 private:
  void run(cl::Buffer& data, bool fwd) override {
    queue_ = rt_.queue()();
    buffer_ = data();
    VkFFTLaunchParams launch{};
    launch.commandQueue = &queue_;
    launch.buffer = &buffer_;
    // VkFFT: -1 forward (e^{-i...}), 1 inverse (e^{+i...}, normalised as configured).
    check(VkFFTAppend(&app_->app, fwd ? -1 : 1, &launch), fwd ? "forward VkFFTAppend" : "inverse VkFFTAppend",
          rows(), cols(), batch(), precision());
  }
  Runtime& rt_;
  cl_device_id device_;
  cl_context context_;
  cl_command_queue queue_ = nullptr;
  cl_mem buffer_ = nullptr;
  std::uint64_t buffer_bytes_;
  std::unique_ptr<VkfftApp> app_;
};

}  // namespace

std::string vkfft_version() {
  const int v = VkFFTGetVersion();  // X.XX.XX as one integer, e.g. 10226
  return std::to_string(v / 10000) + "." + std::to_string(v / 100 % 100) + "." + std::to_string(v % 100);
}

namespace detail {
std::unique_ptr<FftPlan> make_vkfft_plan(Runtime& rt, std::size_t rows, std::size_t cols, std::size_t batch,
                                         Precision p, const FftZeroPad& zero_pad) {
  return std::make_unique<VkfftPlan>(rt, rows, cols, batch, p, zero_pad);
}
}  // namespace detail

}  // namespace qdo
