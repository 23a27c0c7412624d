// CPU reference of the raw stage (include/qdo/physics/raw_reference.hpp), in double.
#include "qdo/physics/raw_reference.hpp"

#include <cmath>

#include "qdo/runtime/error.hpp"
#include "qdo/runtime/rng.hpp"

namespace qdo {

int cfa_code(Cfa cfa) {
  // Channels of the 2 x 2 cell in order (0, 0), (0, 1), (1, 0), (1, 1); 0 R, 1 G, 2 B.
  auto pack = [](int a, int b, int c, int d) { return a | (b << 2) | (c << 4) | (d << 6); };
  switch (cfa) {
    case Cfa::None: return -1;
    case Cfa::RGGB: return pack(0, 1, 1, 2);
    case Cfa::GRBG: return pack(1, 0, 2, 1);
    case Cfa::GBRG: return pack(1, 2, 0, 1);
    case Cfa::BGGR: return pack(2, 1, 1, 0);
  }
  reject("cfa", static_cast<int>(cfa), "\"none\", \"rggb\", \"grbg\", \"gbrg\" or \"bggr\"");
}

int cfa_channel(Cfa cfa, std::size_t y, std::size_t x) {
  const int code = cfa_code(cfa);
  if (code < 0) return -1;
  return (code >> (2 * int((y & 1) * 2 + (x & 1)))) & 3;
}

namespace ref {
namespace {

// One element's point: the noisy linear value and whether it is clipped, and its code.
struct RawPoint {
  double code = 0;
  bool saturated = false, floored = false;
};

RawPoint raw_point(double v, const SystemConfig& cfg, std::size_t index) {
  if (cfg.read_noise_sigma > 0 || cfg.full_well_photons > 0) {
    const NoiseDraw d = noise_draw(cfg.noise_seed, index, kRawNoiseStream);
    if (cfg.full_well_photons > 0) v = poisson_from(std::fmax(v, 0.0) * cfg.full_well_photons, d) / cfg.full_well_photons;
    v += cfg.read_noise_sigma * d.gaussian;
  }
  const double white = cfg.white_level_dn(), black = cfg.black_level_dn;
  RawPoint pt;
  pt.code = black + cfg.gain * std::fmin(v, 1.0) * (white - black);
  if (v > 1.0 || pt.code > white) {
    pt.saturated = true;
    pt.code = white;
  } else if (pt.code < 0) {
    pt.floored = true;
    pt.code = 0;
  }
  return pt;
}

void check_rgb(const RealStack& rgb, const char* name) {
  if (rgb.planes != 3) reject(name, to_str(rgb.planes) + " planes", "3 x H x W (R, G, B)");
}

}  // namespace

RawFrame raw_forward(const RealStack& rgb, const SystemConfig& cfg, std::size_t scene_index) {
  check_rgb(rgb, "rgb");
  const std::size_t ch = raw_channels(cfg.cfa), hw = rgb.plane_size();
  RawFrame f;
  f.raw = RealStack(ch, rgb.rows, rgb.cols);
  f.unquantized = f.raw;
  f.counts.total = f.raw.size();
  for (std::size_t o = 0; o < ch; ++o)
    for (std::size_t y = 0; y < rgb.rows; ++y)
      for (std::size_t x = 0; x < rgb.cols; ++x) {
        const std::size_t c = cfg.cfa == Cfa::None ? o : std::size_t(cfa_channel(cfg.cfa, y, x)), p = y * rgb.cols + x;
        const RawPoint pt = raw_point(rgb(c, y, x), cfg, (scene_index * hw + p) * 3 + c);
        f.counts.saturated += pt.saturated ? 1 : 0;
        f.counts.floored += pt.floored ? 1 : 0;
        f.unquantized(o, y, x) = pt.code;
        f.raw(o, y, x) = cfg.bit_depth > 0 ? std::floor(pt.code + 0.5) : pt.code;
      }
  return f;
}

RealStack raw_jvp(const RealStack& rgb, const RealStack& d, const SystemConfig& cfg, std::size_t scene_index) {
  check_rgb(rgb, "rgb");
  if (d.planes != 3 || d.rows != rgb.rows || d.cols != rgb.cols) reject("d", to_str(d.planes) + " planes", "the shape of rgb");
  const std::size_t ch = raw_channels(cfg.cfa), hw = rgb.plane_size();
  const double scale = cfg.gain * (cfg.white_level_dn() - cfg.black_level_dn);
  RealStack out(ch, rgb.rows, rgb.cols);
  for (std::size_t o = 0; o < ch; ++o)
    for (std::size_t y = 0; y < rgb.rows; ++y)
      for (std::size_t x = 0; x < rgb.cols; ++x) {
        const std::size_t c = cfg.cfa == Cfa::None ? o : std::size_t(cfa_channel(cfg.cfa, y, x)), p = y * rgb.cols + x;
        const RawPoint pt = raw_point(rgb(c, y, x), cfg, (scene_index * hw + p) * 3 + c);
        out(o, y, x) = pt.saturated || pt.floored ? 0.0 : scale * d(c, y, x);
      }
  return out;
}

RealStack raw_vjp(const RealStack& rgb, const RealStack& g_raw, const SystemConfig& cfg, std::size_t scene_index) {
  check_rgb(rgb, "rgb");
  const std::size_t ch = raw_channels(cfg.cfa), hw = rgb.plane_size();
  if (g_raw.planes != ch || g_raw.rows != rgb.rows || g_raw.cols != rgb.cols)
    reject("g_raw", to_str(g_raw.planes) + " x " + to_str(g_raw.rows) + " x " + to_str(g_raw.cols),
           to_str(ch) + " x H x W with H x W of rgb (" + to_str(rgb.rows) + " x " + to_str(rgb.cols) + ")");
  const double scale = cfg.gain * (cfg.white_level_dn() - cfg.black_level_dn);
  RealStack out(3, rgb.rows, rgb.cols, 0.0);
  for (std::size_t o = 0; o < ch; ++o)
    for (std::size_t y = 0; y < rgb.rows; ++y)
      for (std::size_t x = 0; x < rgb.cols; ++x) {
        const std::size_t c = cfg.cfa == Cfa::None ? o : std::size_t(cfa_channel(cfg.cfa, y, x)), p = y * rgb.cols + x;
        const RawPoint pt = raw_point(rgb(c, y, x), cfg, (scene_index * hw + p) * 3 + c);
        if (!pt.saturated && !pt.floored) out(c, y, x) = scale * g_raw(o, y, x);
      }
  return out;
}

}  // namespace ref
}  // namespace qdo
