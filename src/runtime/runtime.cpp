#include "qdo/runtime/runtime.hpp"

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <iterator>
#include <sstream>
#include <unistd.h>

#include "qdo/runtime/embedded.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/hash.hpp"
#include "qdo/runtime/fft.hpp"
#include "qdo/runtime/kernel_cache.hpp"

namespace qdo {
namespace {

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return std::tolower(c); });
  return s;
}

std::uint64_t fnv1a(const std::string& s, std::uint64_t h = Fnv1a64{}.h) { return Fnv1a64{h}.add(s.data(), s.size()).h; }

std::string device_type_name(cl_device_type t) {
  if (t & CL_DEVICE_TYPE_GPU) return "GPU";
  if (t & CL_DEVICE_TYPE_CPU) return "CPU";
  if (t & CL_DEVICE_TYPE_ACCELERATOR) return "accelerator";
  return "other";
}

std::vector<cl::Platform> platforms() {
  std::vector<cl::Platform> ps;
  try {
    cl::Platform::get(&ps);
  } catch (const cl::Error& e) {
    if (e.err() != CL_PLATFORM_NOT_FOUND_KHR) throw DeviceError(std::string("OpenCL: ") + e.what() + " " + cl_error_name(e.err()));
  }
  if (ps.empty())
    throw DeviceError(
        "no OpenCL platform found: install an OpenCL driver (on Debian: pocl-opencl-icd for CPUs; "
        "scripts/install-deps.sh does this) and check /etc/OpenCL/vendors");
  return ps;
}

DeviceInfo describe(const cl::Platform& p, const cl::Device& d, std::size_t pi, std::size_t di) {
  DeviceInfo i;
  i.platform_index = pi;
  i.device_index = di;
  i.platform = p.getInfo<CL_PLATFORM_NAME>();
  i.name = d.getInfo<CL_DEVICE_NAME>();
  i.type = device_type_name(d.getInfo<CL_DEVICE_TYPE>());
  i.driver_version = d.getInfo<CL_DRIVER_VERSION>();
  i.version = d.getInfo<CL_DEVICE_VERSION>();
  i.fp64 = d.getInfo<CL_DEVICE_EXTENSIONS>().find("cl_khr_fp64") != std::string::npos ||
           d.getInfo<CL_DEVICE_DOUBLE_FP_CONFIG>() != 0;
  // QDO_DISABLE_FP64=1 makes every device look float32-only (to exercise that path anywhere).
  if (const char* off = std::getenv("QDO_DISABLE_FP64"); off && std::string(off) == "1") i.fp64 = false;
  i.global_mem_bytes = static_cast<std::size_t>(d.getInfo<CL_DEVICE_GLOBAL_MEM_SIZE>());
  i.max_alloc_bytes = static_cast<std::size_t>(d.getInfo<CL_DEVICE_MAX_MEM_ALLOC_SIZE>());
  i.compute_units = d.getInfo<CL_DEVICE_MAX_COMPUTE_UNITS>();
  // Strip the NUL terminators some drivers leave in strings.
  for (std::string* s : {&i.platform, &i.name, &i.driver_version, &i.version})
    s->erase(std::find(s->begin(), s->end(), '\0'), s->end());
  return i;
}

}  // namespace

std::filesystem::path kernel_cache_dir() {
  if (const char* off = std::getenv("QDO_KERNEL_CACHE"); off && lower(off) == "off") return {};
  if (const char* d = std::getenv("QDO_CACHE_DIR"); d && *d) return std::filesystem::path(d);
  if (const char* x = std::getenv("XDG_CACHE_HOME"); x && *x) return std::filesystem::path(x) / "qdo" / "kernels";
  if (const char* h = std::getenv("HOME"); h && *h) return std::filesystem::path(h) / ".cache" / "qdo" / "kernels";
  return {};
}

std::string cl_error_name(int code) {
  switch (code) {
#define QDO_CL_ERR(x) \
  case x:             \
    return std::string(#x) + " (" + std::to_string(code) + ")";
    QDO_CL_ERR(CL_DEVICE_NOT_FOUND)
    QDO_CL_ERR(CL_DEVICE_NOT_AVAILABLE)
    QDO_CL_ERR(CL_MEM_OBJECT_ALLOCATION_FAILURE)
    QDO_CL_ERR(CL_OUT_OF_RESOURCES)
    QDO_CL_ERR(CL_OUT_OF_HOST_MEMORY)
    QDO_CL_ERR(CL_BUILD_PROGRAM_FAILURE)
    QDO_CL_ERR(CL_INVALID_VALUE)
    QDO_CL_ERR(CL_INVALID_BUFFER_SIZE)
    QDO_CL_ERR(CL_INVALID_KERNEL_ARGS)
    QDO_CL_ERR(CL_INVALID_WORK_GROUP_SIZE)
    QDO_CL_ERR(CL_INVALID_GLOBAL_WORK_SIZE)
    QDO_CL_ERR(CL_INVALID_ARG_SIZE)
    QDO_CL_ERR(CL_INVALID_MEM_OBJECT)
#undef QDO_CL_ERR
    default:
      return "OpenCL error " + std::to_string(code);
  }
}

Precision precision_from_string(const std::string& s) {
  if (s == "f32" || s == "float" || s == "float32") return Precision::F32;
  if (s == "f64" || s == "double" || s == "float64") return Precision::F64;
  reject("precision", s, "f32 or f64");
}

std::string to_string(Precision p) { return p == Precision::F64 ? "f64" : "f32"; }

std::vector<DeviceInfo> list_devices() {
  std::vector<DeviceInfo> out;
  const auto ps = platforms();
  for (std::size_t pi = 0; pi < ps.size(); ++pi) {
    std::vector<cl::Device> ds;
    try {
      ps[pi].getDevices(CL_DEVICE_TYPE_ALL, &ds);
    } catch (const cl::Error&) {
      continue;  // a platform with no devices
    }
    for (std::size_t di = 0; di < ds.size(); ++di) out.push_back(describe(ps[pi], ds[di], pi, di));
  }
  return out;
}

FftBackend fft_backend_from_string(const std::string& s, const std::string& argument) {
  const std::string l = lower(s);
  if (l == "clfft") return FftBackend::ClFFT;
  if (l == "vkfft") return FftBackend::VkFFT;
  if (l == "fftw") return FftBackend::FFTW;
  if (l == "auto") return FftBackend::Auto;
  reject(argument, s, "clfft, vkfft, fftw or auto");
}

std::string to_string(FftBackend b) {
  switch (b) {
    case FftBackend::ClFFT: return "clfft";
    case FftBackend::VkFFT: return "vkfft";
    case FftBackend::FFTW: return "fftw";
    case FftBackend::Auto: return "auto";
  }
  return "?";
}

namespace {
// What QDO_FFT=auto means on a device: FFTW on a CPU device (PoCL buffers are host memory; FFTW
// is 3.5x clFFT there, BENCHMARKS "FFT backends"), VkFFT on any other. On an NVIDIA H100 (driver
// 580) VkFFT did the paper preset's 31 x 1536^2 forward + inverse in 2.2 ms against clFFT's 15.4
// ms (f32; 4.3 against 51.5 ms in f64), at float32 error 5e-7 against clFFT's 2e-7 (BENCHMARKS
// "GPU").
FftBackend auto_fft_backend(const DeviceInfo& info) { return info.type == "CPU" ? FftBackend::FFTW : FftBackend::VkFFT; }

// QDO_FFT, else auto; a bad value is rejected before any device work.
FftBackend fft_backend_from_env() {
  const char* e = std::getenv("QDO_FFT");
  return e && *e ? fft_backend_from_string(e, "QDO_FFT") : FftBackend::Auto;
}
}  // namespace

Runtime::Runtime(const std::string& selector) : Runtime(selector, fft_backend_from_env()) {}

Runtime::Runtime(const std::string& selector, FftBackend fft_backend) : fft_backend_(fft_backend) {
  ensure_fft_library();
  std::string sel = selector;
  if (sel.empty())
    if (const char* e = std::getenv("QDO_DEVICE")) sel = e;
  const auto ps = platforms();
  struct Cand {
    cl::Platform p;
    cl::Device d;
    DeviceInfo info;
  };
  std::vector<Cand> all;
  for (std::size_t pi = 0; pi < ps.size(); ++pi) {
    std::vector<cl::Device> ds;
    try {
      ps[pi].getDevices(CL_DEVICE_TYPE_ALL, &ds);
    } catch (const cl::Error&) {
      continue;
    }
    for (std::size_t di = 0; di < ds.size(); ++di) all.push_back({ps[pi], ds[di], describe(ps[pi], ds[di], pi, di)});
  }
  if (all.empty()) throw DeviceError("no OpenCL device found on any platform");
  const Cand* pick = nullptr;
  const std::string ls = lower(sel);
  if (ls.empty()) {
    for (const auto& c : all)
      if (!pick && c.info.type == "GPU") pick = &c;
    for (const auto& c : all)
      if (!pick && c.info.type == "CPU") pick = &c;
    if (!pick) pick = &all.front();
  } else if (ls == "gpu" || ls == "cpu") {
    for (const auto& c : all)
      if (!pick && lower(c.info.type) == ls) pick = &c;
  } else if (ls.find(':') != std::string::npos && std::isdigit(static_cast<unsigned char>(ls[0]))) {
    std::size_t pi = 0, di = 0;
    char colon = 0;
    std::istringstream is(ls);
    is >> pi >> colon >> di;
    for (const auto& c : all)
      if (!pick && c.info.platform_index == pi && c.info.device_index == di) pick = &c;
  } else {
    for (const auto& c : all)
      if (!pick && lower(c.info.platform + " / " + c.info.name).find(ls) != std::string::npos) pick = &c;
  }
  if (!pick) {
    std::string names;
    for (const auto& c : all)
      names += "\n  " + std::to_string(c.info.platform_index) + ":" + std::to_string(c.info.device_index) + "  " +
               c.info.platform + " / " + c.info.name + " (" + c.info.type + ")";
    reject("device", sel, "gpu, cpu, P:D or a substring of a device name; devices here:" + names);
  }
  device_ = pick->d;
  info_ = pick->info;
  context_ = cl::Context(device_);
  queue_ = cl::CommandQueue(context_, device_);
  if (fft_backend_ == FftBackend::Auto) fft_backend_ = auto_fft_backend(info_);
  if (fft_backend_ == FftBackend::FFTW && info_.type != "CPU")
    throw DeviceError("the FFTW backend runs on the mapped buffers of a CPU device; device '" + info_.name + "' is a " +
                      info_.type + " (use QDO_FFT=clfft, vkfft or auto)");
}

Runtime::~Runtime() {
  ffts_.clear();  // plans before the context goes
}

void Runtime::require(Precision p) const {
  if (p == Precision::F64 && !info_.fp64)
    throw DeviceError("device '" + info_.name + "' (" + info_.platform +
                      ") has no double precision (cl_khr_fp64); use --precision f32 or another device");
}

cl::Program& Runtime::program(const std::string& label, const std::string& source, const std::string& options) {
  const std::string key = label + "|" + options + "|" + std::to_string(fnv1a(source));
  auto it = programs_.find(key);
  if (it != programs_.end()) return it->second;

  const std::uint64_t h = fnv1a(source, fnv1a(options + "|" + info_.platform + "|" + info_.name + "|" +
                                               info_.driver_version + "|" + info_.version));
  char hex[17];
  std::snprintf(hex, sizeof hex, "%016llx", static_cast<unsigned long long>(h));
  const auto dir = kernel_cache_dir();
  const auto path = dir.empty() ? std::filesystem::path() : dir / (std::string(hex) + ".bin");

  const auto t0 = std::chrono::steady_clock::now();
  cl::Program prog;
  bool from_disk = false;
  // The disk cache is untrusted: another process, a full disk or a crash may have left a
  // truncated or corrupt entry, and handing that to clCreateProgramWithBinary crashed PoCL
  // (SIGSEGV / assertion) in every later run. An entry is the 8-byte magic "QDOKBIN1", the
  // binary's size and FNV-1a hash (uint64 each, little-endian), then the binary. Anything that
  // does not match, or any failure to build from it, means: rebuild from source with a one-line
  // note on stderr and rewrite the entry (temp file + rename). Never fatal.
  std::error_code ec;
  if (!path.empty() && std::filesystem::exists(path, ec)) {
    std::string problem;
    std::vector<unsigned char> file;
    {
      std::ifstream in(path, std::ios::binary);
      file.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
      if (!in.eof() && in.fail()) problem = "unreadable";
    }
    KernelCacheEntry entry;
    if (problem.empty()) {
      entry = decode_kernel_cache_entry(file.data(), file.size());  // the format: kernel_cache.hpp
      problem = entry.problem;
    }
    if (problem.empty()) {
      try {
        cl::Program::Binaries bins{std::move(entry.binary)};
        prog = cl::Program(context_, {device_}, bins);
        prog.build({device_}, options.c_str());
        from_disk = true;
      } catch (const cl::Error& e) {
        problem = std::string("not loadable on this device (") + e.what() + " " + cl_error_name(e.err()) + ")";
      }
    }
    if (!from_disk)
      std::cerr << "qdo: note: kernel cache entry " << path.string() << " for " << label << " is " << problem
                << "; rebuilding from source and rewriting it\n";
  }
  if (!from_disk) {
    prog = cl::Program(context_, source);
    try {
      prog.build({device_}, options.c_str());
    } catch (const cl::Error&) {
      const std::string log = prog.getBuildInfo<CL_PROGRAM_BUILD_LOG>(device_);
      throw DeviceError("kernel build of " + label + " failed on device '" + info_.name + "' (" +
                        info_.platform + ", driver " + info_.driver_version + ") with options '" + options +
                        "'. Build log:\n" + log);
    }
    ++built_;
    if (!path.empty()) {
      try {
        auto bins = prog.getInfo<CL_PROGRAM_BINARIES>();
        if (!bins.empty() && !bins[0].empty()) {
          std::filesystem::create_directories(dir);
          const auto tmp = path.string() + ".tmp-" + std::to_string(::getpid());
          {
            const std::vector<unsigned char> entry = encode_kernel_cache_entry(bins[0].data(), bins[0].size());
            std::ofstream out(tmp, std::ios::binary);
            out.write(reinterpret_cast<const char*>(entry.data()), static_cast<std::streamsize>(entry.size()));
            out.close();
            if (!out) throw std::runtime_error("write failed");
          }
          std::error_code rename_ec;
          std::filesystem::rename(tmp, path, rename_ec);
          if (rename_ec) std::filesystem::remove(tmp, rename_ec);
        }
      } catch (const std::exception&) {
        // The disk cache is an optimisation only; an unwritable cache directory is not an error.
      }
    }
  } else {
    ++loaded_;
  }
  build_seconds_ += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return programs_.emplace(key, std::move(prog)).first->second;
}

cl::Kernel Runtime::kernel(const std::string& file, const std::string& name, Precision p, const std::string& options) {
  return kernel_from_source("kernels/" + file, embedded_file(file), name, p, options);
}

cl::Kernel Runtime::kernel_from_source(const std::string& label, const std::string& source, const std::string& name,
                                       Precision p, const std::string& options) {
  require(p);
  std::string opts = (p == Precision::F64 ? "-DQDO_FP64=1" : "-DQDO_FP64=0");
  opts += " -cl-std=CL1.2";
  if (!options.empty()) opts += " " + options;
  try {
    return cl::Kernel(program(label, embedded_file("common.cl") + "\n" + source, opts), name.c_str());
  } catch (const cl::Error& e) {
    throw DeviceError("kernel '" + name + "' in " + label + ": " + e.what() + " " + cl_error_name(e.err()));
  }
}

FftPlan& Runtime::fft(std::size_t rows, std::size_t cols, std::size_t batch, Precision p) {
  return fft(rows, cols, batch, p, fft_backend_);
}

FftPlan& Runtime::fft(std::size_t rows, std::size_t cols, std::size_t batch, Precision p, FftBackend backend,
                      const FftZeroPad& zero_pad) {
  if (rows == 0) reject("rows", rows, "a positive FFT size");
  if (cols == 0) reject("cols", cols, "a positive FFT size");
  if (batch == 0) reject("batch", batch, "a positive number of transforms");
  if (backend == FftBackend::Auto) backend = auto_fft_backend(info_);
  if (backend == FftBackend::FFTW && info_.type != "CPU")
    throw DeviceError("the FFTW backend runs on the mapped buffers of a CPU device; device '" + info_.name + "' is a " +
                      info_.type + " (use clfft or vkfft)");
  if (zero_pad.row_begin > zero_pad.row_end || zero_pad.row_end > rows)
    reject("zero_pad rows", to_str(zero_pad.row_begin) + ".." + to_str(zero_pad.row_end),
           "a range begin <= end <= rows = " + to_str(rows));
  if (zero_pad.col_begin > zero_pad.col_end || zero_pad.col_end > cols)
    reject("zero_pad cols", to_str(zero_pad.col_begin) + ".." + to_str(zero_pad.col_end),
           "a range begin <= end <= cols = " + to_str(cols));
  require(p);
  // Empty ranges are normalised so that every "no hint" spelling shares one plan.
  FftZeroPad zp = zero_pad;
  if (zp.row_begin == zp.row_end) zp.row_begin = zp.row_end = 0;
  if (zp.col_begin == zp.col_end) zp.col_begin = zp.col_end = 0;
  std::string key = to_string(backend) + ":" + std::to_string(rows) + "x" + std::to_string(cols) + "x" +
                    std::to_string(batch) + to_string(p);
  if (zp.any())
    key += ":zero" + std::to_string(zp.row_begin) + "-" + std::to_string(zp.row_end) + "," +
           std::to_string(zp.col_begin) + "-" + std::to_string(zp.col_end);
  auto it = ffts_.find(key);
  if (it == ffts_.end()) {
    std::unique_ptr<FftPlan> plan;
    if (backend == FftBackend::VkFFT) plan = detail::make_vkfft_plan(*this, rows, cols, batch, p, zp);
    else if (backend == FftBackend::FFTW) plan = detail::make_fftw_plan(*this, rows, cols, batch, p, zp);
    else plan = detail::make_clfft_plan(*this, rows, cols, batch, p, zp);
    it = ffts_.emplace(key, std::move(plan)).first;
  }
  return *it->second;
}

void FftPlan::check_buffer(const cl::Buffer& data) const {
  if (!data()) reject("data", "a null cl::Buffer", "a buffer of at least " + to_str(bytes()) + " bytes");
  const std::size_t have = data.getInfo<CL_MEM_SIZE>();
  if (have < bytes())
    reject("data", to_str(have) + " bytes",
           "at least " + to_str(bytes()) + " bytes (" + to_str(batch_) + " x " + to_str(rows_) + " x " + to_str(cols_) +
               " complex " + to_string(precision_) + ")");
}

void FftPlan::forward(cl::Buffer& data) {
  check_buffer(data);
  run(data, true);
}

void FftPlan::inverse(cl::Buffer& data) {
  check_buffer(data);
  run(data, false);
}

double Runtime::fft_bake_seconds() const {
  double s = 0;
  for (const auto& kv : ffts_) s += kv.second->bake_seconds();
  return s;
}

void Runtime::write_reals(cl::CommandQueue& q, const cl::Buffer& b, const double* src, std::size_t n, Precision p,
                          std::size_t offset) {
  if (n == 0) return;
  if (p == Precision::F64) {
    q.enqueueWriteBuffer(b, CL_TRUE, offset * 8, n * 8, src);
  } else {
    const std::vector<float> f(src, src + n);
    q.enqueueWriteBuffer(b, CL_TRUE, offset * 4, n * 4, f.data());
  }
}

void Runtime::read_reals(cl::CommandQueue& q, const cl::Buffer& b, double* dst, std::size_t n, Precision p,
                         std::size_t offset) {
  if (n == 0) return;
  if (p == Precision::F64) {
    q.enqueueReadBuffer(b, CL_TRUE, offset * 8, n * 8, dst);
  } else {
    // Mapped, then converted straight into dst: no staging copy (on a CPU device the map is the
    // buffer itself).
    void* ptr = q.enqueueMapBuffer(b, CL_TRUE, CL_MAP_READ, offset * 4, n * 4);
    const float* f = static_cast<const float*>(ptr);
    std::copy(f, f + n, dst);
    q.enqueueUnmapMemObject(b, ptr);
  }
}

}  // namespace qdo
