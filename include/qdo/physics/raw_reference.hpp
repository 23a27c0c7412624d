// CPU reference of the raw stage (kernels/raw.cl), in double: the sensor as built, from linear
// RGB to raw code values in DN (mosaic, noise, full-well and ADC clipping, black level, gain,
// bit depth), and the Jacobian products of its differentiable part (see raw.hpp for what is
// differentiable). Same noise counters as the device.
#pragma once
#include <cstddef>

#include "qdo/data/config.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

// The colour channel (0 R, 1 G, 2 B) a mosaic filters at pixel (y, x); -1 for Cfa::None.
int cfa_channel(Cfa cfa, std::size_t y, std::size_t x);
// The mosaic as the kernel's code: entry (y & 1) * 2 + (x & 1) of the 2 x 2 cell in bits
// 2 * entry .. 2 * entry + 1; -1 for Cfa::None.
int cfa_code(Cfa cfa);
// Raw planes per scene: 1 with a mosaic, 3 without.
inline std::size_t raw_channels(Cfa cfa) { return cfa == Cfa::None ? 3 : 1; }

// The clipping tally of a raw frame: `saturated` elements (full well or white level exceeded),
// `floored` (code below 0 before clipping: negative read noise beyond the black level), of `total`.
struct RawCounts {
  std::size_t saturated = 0, floored = 0, total = 0;
  double clipped_fraction() const { return total ? double(saturated) / double(total) : 0.0; }
};

namespace ref {

struct RawFrame {
  RealStack raw;          // raw_channels(cfa) x H x W code values, DN
  RealStack unquantized;  // the same before rounding (equal to raw when bit_depth = 0)
  RawCounts counts;
};

// rgb: 3 x H x W linear values (1.0 = full well; SensorStage's output without noise) of scene
// `scene_index` of a batch (the noise counter is (scene_index * H * W + y * W + x) * 3 + c).
// For each raw element (o, y, x), c = cfa_channel(cfg.cfa, y, x) (o without a mosaic):
//   v    = rgb(c, y, x), with shot noise (Poisson, full_well_photons at 1.0; none when 0) and
//          read noise (Gaussian of read_noise_sigma, full-scale units) from noise_seed;
//   code = black + gain * min(v, 1) * (white - black), white = cfg.white_level_dn();
//   saturated when v > 1 or code > white (code = white), floored when code < 0 (code = 0);
//   raw  = round(code) (half up) when bit_depth > 0, else code.
RawFrame raw_forward(const RealStack& rgb, const SystemConfig& cfg, std::size_t scene_index = 0);
// The Jacobian of the differentiable part at rgb (noise included in the point, rounding as the
// identity): d_raw(o, y, x) = gain * (white - black) * d(c, y, x) where the element is unclipped,
// else 0. d: 3 x H x W -> raw_channels x H x W.
RealStack raw_jvp(const RealStack& rgb, const RealStack& d, const SystemConfig& cfg, std::size_t scene_index = 0);
// Its transpose: g_raw raw_channels x H x W -> 3 x H x W (a mosaic scatters each raw element
// into the channel it read; other channels get 0).
RealStack raw_vjp(const RealStack& rgb, const RealStack& g_raw, const SystemConfig& cfg, std::size_t scene_index = 0);

}  // namespace ref
}  // namespace qdo
