// CPU reference of the demosaic stage (include/qdo/physics/demosaic_reference.hpp), in double. The filters
// are written out as tap lists from the formulas (the kernel holds them as a 5 x 5 table: two
// spellings of the same numbers, compared by the tests).
#include "qdo/physics/demosaic_reference.hpp"

#include <algorithm>
#include <cctype>
#include <vector>

#include "qdo/runtime/error.hpp"
#include "qdo/physics/raw_reference.hpp"

namespace qdo {

DemosaicMethod demosaic_method_from_string(const std::string& s, const std::string& argument) {
  std::string l(s);
  std::transform(l.begin(), l.end(), l.begin(), [](unsigned char ch) { return char(std::tolower(ch)); });
  if (l == "bilinear") return DemosaicMethod::Bilinear;
  if (l == "mhc") return DemosaicMethod::MHC;
  reject(argument, "\"" + s + "\"", "\"bilinear\" or \"mhc\" (Malvar-He-Cutler)");
}

std::string to_string(DemosaicMethod m) { return m == DemosaicMethod::Bilinear ? "bilinear" : "mhc"; }

RealStack raw_to_linear(const RealStack& raw_dn, const SystemConfig& cfg) {
  const double black = cfg.black_level_dn, span = cfg.gain * (cfg.white_level_dn() - black);
  if (!(span > 0)) reject("gain * (white - black level)", span, "positive");
  RealStack out = raw_dn;
  for (double& v : out.data) v = (v - black) / span;
  return out;
}

namespace ref {
namespace {

struct Tap {
  int dy, dx;
  double w;
};
using Filter = std::vector<Tap>;

// The four interpolating filters of a method, from the formulas in demosaic_reference.hpp.
// horizontal: the wanted colour lies left and right; vertical: above and below.
struct Filters {
  Filter cross, horizontal, vertical, diagonal;
};

Filter transpose(const Filter& f) {
  Filter t;
  for (const Tap& k : f) t.push_back({k.dx, k.dy, k.w});
  return t;
}

Filters filters(DemosaicMethod m) {
  Filters f;
  if (m == DemosaicMethod::Bilinear) {
    f.cross = {{-1, 0, 0.25}, {1, 0, 0.25}, {0, -1, 0.25}, {0, 1, 0.25}};
    f.horizontal = {{0, -1, 0.5}, {0, 1, 0.5}};
    f.diagonal = {{-1, -1, 0.25}, {-1, 1, 0.25}, {1, -1, 0.25}, {1, 1, 0.25}};
  } else {
    f.cross = {{0, 0, 4.0 / 8},   {-1, 0, 2.0 / 8},  {1, 0, 2.0 / 8},  {0, -1, 2.0 / 8}, {0, 1, 2.0 / 8},
               {-2, 0, -1.0 / 8}, {2, 0, -1.0 / 8}, {0, -2, -1.0 / 8}, {0, 2, -1.0 / 8}};
    f.horizontal = {{0, 0, 5.0 / 8},   {0, -1, 4.0 / 8},  {0, 1, 4.0 / 8},   {0, -2, -1.0 / 8}, {0, 2, -1.0 / 8},
                    {-1, -1, -1.0 / 8}, {-1, 1, -1.0 / 8}, {1, -1, -1.0 / 8}, {1, 1, -1.0 / 8},  {-2, 0, 0.5 / 8},
                    {2, 0, 0.5 / 8}};
    f.diagonal = {{0, 0, 6.0 / 8},   {-1, -1, 2.0 / 8}, {-1, 1, 2.0 / 8},  {1, -1, 2.0 / 8}, {1, 1, 2.0 / 8},
                  {-2, 0, -1.5 / 8}, {2, 0, -1.5 / 8},  {0, -2, -1.5 / 8}, {0, 2, -1.5 / 8}};
  }
  f.vertical = transpose(f.horizontal);
  return f;
}

const Filter kIdentity = {{0, 0, 1.0}};

// The filter giving channel c at pixel (y, x) of the mosaic.
const Filter& filter_for(const Filters& f, Cfa cfa, std::size_t y, std::size_t x, int c) {
  const int site = cfa_channel(cfa, y, x);
  if (site == c) return kIdentity;
  if (c == 1) return f.cross;  // G at an R or B site
  if (site != 1) return f.diagonal;  // R at B, B at R
  // A green site: is channel c left and right of it?
  return cfa_channel(cfa, y, x ^ 1u) == c ? f.horizontal : f.vertical;
}

// Mirror about the edge pixel (no repeat); n >= 3 and |i - inside| <= 2.
std::size_t mirror(long i, std::size_t n) {
  if (i < 0) i = -i;
  if (i >= long(n)) i = 2 * (long(n) - 1) - i;
  return std::size_t(i);
}

void check(const RealStack& s, std::size_t planes, Cfa cfa, const char* name) {
  if (cfa == Cfa::None) reject("cfa", "\"none\"", "a mosaic to demosaic: \"rggb\", \"grbg\", \"gbrg\" or \"bggr\"");
  if (s.planes != planes || s.rows < 3 || s.cols < 3)
    reject(name, shape(s), to_str(planes) + " x H x W with H, W >= 3");
}

}  // namespace

RealStack demosaic(const RealStack& raw, Cfa cfa, DemosaicMethod method) {
  check(raw, 1, cfa, "raw");
  const Filters f = filters(method);
  RealStack out(3, raw.rows, raw.cols);
  for (int c = 0; c < 3; ++c)
    for (std::size_t y = 0; y < raw.rows; ++y)
      for (std::size_t x = 0; x < raw.cols; ++x) {
        double s = 0;
        for (const Tap& t : filter_for(f, cfa, y, x, c))
          s += t.w * raw(0, mirror(long(y) + t.dy, raw.rows), mirror(long(x) + t.dx, raw.cols));
        out(std::size_t(c), y, x) = s;
      }
  return out;
}

RealStack demosaic_vjp(const RealStack& g_rgb, Cfa cfa, DemosaicMethod method) {
  check(g_rgb, 3, cfa, "g_rgb");
  const Filters f = filters(method);
  RealStack g(1, g_rgb.rows, g_rgb.cols);
  for (int c = 0; c < 3; ++c)
    for (std::size_t y = 0; y < g.rows; ++y)
      for (std::size_t x = 0; x < g.cols; ++x)
        for (const Tap& t : filter_for(f, cfa, y, x, c))
          g(0, mirror(long(y) + t.dy, g.rows), mirror(long(x) + t.dx, g.cols)) += t.w * g_rgb(std::size_t(c), y, x);
  return g;
}

RealStack mosaic_planes(const RealStack& raw, Cfa cfa) {
  if (cfa == Cfa::None) reject("cfa", "\"none\"", "a mosaic: \"rggb\", \"grbg\", \"gbrg\" or \"bggr\"");
  if (raw.planes != 1) reject("raw", shape(raw), "1 x H x W");
  RealStack out(3, raw.rows, raw.cols);
  for (std::size_t y = 0; y < raw.rows; ++y)
    for (std::size_t x = 0; x < raw.cols; ++x) out(std::size_t(cfa_channel(cfa, y, x)), y, x) = raw(0, y, x);
  return out;
}

}  // namespace ref
}  // namespace qdo
