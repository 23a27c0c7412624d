// The CPU reference of the release's image formation (include/qdo/physics/release_reference.hpp), in
// double, literally: arrays padded, rolled and transformed with FFTW (the device path is
// release.cpp, kernels/release.cl).
#include "qdo/physics/release_reference.hpp"

#include <algorithm>
#include <cmath>
#include <string>

#include "qdo/runtime/error.hpp"
#include "qdo/runtime/fftw2.hpp"

namespace qdo {

namespace ref {
namespace {
// TF2's half-pixel bilinear taps for output index i of an in -> out resize.
void tap(std::size_t i, std::size_t in, std::size_t out, std::size_t& lo, std::size_t& hi, double& w) {
  const double t = (double(i) + 0.5) * double(in) / double(out) - 0.5;
  const double f = std::floor(t);
  lo = f < 0 ? 0 : std::size_t(f);
  const double c = std::ceil(t);
  hi = std::min(in - 1, c < 0 ? std::size_t(0) : std::size_t(c));
  w = t - f;
}
}  // namespace

RealStack resize_bilinear(const RealStack& x, std::size_t rows, std::size_t cols) {
  if (x.rows == 0 || x.cols == 0) reject("x", to_str(x.rows) + " x " + to_str(x.cols), "non-empty planes");
  if (rows == 0 || cols == 0) reject("output size", to_str(rows) + " x " + to_str(cols), "positive sizes");
  RealStack out(x.planes, rows, cols);
  for (std::size_t b = 0; b < x.planes; ++b)
    for (std::size_t i = 0; i < rows; ++i) {
      std::size_t y0, y1, x0, x1;
      double wy, wx;
      tap(i, x.rows, rows, y0, y1, wy);
      for (std::size_t j = 0; j < cols; ++j) {
        tap(j, x.cols, cols, x0, x1, wx);
        const double top = x(b, y0, x0) + (x(b, y0, x1) - x(b, y0, x0)) * wx;
        const double bot = x(b, y1, x0) + (x(b, y1, x1) - x(b, y1, x0)) * wx;
        out(b, i, j) = top + (bot - top) * wy;
      }
    }
  return out;
}

RealStack release_blur(const RealStack& cube, const RealStack& psf_native) {
  if (cube.rows != cube.cols) reject("cube", to_str(cube.rows) + " x " + to_str(cube.cols), "square S x S scenes");
  if (psf_native.rows != psf_native.cols) reject("psf_native", to_str(psf_native.rows) + " x " + to_str(psf_native.cols), "square N x N");
  if (cube.planes != psf_native.planes) reject("cube bands", cube.planes, "the PSF's band count (" + to_str(psf_native.planes) + ")");
  const ReleaseGeometry g = release_geometry(cube.rows, psf_native.rows);
  const std::size_t n = g.n, gg = g.g;
  // 1. Up-sample; 2. symmetric padding (edge repeated), as arrays.
  const RealStack up = resize_bilinear(cube, n, n);
  auto mirror = [&](std::size_t k) {
    long v = long(k) - long(g.before);
    if (v < 0) v = -v - 1;
    if (v >= long(n)) v = 2 * long(n) - 1 - v;
    return std::size_t(v);
  };
  ComplexStack a(cube.planes, gg, gg), k(cube.planes, gg, gg, cdouble(0, 0));
  for (std::size_t b = 0; b < cube.planes; ++b)
    for (std::size_t y = 0; y < gg; ++y)
      for (std::size_t x = 0; x < gg; ++x) a(b, y, x) = up(b, mirror(y), mirror(x));
  // 3. psf2otf: zero-pad the PSF to G (psf_before first), then ifftshift (index split -> 0).
  ComplexStack padded(cube.planes, gg, gg, cdouble(0, 0));
  for (std::size_t b = 0; b < cube.planes; ++b)
    for (std::size_t y = 0; y < n; ++y)
      for (std::size_t x = 0; x < n; ++x) padded(b, y + g.psf_before, x + g.psf_before) = psf_native(b, y, x);
  for (std::size_t b = 0; b < cube.planes; ++b)
    for (std::size_t y = 0; y < gg; ++y)
      for (std::size_t x = 0; x < gg; ++x) k(b, y, x) = padded(b, (y + g.split) % gg, (x + g.split) % gg);
  fftw2(a, true);
  fftw2(k, true);
  for (std::size_t i = 0; i < a.size(); ++i) a.data[i] *= k.data[i];
  fftw2(a, false);  // scaled by 1 / G²
  // 4. Crop [before, before + N), down-sample to S.
  RealStack crop(cube.planes, n, n);
  for (std::size_t b = 0; b < cube.planes; ++b)
    for (std::size_t y = 0; y < n; ++y)
      for (std::size_t x = 0; x < n; ++x) crop(b, y, x) = a(b, y + g.before, x + g.before).real();
  return resize_bilinear(crop, cube.rows, cube.cols);
}

}  // namespace ref

}  // namespace qdo
