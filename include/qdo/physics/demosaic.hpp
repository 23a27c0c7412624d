// The demosaic stage on the device (kernels/demosaic.cl): one Bayer raw plane per scene -> R, G, B
// planes, bilinear or Malvar-He-Cutler (2004, 5 x 5 gradient-corrected), and its transpose (the
// stage is linear, so its adjoint is the transpose, a kernel too). The filters, the border rule
// (mirror about the edge pixel, which keeps the mosaic) and the units are those of
// demosaic_reference.hpp: the raw plane in linear signal units (black level removed and scaled,
// raw_to_linear(); 1.0 = full well), the output in the same units.
// CPU reference: ref::demosaic, ref::demosaic_vjp (demosaic_reference.hpp).
#pragma once
#include <CL/opencl.hpp>

#include <cstddef>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/physics/demosaic_reference.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

class DemosaicStage {
 public:
  // One per (mosaic, method, precision); cfa must be a mosaic (Cfa::None is refused).
  DemosaicStage(Runtime& rt, Cfa cfa, DemosaicMethod method, Precision p);
  DemosaicStage(const DemosaicStage&) = delete;
  DemosaicStage& operator=(const DemosaicStage&) = delete;

  Cfa cfa() const { return cfa_; }
  DemosaicMethod method() const { return method_; }

  // raw (scenes x rows x cols reals of the precision) -> rgb (scenes x 3 x rows x cols), written
  // whole; rows, cols >= 3. Enqueued, not waited for.
  void run(const cl::Buffer& raw, cl::Buffer& rgb, std::size_t rows, std::size_t cols, std::size_t scenes);
  // The transpose: g_rgb (scenes x 3 x rows x cols) -> g_raw (scenes x rows x cols), written whole.
  void adjoint(const cl::Buffer& g_rgb, cl::Buffer& g_raw, std::size_t rows, std::size_t cols, std::size_t scenes);

  // Host forms: raw 1 x H x W per scene (all one shape) -> 3 x H x W per scene, and the transpose.
  std::vector<RealStack> run(const std::vector<RealStack>& raw);
  std::vector<RealStack> adjoint(const std::vector<RealStack>& g_rgb);

 private:
  Runtime& rt_;
  Cfa cfa_;
  DemosaicMethod method_;
  Precision prec_;
  cl::Kernel k_forward_, k_adjoint_;
};

}  // namespace qdo
