// RawStage (include/qdo/physics/raw.hpp): the launcher of kernels/raw.cl.
#include "qdo/physics/raw.hpp"

#include <algorithm>
#include <limits>
#include <utility>

#include "physics/device_buffers.hpp"
#include "qdo/runtime/error.hpp"

namespace qdo {

namespace {

// Element counts go to the kernels as int and the tallies come back as cl_uint.
void check_size(std::size_t rows, std::size_t cols, std::size_t scenes) {
  const std::size_t n = rows * cols * 3 * scenes;
  if (rows == 0 || cols == 0 || scenes == 0 || n / 3 / scenes != rows * cols ||
      n > std::size_t(std::numeric_limits<int>::max()))
    reject("raw frame", to_str(scenes) + " x 3 x " + to_str(rows) + " x " + to_str(cols),
           "non-empty, at most " + to_str(std::numeric_limits<int>::max()) + " elements");
}

// The host batch as one contiguous buffer of scenes x 3 x H x W (or the given planes).
std::vector<double> flatten(const std::vector<RealStack>& stacks, std::size_t planes, std::size_t rows, std::size_t cols,
                            const char* name) {
  std::vector<double> flat;
  flat.reserve(stacks.size() * planes * rows * cols);
  for (const RealStack& s : stacks) {
    if (s.planes != planes || s.rows != rows || s.cols != cols)
      reject(name, shape(s.planes, s.rows, s.cols), "every scene " + shape(planes, rows, cols));
    flat.insert(flat.end(), s.data.begin(), s.data.end());
  }
  return flat;
}

}  // namespace

RawStage::RawStage(Runtime& rt, const SystemConfig& cfg, Precision p) : rt_(rt), cfg_(cfg), prec_(p) {
  k_forward_ = rt_.kernel("raw.cl", "raw_forward", p);
  k_adjoint_ = rt_.kernel("raw.cl", "raw_adjoint", p);
  counts_ = detail::upload(rt_, std::vector<cl_uint>(2, 0u), CL_MEM_READ_WRITE);
}

RawCounts RawStage::run(const cl::Buffer& rgb, cl::Buffer& raw, std::size_t rows, std::size_t cols, std::size_t scenes) {
  check_size(rows, cols, scenes);
  const std::size_t hw = rows * cols, n = scenes * channels() * hw;
  const cl_uint zero[2] = {0u, 0u};
  rt_.queue().enqueueWriteBuffer(counts_, CL_FALSE, 0, sizeof(zero), zero);
  rt_.launch_1d(k_forward_, n, prec_, rgb, raw, counts_, int(hw), int(cols), int(channels()), cfa_code(cfg_.cfa),
                Real{cfg_.gain}, Real{cfg_.black_level_dn}, Real{cfg_.white_level_dn()}, int(cfg_.bit_depth > 0 ? 1 : 0),
                Real{cfg_.read_noise_sigma}, Real{cfg_.full_well_photons}, cl_uint(cfg_.noise_seed & 0xffffffffull),
                cl_uint(cfg_.noise_seed >> 32), int(scenes));
  cl_uint got[2] = {0u, 0u};
  rt_.queue().enqueueReadBuffer(counts_, CL_TRUE, 0, sizeof(got), got);
  RawCounts c;
  c.saturated = got[0];
  c.floored = got[1];
  c.total = n;
  return c;
}

void RawStage::adjoint(const cl::Buffer& rgb, const cl::Buffer& g_raw, cl::Buffer& g_rgb, std::size_t rows,
                       std::size_t cols, std::size_t scenes) {
  check_size(rows, cols, scenes);
  const std::size_t hw = rows * cols;
  rt_.launch_1d(k_adjoint_, scenes * 3 * hw, prec_, rgb, g_raw, g_rgb, int(hw), int(cols), int(channels()),
                cfa_code(cfg_.cfa), Real{cfg_.gain}, Real{cfg_.black_level_dn}, Real{cfg_.white_level_dn()},
                Real{cfg_.read_noise_sigma}, Real{cfg_.full_well_photons}, cl_uint(cfg_.noise_seed & 0xffffffffull),
                cl_uint(cfg_.noise_seed >> 32), int(scenes));
}

RawStage::Frames RawStage::run(const std::vector<RealStack>& rgb) {
  if (rgb.empty()) reject("rgb", "0 scenes", "at least one 3 x H x W scene");
  const std::size_t rows = rgb[0].rows, cols = rgb[0].cols, scenes = rgb.size(), ch = channels();
  check_size(rows, cols, scenes);
  const cl::Buffer in = detail::upload_real(rt_, flatten(rgb, 3, rows, cols, "rgb"), prec_);
  cl::Buffer out(rt_.context(), CL_MEM_READ_WRITE, scenes * ch * rows * cols * real_size(prec_));
  Frames f;
  f.counts = run(in, out, rows, cols, scenes);
  const std::vector<double> flat = detail::download_real(rt_, out, scenes * ch * rows * cols, prec_);
  for (std::size_t k = 0; k < scenes; ++k) {
    RealStack s(ch, rows, cols);
    std::copy(flat.begin() + long(k * s.size()), flat.begin() + long((k + 1) * s.size()), s.data.begin());
    f.raw.push_back(std::move(s));
  }
  return f;
}

std::vector<RealStack> RawStage::adjoint(const std::vector<RealStack>& rgb, const std::vector<RealStack>& g_raw) {
  if (rgb.empty() || g_raw.size() != rgb.size())
    reject("g_raw", to_str(g_raw.size()) + " scenes", "one per rgb scene (" + to_str(rgb.size()) + "), at least one");
  const std::size_t rows = rgb[0].rows, cols = rgb[0].cols, scenes = rgb.size();
  check_size(rows, cols, scenes);
  const cl::Buffer in = detail::upload_real(rt_, flatten(rgb, 3, rows, cols, "rgb"), prec_);
  const cl::Buffer g = detail::upload_real(rt_, flatten(g_raw, channels(), rows, cols, "g_raw"), prec_);
  cl::Buffer out(rt_.context(), CL_MEM_READ_WRITE, scenes * 3 * rows * cols * real_size(prec_));
  adjoint(in, g, out, rows, cols, scenes);
  const std::vector<double> flat = detail::download_real(rt_, out, scenes * 3 * rows * cols, prec_);
  std::vector<RealStack> res;
  for (std::size_t k = 0; k < scenes; ++k) {
    RealStack s(3, rows, cols);
    std::copy(flat.begin() + long(k * s.size()), flat.begin() + long((k + 1) * s.size()), s.data.begin());
    res.push_back(std::move(s));
  }
  return res;
}

}  // namespace qdo
