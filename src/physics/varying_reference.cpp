#include "qdo/physics/varying_reference.hpp"

#include <vector>

#include "qdo/physics/camera_reference.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/physics/sensor_reference.hpp"

namespace qdo::ref {

namespace {

void check(const RealStack& scene, const RealStack& psfs, const RealStack& weights, const Eigen::MatrixXd& srf) {
  const std::size_t bands = scene.planes, kk = weights.planes;
  if (bands == 0 || Eigen::Index(bands) != srf.cols()) reject("scene bands", bands, "the response's " + to_str(srf.cols()) + " bands");
  if (psfs.planes != kk * bands || psfs.rows != psfs.cols)
    reject("psfs", shape(psfs), "(K * bands) x S x S with K = " + to_str(kk) + ", bands = " + to_str(bands));
  if (weights.rows != scene.rows || weights.cols != scene.cols) reject("weights", shape(weights), "K x H x W with the scene's H x W");
}

// Component k's planes (bands x S x S) of psfs ((K * bands) x S x S, component-major).
RealStack component(const RealStack& psfs, std::size_t k, std::size_t bands) {
  RealStack out(bands, psfs.rows, psfs.cols);
  std::copy(psfs.plane(k * bands), psfs.plane(k * bands) + bands * psfs.plane_size(), out.data.begin());
  return out;
}

// a ⊙ w_k over every plane of a (planes x H x W; weights K x H x W).
RealStack weighted(const RealStack& a, const RealStack& weights, std::size_t k) {
  RealStack out = a;
  const std::size_t hw = a.plane_size();
  for (std::size_t b = 0; b < a.planes; ++b)
    for (std::size_t i = 0; i < hw; ++i) out.plane(b)[i] *= weights.plane(k)[i];
  return out;
}

// acc += a, element by element (same shape).
void add(RealStack& acc, const RealStack& a) {
  for (std::size_t i = 0; i < acc.size(); ++i) acc.data[i] += a.data[i];
}

}  // namespace

RealStack varying_images(const RealStack& scene, const RealStack& psfs, const RealStack& weights,
                         const Eigen::MatrixXd& srf, PsfPlacement placement) {
  check(scene, psfs, weights, srf);
  const std::size_t bands = scene.planes;
  RealStack blur(bands, scene.rows, scene.cols);
  for (std::size_t k = 0; k < weights.planes; ++k) {
    const RealStack pk = component(psfs, k, bands);
    if (placement == PsfPlacement::Source) add(blur, convolve(weighted(scene, weights, k), pk, ConvolutionMode::Linear));
    else add(blur, weighted(convolve(scene, pk, ConvolutionMode::Linear), weights, k));
  }
  return sensor_integrate(blur, srf);
}

VaryingGradient varying_vjp(const RealStack& scene, const RealStack& psfs, const RealStack& weights,
                            const Eigen::MatrixXd& srf, PsfPlacement placement, const RealStack& g_rgb) {
  check(scene, psfs, weights, srf);
  const std::size_t bands = scene.planes, s = psfs.rows;
  const RealStack gb = sensor_integrate_vjp(g_rgb, srf);  // bands x H x W
  VaryingGradient out{RealStack(bands, scene.rows, scene.cols), RealStack(psfs.planes, s, s), RealStack(weights.planes, scene.rows, scene.cols)};
  const std::size_t hw = scene.plane_size();
  // gw_k(q) = sum_j a(j, q) b(j, q).
  auto weight_grad = [&](std::size_t k, const RealStack& a, const RealStack& b) {
    for (std::size_t j = 0; j < a.planes; ++j)
      for (std::size_t i = 0; i < hw; ++i) out.weights.plane(k)[i] += a.plane(j)[i] * b.plane(j)[i];
  };
  for (std::size_t k = 0; k < weights.planes; ++k) {
    const RealStack pk = component(psfs, k, bands);
    RealStack gpk;
    if (placement == PsfPlacement::Source) {
      const RealStack back = convolve_vjp_scene(pk, gb, ConvolutionMode::Linear);
      add(out.scene, weighted(back, weights, k));
      weight_grad(k, scene, back);
      gpk = convolve_vjp_psf(weighted(scene, weights, k), gb, s, ConvolutionMode::Linear);
    } else {
      const RealStack gw = weighted(gb, weights, k);
      add(out.scene, convolve_vjp_scene(pk, gw, ConvolutionMode::Linear));
      weight_grad(k, g_rgb, sensor_integrate(convolve(scene, pk, ConvolutionMode::Linear), srf));
      gpk = convolve_vjp_psf(scene, gw, s, ConvolutionMode::Linear);
    }
    std::copy(gpk.data.begin(), gpk.data.end(), out.psfs.plane(k * bands));
  }
  return out;
}

RealStack varying_images_brute_force(const RealStack& scene, const RealStack& psfs, const RealStack& weights,
                                     const Eigen::MatrixXd& srf, PsfPlacement placement) {
  check(scene, psfs, weights, srf);
  const long bands = long(scene.planes), h = long(scene.rows), w = long(scene.cols), s = long(psfs.rows), c = s / 2;
  const long kk = long(weights.planes);
  RealStack blur(scene.planes, scene.rows, scene.cols);
  std::vector<double> pq(std::size_t(bands * s * s));
  for (long y = 0; y < h; ++y)
    for (long x = 0; x < w; ++x) {
      // This pixel's own PSF.
      std::fill(pq.begin(), pq.end(), 0.0);
      for (long k = 0; k < kk; ++k) {
        const double wk = weights(std::size_t(k), std::size_t(y), std::size_t(x));
        if (wk == 0) continue;
        const double* src = psfs.plane(std::size_t(k * bands));
        for (std::size_t i = 0; i < pq.size(); ++i) pq[i] += wk * src[i];
      }
      for (long b = 0; b < bands; ++b)
        for (long ty = -c; ty < s - c; ++ty)
          for (long tx = -c; tx < s - c; ++tx) {
            const double p = pq[std::size_t((b * s + ty + c) * s + tx + c)];
            if (placement == PsfPlacement::Source) {
              const long oy = y + ty, ox = x + tx;
              if (oy < 0 || oy >= h || ox < 0 || ox >= w) continue;
              blur(std::size_t(b), std::size_t(oy), std::size_t(ox)) += p * scene(std::size_t(b), std::size_t(y), std::size_t(x));
            } else {
              const long iy = y - ty, ix = x - tx;
              if (iy < 0 || iy >= h || ix < 0 || ix >= w) continue;
              blur(std::size_t(b), std::size_t(y), std::size_t(x)) += p * scene(std::size_t(b), std::size_t(iy), std::size_t(ix));
            }
          }
    }
  return sensor_integrate(blur, srf);
}

}  // namespace qdo::ref
