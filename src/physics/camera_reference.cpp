#include "qdo/physics/camera_reference.hpp"

#include <vector>

#include "qdo/runtime/error.hpp"
#include "qdo/physics/optics.hpp"
#include "reference_internal.hpp"

namespace qdo::ref {

using detail::fft2_batch;

RealStack convolve(const RealStack& cube, const RealStack& psf, ConvolutionMode mode) {
  if (cube.planes != psf.planes) reject("cube bands", cube.planes, "the PSF stack's band count (" + to_str(psf.planes) + ")");
  if (psf.rows != psf.cols) reject("psf", to_str(psf.rows) + " x " + to_str(psf.cols), "square PSFs");
  const std::size_t h = cube.rows, w = cube.cols, s = psf.rows, c = s / 2;
  const std::size_t py = mode == ConvolutionMode::Linear ? fast_fft_size(h + s - 1) : h;
  const std::size_t px = mode == ConvolutionMode::Linear ? fast_fft_size(w + s - 1) : w;
  ComplexStack a(cube.planes, py, px, cdouble(0, 0)), k(cube.planes, py, px, cdouble(0, 0));
  for (std::size_t b = 0; b < cube.planes; ++b) {
    for (std::size_t y = 0; y < h; ++y)
      for (std::size_t x = 0; x < w; ++x) a(b, y, x) = cube(b, y, x);
    // PSF centre (c, c) goes to index (0, 0); wrap (and, for circular, fold) the rest.
    for (std::size_t y = 0; y < s; ++y)
      for (std::size_t x = 0; x < s; ++x) {
        const std::size_t ty = (y + py * s - c) % py, tx = (x + px * s - c) % px;
        k(b, ty, tx) += psf(b, y, x);
      }
  }
  fft2_batch(a, FFTW_FORWARD);
  fft2_batch(k, FFTW_FORWARD);
  for (std::size_t i = 0; i < a.size(); ++i) a.data[i] *= k.data[i];
  fft2_batch(a, FFTW_BACKWARD);
  RealStack out(cube.planes, h, w);
  for (std::size_t b = 0; b < cube.planes; ++b)
    for (std::size_t y = 0; y < h; ++y)
      for (std::size_t x = 0; x < w; ++x) out(b, y, x) = a(b, y, x).real();
  return out;
}

RealStack convolve_vjp_psf(const RealStack& cube, const RealStack& g_out, std::size_t psf_size, ConvolutionMode mode) {
  if (g_out.planes != cube.planes || g_out.rows != cube.rows || g_out.cols != cube.cols)
    reject("g_out", to_str(g_out.planes) + " x " + to_str(g_out.rows) + " x " + to_str(g_out.cols), "the cube's shape");
  // <convolve(cube, psf), g> is linear in psf: probe it one PSF pixel at a time would be slow;
  // instead correlate: g_psf[b][y][x] = sum_{p} g[b][p] * cube[b][p - (y - c, x - c)] over the
  // same (zero-padded or periodic) grid the forward convolution uses.
  const std::size_t h = cube.rows, w = cube.cols, s = psf_size, c = s / 2;
  const bool lin = mode == ConvolutionMode::Linear;
  const std::size_t py = lin ? fast_fft_size(h + s - 1) : h, px = lin ? fast_fft_size(w + s - 1) : w;
  RealStack out(cube.planes, s, s);
  for (std::size_t b = 0; b < cube.planes; ++b) {
    // r[u][v] = sum_{y',x'} g[y'][x'] X[(y' - u) mod P][(x' - v) mod P] on the padded grid.
    std::vector<double> r(py * px, 0.0);
    for (std::size_t u = 0; u < py; ++u)
      for (std::size_t v = 0; v < px; ++v) {
        double acc = 0;
        for (std::size_t y = 0; y < h; ++y) {
          const std::size_t sy = (y + py - u) % py;
          if (sy >= h) continue;
          for (std::size_t x = 0; x < w; ++x) {
            const std::size_t sx = (x + px - v) % px;
            if (sx < w) acc += g_out(b, y, x) * cube(b, sy, sx);
          }
        }
        r[u * px + v] = acc;
      }
    for (std::size_t y = 0; y < s; ++y)
      for (std::size_t x = 0; x < s; ++x) out(b, y, x) = r[((y + py * s - c) % py) * px + (x + px * s - c) % px];
  }
  return out;
}

RealStack convolve_vjp_scene(const RealStack& psf, const RealStack& g_out, ConvolutionMode mode) {
  if (psf.planes != g_out.planes || psf.rows != psf.cols)
    reject("psf", shape(psf), "square planes, one per band of g_out (" + to_str(g_out.planes) + ")");
  const long h = long(g_out.rows), w = long(g_out.cols), s = long(psf.rows), c = s / 2;
  const bool lin = mode == ConvolutionMode::Linear;
  RealStack out(g_out.planes, g_out.rows, g_out.cols);
  for (std::size_t b = 0; b < g_out.planes; ++b)
    for (long qy = 0; qy < h; ++qy)
      for (long qx = 0; qx < w; ++qx) {
        double acc = 0;
        for (long ty = -c; ty < s - c; ++ty)
          for (long tx = -c; tx < s - c; ++tx) {
            long py = qy + ty, px = qx + tx;
            if (lin && (py < 0 || py >= h || px < 0 || px >= w)) continue;
            py = ((py % h) + h) % h;
            px = ((px % w) + w) % w;
            acc += g_out(b, std::size_t(py), std::size_t(px)) * psf(b, std::size_t(ty + c), std::size_t(tx + c));
          }
        out(b, std::size_t(qy), std::size_t(qx)) = acc;
      }
  return out;
}

}  // namespace qdo::ref
