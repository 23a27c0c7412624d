// DemosaicStage (include/qdo/physics/demosaic.hpp): the launcher of kernels/demosaic.cl.
#include "qdo/physics/demosaic.hpp"

#include <algorithm>
#include <limits>
#include <utility>

#include "physics/device_buffers.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/physics/raw_reference.hpp"

namespace qdo {

namespace {

// Element counts go to the kernels as int; the 5 x 5 mirror needs 3 rows and columns.
void check_size(std::size_t rows, std::size_t cols, std::size_t scenes) {
  const std::size_t n = rows * cols * 3 * scenes;
  if (rows < 3 || cols < 3 || scenes == 0 || n / 3 / scenes != rows * cols ||
      n > std::size_t(std::numeric_limits<int>::max()))
    reject("demosaic frame", to_str(scenes) + " x " + to_str(rows) + " x " + to_str(cols),
           "at least one scene of at least 3 x 3 pixels, at most " + to_str(std::numeric_limits<int>::max()) +
               " output elements");
}

// The batch as one contiguous buffer of scenes x planes x H x W, all scenes of one shape.
std::vector<double> flatten(const std::vector<RealStack>& stacks, std::size_t planes, const char* name) {
  if (stacks.empty()) reject(name, "0 scenes", "at least one " + to_str(planes) + " x H x W scene");
  const std::size_t rows = stacks[0].rows, cols = stacks[0].cols;
  check_size(rows, cols, stacks.size());
  std::vector<double> flat;
  flat.reserve(stacks.size() * planes * rows * cols);
  for (const RealStack& s : stacks) {
    if (s.planes != planes || s.rows != rows || s.cols != cols)
      reject(name, shape(s), "every scene " + shape(planes, rows, cols));
    flat.insert(flat.end(), s.data.begin(), s.data.end());
  }
  return flat;
}

std::vector<RealStack> split(const std::vector<double>& flat, std::size_t scenes, std::size_t planes, std::size_t rows,
                             std::size_t cols) {
  std::vector<RealStack> out;
  for (std::size_t k = 0; k < scenes; ++k) {
    RealStack s(planes, rows, cols);
    std::copy(flat.begin() + long(k * s.size()), flat.begin() + long((k + 1) * s.size()), s.data.begin());
    out.push_back(std::move(s));
  }
  return out;
}

}  // namespace

DemosaicStage::DemosaicStage(Runtime& rt, Cfa cfa, DemosaicMethod method, Precision p)
    : rt_(rt), cfa_(cfa), method_(method), prec_(p) {
  if (cfa == Cfa::None) reject("cfa", "\"none\"", "a mosaic to demosaic: \"rggb\", \"grbg\", \"gbrg\" or \"bggr\"");
  rt_.require(p);
  k_forward_ = rt_.kernel("demosaic.cl", "demosaic_forward", p);
  k_adjoint_ = rt_.kernel("demosaic.cl", "demosaic_adjoint", p);
}

void DemosaicStage::run(const cl::Buffer& raw, cl::Buffer& rgb, std::size_t rows, std::size_t cols, std::size_t scenes) {
  check_size(rows, cols, scenes);
  rt_.launch_1d(k_forward_, scenes * rows * cols, prec_, raw, rgb, int(rows), int(cols), cfa_code(cfa_),
                int(method_ == DemosaicMethod::MHC ? 1 : 0), int(scenes));
}

void DemosaicStage::adjoint(const cl::Buffer& g_rgb, cl::Buffer& g_raw, std::size_t rows, std::size_t cols,
                            std::size_t scenes) {
  check_size(rows, cols, scenes);
  rt_.launch_1d(k_adjoint_, scenes * rows * cols, prec_, g_rgb, g_raw, int(rows), int(cols), cfa_code(cfa_),
                int(method_ == DemosaicMethod::MHC ? 1 : 0), int(scenes));
}

std::vector<RealStack> DemosaicStage::run(const std::vector<RealStack>& raw) {
  const std::vector<double> flat = flatten(raw, 1, "raw");
  const std::size_t rows = raw[0].rows, cols = raw[0].cols, scenes = raw.size();
  const cl::Buffer in = detail::upload_real(rt_, flat, prec_);
  cl::Buffer out(rt_.context(), CL_MEM_READ_WRITE, scenes * 3 * rows * cols * real_size(prec_));
  run(in, out, rows, cols, scenes);
  return split(detail::download_real(rt_, out, scenes * 3 * rows * cols, prec_), scenes, 3, rows, cols);
}

std::vector<RealStack> DemosaicStage::adjoint(const std::vector<RealStack>& g_rgb) {
  const std::vector<double> flat = flatten(g_rgb, 3, "g_rgb");
  const std::size_t rows = g_rgb[0].rows, cols = g_rgb[0].cols, scenes = g_rgb.size();
  const cl::Buffer in = detail::upload_real(rt_, flat, prec_);
  cl::Buffer out(rt_.context(), CL_MEM_READ_WRITE, scenes * rows * cols * real_size(prec_));
  adjoint(in, out, rows, cols, scenes);
  return split(detail::download_real(rt_, out, scenes * rows * cols, prec_), scenes, 1, rows, cols);
}

}  // namespace qdo
