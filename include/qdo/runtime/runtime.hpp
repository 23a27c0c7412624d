// OpenCL runtime: device selection, program building with a disk cache, and the FFT plans.
// Device selection (first match wins): the explicit selector (--device), the environment
// variable QDO_DEVICE, else the first GPU, else the first CPU device, else any device.
// Selector forms: "gpu", "cpu", "P:D" (platform and device index as `qdo devices` prints),
// or a case-insensitive substring of "platform name / device name".
// FFT backend (first match wins): the constructor argument, the environment variable
// QDO_FFT=clfft|vkfft, else clFFT. Plans are cached per (backend, sizes, batch, precision,
// zero-padding hint) for the Runtime's lifetime.
// Kernel programs are cached in memory per (file, options) and on disk per (platform,
// device, driver version, options, source) under $QDO_CACHE_DIR, else
// $XDG_CACHE_HOME/qdo/kernels, else ~/.cache/qdo/kernels; QDO_KERNEL_CACHE=off disables it.
#pragma once
#include <CL/opencl.hpp>

#include <filesystem>
#include <map>
#include <memory>
#include <string>
#include <type_traits>
#include <vector>

namespace qdo {

enum class Precision { F32, F64 };
Precision precision_from_string(const std::string& s);
std::string to_string(Precision p);
inline std::size_t real_size(Precision p) { return p == Precision::F64 ? 8 : 4; }

// The host type of the kernels' `real` at precision P: float (F32) or double (F64).
template <Precision P>
using device_real_t = std::conditional_t<P == Precision::F64, double, float>;

// A real scalar kernel argument: set_args passes it as device_real_t of the launch precision,
// i.e. as the `real` the kernel was compiled with. (A kernel parameter declared `double`
// whatever the precision, e.g. doe_field_p64's, is set with Precision::F64.)
struct Real {
  double value;
};

namespace detail {
inline void set_arg(cl::Kernel& k, cl_uint i, Precision p, const Real& r) {
  if (p == Precision::F64)
    k.setArg(i, static_cast<device_real_t<Precision::F64>>(r.value));
  else
    k.setArg(i, static_cast<device_real_t<Precision::F32>>(r.value));
}
template <typename T>
void set_arg(cl::Kernel& k, cl_uint i, Precision, const T& v) {
  static_assert(!std::is_floating_point<T>::value, "pass real scalars as Real{x}: converted to the device precision");
  k.setArg(i, v);
}
}  // namespace detail

// Sets k's arguments 0, 1, 2, ... to args in order: cl::Buffer, cl::Local and integer types
// (int, cl_uint, ...) as given, Real as float or double per p. The argument types must be
// exactly those the kernel declares (int vs cl_uint matters); a bare float or double is refused
// at compile time.
template <typename... A>
void set_args(cl::Kernel& k, Precision p, const A&... args) {
  cl_uint i = 0;
  (detail::set_arg(k, i++, p, args), ...);
}

// The library behind FftPlan: clFFT (src/runtime/fft_clfft.cpp), VkFFT's OpenCL backend
// (src/runtime/fft_vkfft.cpp) or, on CPU devices, FFTW on the mapped buffers
// (src/runtime/fft_fftw.cpp). All give the same transform (see fft.hpp). Auto (the default):
// FFTW on a CPU device, clFFT on any other; a Runtime resolves it when it picks the device.
enum class FftBackend { ClFFT, VkFFT, FFTW, Auto };
// "clfft", "vkfft", "fftw" or "auto" (case-insensitive); anything else is rejected naming `argument`.
FftBackend fft_backend_from_string(const std::string& s, const std::string& argument = "fft backend");
std::string to_string(FftBackend b);
// The folder of the kernel cache (QDO_CACHE_DIR, else $XDG_CACHE_HOME/qdo/kernels, else
// ~/.cache/qdo/kernels; empty when QDO_KERNEL_CACHE=off or no home is known). FFTW's wisdom is
// kept there too.
std::filesystem::path kernel_cache_dir();

// Zero-padding hint of a 2-D transform of rows x cols: the input is zero in every row of
// [row_begin, row_end) and every column of [col_begin, col_end) (one contiguous block per axis,
// no wrap-around; an empty range, begin == end, means no hint on that axis), so only the
// rectangle (rows outside the row block) x (columns outside the column block) carries data.
// Contract for both backends: before forward() the caller leaves zeros outside the rectangle
// (VkFFT skips reading them and the 1-D transforms of all-zero rows; clFFT reads them); the
// forward output is the full spectrum. inverse() defines its output only inside the rectangle
// (VkFFT does not write the rest, clFFT writes everything). Made for zero-padded fields: data in
// one corner, or, stored with the optical axis at index 0 (the PSF path's N x N field in its
// M x M window), at the four corners with the zero block [N/2, M - N/2) on both axes.
struct FftZeroPad {
  std::size_t row_begin = 0, row_end = 0, col_begin = 0, col_end = 0;
  bool any() const { return row_end > row_begin || col_end > col_begin; }
};

struct DeviceInfo {
  std::size_t platform_index = 0, device_index = 0;
  std::string platform, name, type, driver_version, version;
  bool fp64 = false;
  std::size_t global_mem_bytes = 0, max_alloc_bytes = 0;
  unsigned compute_units = 0;
};
// Every device of every platform; throws DeviceError when no OpenCL platform exists.
std::vector<DeviceInfo> list_devices();
// What `qdo devices` lists: every device of every platform, one line each (P:D, platform / name,
// type, driver, OpenCL version, fp64, compute units, memory in GiB); DeviceError as list_devices.
std::string devices_report();
// What `qdo --version` reports of the machine: the OpenCL devices (none is fine: the reason is
// named), one line each, and the FFT backends' versions (clFFT, VkFFT, FFTW). Lines end with "\n".
std::string backends_report();

class FftPlan;

class Runtime {
 public:
  explicit Runtime(const std::string& selector = "");
  // The same with an explicit FFT backend (QDO_FFT is then not consulted; Auto resolves as above;
  // FFTW on a device that is not a CPU is a DeviceError).
  Runtime(const std::string& selector, FftBackend fft_backend);
  ~Runtime();
  Runtime(const Runtime&) = delete;
  Runtime& operator=(const Runtime&) = delete;

  const cl::Context& context() const { return context_; }
  const cl::Device& device() const { return device_; }
  cl::CommandQueue& queue() { return queue_; }
  const DeviceInfo& info() const { return info_; }
  bool has_fp64() const { return info_.fp64; }
  // Throws DeviceError naming the device when p is F64 and the device lacks cl_khr_fp64.
  void require(Precision p) const;

  // The kernel `name` from kernels/<file> (common.cl prepended), built for precision p with
  // extra build options. Build failures throw DeviceError with the device and full log.
  cl::Kernel kernel(const std::string& file, const std::string& name, Precision p, const std::string& options = "");
  // The same for OpenCL C source given as text (common.cl prepended); `label` names it in
  // errors. Cached like the embedded kernels.
  cl::Kernel kernel_from_source(const std::string& label, const std::string& source, const std::string& name,
                                Precision p, const std::string& options = "");
  // A cached FFT plan for `batch` complex rows x cols transforms in place, made by this
  // Runtime's backend (fft_backend()). rows, cols and batch must be positive.
  FftPlan& fft(std::size_t rows, std::size_t cols, std::size_t batch, Precision p);
  // The same with an explicit backend and an optional zero-padding hint (FftZeroPad; its ranges
  // must lie within [0, rows] and [0, cols] with begin <= end). The same key returns the
  // same plan object.
  FftPlan& fft(std::size_t rows, std::size_t cols, std::size_t batch, Precision p, FftBackend backend,
               const FftZeroPad& zero_pad = {});
  FftBackend fft_backend() const { return fft_backend_; }
  // Later fft() calls without a backend use b; plans already made stay cached.
  void set_fft_backend(FftBackend b) { fft_backend_ = b; }
  std::size_t fft_plan_count() const { return ffts_.size(); }

  // Statistics (tests and benchmarks): programs built from source / loaded from disk, and
  // the seconds spent building programs and baking FFT plans.
  int programs_built() const { return built_; }
  int programs_loaded_from_disk() const { return loaded_; }
  double build_seconds() const { return build_seconds_; }
  double fft_bake_seconds() const;

  static constexpr std::size_t kLocalSize = 128;  // fixed work-group size of every 1-D kernel
  // Global size: n rounded up to a multiple of kLocalSize.
  static std::size_t global_for(std::size_t n) { return (n + kLocalSize - 1) / kLocalSize * kLocalSize; }
  // Enqueues k over n work items (1-D NDRange global_for(n), work-group kLocalSize) on queue q:
  // the one launch shape of every element-wise kernel (each checks gid < n itself).
  static void enqueue_1d(cl::CommandQueue& q, cl::Kernel& k, std::size_t n) {
    q.enqueueNDRangeKernel(k, cl::NullRange, cl::NDRange(global_for(n)), cl::NDRange(kLocalSize));
  }
  void enqueue_1d(cl::Kernel& k, std::size_t n) { enqueue_1d(queue(), k, n); }
  // set_args(k, p, args...) then enqueue_1d(k, n) on this Runtime's queue (a static form takes
  // the queue), e.g. launch_1d(k, n, prec, in, out, int(n), Real{scale}).
  template <typename... A>
  static void launch_1d(cl::CommandQueue& q, cl::Kernel& k, std::size_t n, Precision p, const A&... args) {
    set_args(k, p, args...);
    enqueue_1d(q, k, n);
  }
  template <typename... A>
  void launch_1d(cl::Kernel& k, std::size_t n, Precision p, const A&... args) {
    launch_1d(queue(), k, n, p, args...);
  }

  // Host doubles <-> a device buffer of reals in precision p (converted to float for F32);
  // blocking. n reals starting at element `offset` of the buffer.
  // The static forms take the queue (for callers holding their own).
  static void write_reals(cl::CommandQueue& q, const cl::Buffer& b, const double* src, std::size_t n, Precision p,
                          std::size_t offset = 0);
  static void read_reals(cl::CommandQueue& q, const cl::Buffer& b, double* dst, std::size_t n, Precision p,
                         std::size_t offset = 0);
  void write_reals(const cl::Buffer& b, const double* src, std::size_t n, Precision p, std::size_t offset = 0) {
    write_reals(queue_, b, src, n, p, offset);
  }
  void read_reals(const cl::Buffer& b, double* dst, std::size_t n, Precision p, std::size_t offset = 0) {
    read_reals(queue_, b, dst, n, p, offset);
  }

 private:
  cl::Program& program(const std::string& label, const std::string& source, const std::string& options);
  cl::Context context_;
  cl::Device device_;
  cl::CommandQueue queue_;
  DeviceInfo info_;
  std::map<std::string, cl::Program> programs_;
  std::map<std::string, std::unique_ptr<FftPlan>> ffts_;
  FftBackend fft_backend_ = FftBackend::ClFFT;
  int built_ = 0, loaded_ = 0;
  double build_seconds_ = 0;
};

// Human-readable OpenCL error name, e.g. "CL_OUT_OF_RESOURCES (-5)".
std::string cl_error_name(int code);

// The first `bytes` of a buffer mapped on the host (a blocking map on q) for the object's
// lifetime, unmapped on destruction, also while an exception unwinds. On CPU devices (PoCL) the
// map is the buffer's own memory, no copy; elsewhere the driver copies. One thread maps; any
// number may read a read-only mapping.
class MappedBuffer {
 public:
  MappedBuffer(cl::CommandQueue& q, const cl::Buffer& b, cl_map_flags flags, std::size_t bytes) : q_(q), b_(b) {
    ptr_ = q_.enqueueMapBuffer(b_, CL_TRUE, flags, 0, bytes);
  }
  ~MappedBuffer() {
    // Must not throw: an unmap that fails here (the queue already broken) is left to the
    // buffer's release, which ends the mapping.
    try {
      q_.enqueueUnmapMemObject(b_, ptr_);
    } catch (const cl::Error&) {
    }
  }
  MappedBuffer(const MappedBuffer&) = delete;
  MappedBuffer& operator=(const MappedBuffer&) = delete;
  template <typename T>
  T* as() const {
    return static_cast<T*>(ptr_);
  }

 private:
  cl::CommandQueue& q_;
  cl::Buffer b_;
  void* ptr_ = nullptr;
};

}  // namespace qdo
