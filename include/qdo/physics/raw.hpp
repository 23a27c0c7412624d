// The sensor as built on the device (kernels/raw.cl): linear RGB (SensorStage's output before
// noise, 1.0 = full well) -> raw code values in DN, as a real camera's raw file holds them:
//   colour filter mosaic   cfa: each pixel keeps the channel its filter passes (RGGB, GRBG, GBRG,
//                          BGGR: one plane per scene) or all three ("none": three planes);
//   noise                  shot noise (full_well_photons at 1.0) and read noise (read_noise_sigma,
//                          full-scale units), Philox counters from noise_seed in the raw stream;
//   full well and ADC      code = black_level_dn + gain * min(v, 1) * (white - black_level_dn),
//                          white = cfg.white_level_dn(); saturated (v > 1 or code > white: code =
//                          white) and floored (code < 0: code = 0) elements are counted;
//   bit depth              round to integer DN (half up) when bit_depth > 0.
// Differentiable part: the map is piecewise linear. Its Jacobian at a point is the mosaic sampling
// times gain * (white - black) times the clip mask (0 at saturated and floored elements);
// the rounding is taken as straight-through (identity), and the noise is part of the point
// (recomputed from the same counters, so the adjoint sees the forward's mask; shot noise, a
// step function of the signal, is straight-through as well: its count is held fixed). The adjoint
// scatters each raw element back into the channel it read (0 to the channels a mosaic drops).
// The ladder of tests/adjoint_ladder.hpp checks it where the map is differentiable (bit_depth 0,
// read noise only; rows adjoint_rows::raw in tests/test_raw.cpp).
// CPU reference: ref::raw_forward, ref::raw_jvp, ref::raw_vjp (raw_reference.hpp).
#pragma once
#include <CL/opencl.hpp>

#include <cstddef>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/physics/raw_reference.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

class RawStage {
 public:
  // One per (configuration, precision); the configuration is taken as valid.
  RawStage(Runtime& rt, const SystemConfig& cfg, Precision p);
  RawStage(const RawStage&) = delete;
  RawStage& operator=(const RawStage&) = delete;

  // Raw planes per scene: 1 with a mosaic, 3 without.
  std::size_t channels() const { return raw_channels(cfg_.cfa); }

  // rgb (scenes x 3 x rows x cols reals of the precision) -> raw (scenes x channels() x rows x
  // cols), scene k's noise with counters (k * rows * cols + y * cols + x) * 3 + c. Blocking: returns
  // the clipping tally read back from the device.
  RawCounts run(const cl::Buffer& rgb, cl::Buffer& raw, std::size_t rows, std::size_t cols, std::size_t scenes);
  // The adjoint of run's differentiable part at rgb: g_raw (scenes x channels() x rows x cols)
  // -> g_rgb (scenes x 3 x rows x cols), written whole.
  void adjoint(const cl::Buffer& rgb, const cl::Buffer& g_raw, cl::Buffer& g_rgb, std::size_t rows, std::size_t cols,
               std::size_t scenes);

  // Host forms (tests, tools): one 3 x H x W stack per scene, all of one shape.
  struct Frames {
    std::vector<RealStack> raw;  // channels() x H x W per scene, DN
    RawCounts counts;            // over the whole batch
  };
  Frames run(const std::vector<RealStack>& rgb);
  std::vector<RealStack> adjoint(const std::vector<RealStack>& rgb, const std::vector<RealStack>& g_raw);

 private:
  Runtime& rt_;
  SystemConfig cfg_;
  Precision prec_;
  cl::Kernel k_forward_, k_adjoint_;
  cl::Buffer counts_;  // 2 cl_uint: saturated, floored
};

}  // namespace qdo
