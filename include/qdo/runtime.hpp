// OpenCL runtime: device selection, program building with a disk cache, and the FFT plans.
// Device selection (first match wins): the explicit selector (--device), the environment
// variable QDO_DEVICE, else the first GPU, else the first CPU device, else any device.
// Selector forms: "gpu", "cpu", "P:D" (platform and device index as `qdo devices` prints),
// or a case-insensitive substring of "platform name / device name".
// Kernel programs are cached in memory per (file, options) and on disk per (platform,
// device, driver version, options, source) under $QDO_CACHE_DIR, else
// $XDG_CACHE_HOME/qdo/kernels, else ~/.cache/qdo/kernels; QDO_KERNEL_CACHE=off disables it.
#pragma once
#include <CL/opencl.hpp>

#include <map>
#include <memory>
#include <string>
#include <vector>

namespace qdo {

enum class Precision { F32, F64 };
Precision precision_from_string(const std::string& s);
std::string to_string(Precision p);
inline std::size_t real_size(Precision p) { return p == Precision::F64 ? 8 : 4; }

struct DeviceInfo {
  std::size_t platform_index = 0, device_index = 0;
  std::string platform, name, type, driver_version, version;
  bool fp64 = false;
  std::size_t global_mem_bytes = 0, max_alloc_bytes = 0;
  unsigned compute_units = 0;
};
// Every device of every platform; throws DeviceError when no OpenCL platform exists.
std::vector<DeviceInfo> list_devices();

class FftPlan;

class Runtime {
 public:
  explicit Runtime(const std::string& selector = "");
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
  // A cached FFT plan for `batch` complex rows x cols transforms in place.
  FftPlan& fft(std::size_t rows, std::size_t cols, std::size_t batch, Precision p);

  // Statistics (tests and benchmarks): programs built from source / loaded from disk, and
  // the seconds spent building programs and baking FFT plans.
  int programs_built() const { return built_; }
  int programs_loaded_from_disk() const { return loaded_; }
  double build_seconds() const { return build_seconds_; }
  double fft_bake_seconds() const;

  static constexpr std::size_t kLocalSize = 128;  // fixed work-group size of every 1-D kernel
  // Global size: n rounded up to a multiple of kLocalSize.
  static std::size_t global_for(std::size_t n) { return (n + kLocalSize - 1) / kLocalSize * kLocalSize; }

 private:
  cl::Program& program(const std::string& label, const std::string& source, const std::string& options);
  cl::Context context_;
  cl::Device device_;
  cl::CommandQueue queue_;
  DeviceInfo info_;
  std::map<std::string, cl::Program> programs_;
  std::map<std::string, std::unique_ptr<FftPlan>> ffts_;
  int built_ = 0, loaded_ = 0;
  double build_seconds_ = 0;
};

// Human-readable OpenCL error name, e.g. "CL_OUT_OF_RESOURCES (-5)".
std::string cl_error_name(int code);

}  // namespace qdo
