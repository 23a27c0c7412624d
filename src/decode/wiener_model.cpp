// The host Wiener decoder's model (include/qdo/decode/wiener.hpp): the spectral prior (SpectralPrior,
// radial_bin, estimate_prior), the PSF <-> OTF transforms and the simulated measurement.
#include "qdo/decode/wiener.hpp"

#include <algorithm>
#include <cmath>
#include <utility>
#include <vector>

#include "decode/wiener_internal.hpp"
#include "qdo/runtime/error.hpp"

namespace qdo {
namespace wiener {
using namespace detail;

// ---------------------------------------------------------------------------------------------
Eigen::MatrixXd SpectralPrior::bin(std::size_t k) const {
  if (k >= bins) reject("bin", k, "< bins = " + to_str(bins));
  Eigen::MatrixXd m(static_cast<Eigen::Index>(bands), static_cast<Eigen::Index>(bands));
  for (std::size_t i = 0; i < bands; ++i)
    for (std::size_t j = 0; j < bands; ++j)
      m(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(j)) = cov[(k * bands + i) * bands + j];
  return m;
}

void SpectralPrior::validate() const {
  if (bands == 0) reject("prior.bands", bands, ">= 1");
  if (bins < 2) reject("prior.bins", bins, ">= 2 (bin 0 is DC alone)");
  if (rows == 0 || cols == 0) reject("prior grid", to_str(rows) + " x " + to_str(cols), "a non-empty H x W grid");
  if (cov.size() != bins * bands * bands)
    reject("prior.cov.size()", cov.size(), "bins * bands * bands = " + to_str(bins * bands * bands));
  for (double v : cov)
    if (!std::isfinite(v)) reject("prior.cov", v, "finite entries");
}

std::size_t radial_bin(std::size_t ky, std::size_t kx, std::size_t rows, std::size_t cols, std::size_t bins) {
  if (bins < 2) reject("bins", bins, ">= 2 (bin 0 is DC alone)");
  if (ky >= rows || kx >= cols)
    reject("(ky, kx)", "(" + to_str(ky) + ", " + to_str(kx) + ")", "inside the " + to_str(rows) + " x " + to_str(cols) + " grid");
  if (ky == 0 && kx == 0) return 0;
  const auto signed_freq = [](std::size_t k, std::size_t m) {
    const double kk = k < (m + 1) / 2 ? double(k) : double(k) - double(m);
    return kk / double(m);
  };
  const double vy = signed_freq(ky, rows), vx = signed_freq(kx, cols);
  const double rho_rel = std::sqrt(2.0 * (vy * vy + vx * vx));  // ρ / ρ_max, in (0, 1]
  const auto k = static_cast<std::size_t>(std::floor(rho_rel * double(bins - 1)));
  return std::min<std::size_t>(1 + k, bins - 1);
}

SpectralPrior estimate_prior(const std::vector<RealStack>& scenes, std::size_t bins) {
  if (bins < 2 || bins > 4096) reject("bins", bins, "in [2, 4096] (bin 0 is DC alone)");
  if (scenes.empty()) reject("scenes.size()", 0, "at least one scene");
  const RealStack& s0 = scenes.front();
  if (s0.size() == 0) reject("scenes[0]", shape(s0), "a non-empty B x H x W cube");
  // bins B x B covariances are allocated next: bounded before (2^27 doubles, 1 GiB).
  if (double(bins) * double(s0.planes) * double(s0.planes) > double(std::size_t(1) << 27))
    reject("bins", bins, "bins x bands^2 <= 2^27 (" + to_str(s0.planes) + " bands: at most " +
                             to_str((std::size_t(1) << 27) / (s0.planes * s0.planes)) + " bins)");
  check_scenes(scenes, s0.planes, s0.rows, s0.cols);
  SpectralPrior pr;
  pr.bands = s0.planes;
  pr.bins = bins;
  pr.rows = s0.rows;
  pr.cols = s0.cols;
  const std::size_t nb = pr.bands, n = pr.rows * pr.cols;
  std::vector<MatrixXd> acc(bins, MatrixXd::Zero(static_cast<Eigen::Index>(nb), static_cast<Eigen::Index>(nb)));
  std::vector<std::size_t> count(bins, 0);
  std::vector<std::size_t> bin_of(n);
  for (std::size_t ky = 0; ky < pr.rows; ++ky)
    for (std::size_t kx = 0; kx < pr.cols; ++kx) bin_of[ky * pr.cols + kx] = radial_bin(ky, kx, pr.rows, pr.cols, bins);
  for (const RealStack& sc : scenes) {
    const ComplexStack x = forward_fft(sc);
    for (std::size_t f = 0; f < n; ++f) {
      const VectorXcd v = gather(x, f);
      acc[bin_of[f]].noalias() += (v * v.adjoint()).real();
      ++count[bin_of[f]];
    }
  }
  pr.cov.assign(bins * nb * nb, 0.0);
  for (std::size_t k = 0; k < bins; ++k) {
    if (count[k] == 0) continue;
    MatrixXd m = acc[k] / (double(count[k]) * double(n));
    m = 0.5 * (m + m.transpose()).eval();
    const double ridge = 1e-9 * m.trace() / double(nb);
    m.diagonal().array() += ridge;
    for (std::size_t i = 0; i < nb; ++i)
      for (std::size_t j = 0; j < nb; ++j)
        pr.cov[(k * nb + i) * nb + j] = m(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(j));
  }
  return pr;
}

// ---------------------------------------------------------------------------------------------
ComplexStack psf_to_otf(const RealStack& psf, std::size_t rows, std::size_t cols) {
  if (psf.rows != psf.cols || psf.rows == 0 || psf.planes == 0) reject("psf", shape(psf), "a non-empty B x S x S stack");
  if (rows == 0 || cols == 0) reject("grid", to_str(rows) + " x " + to_str(cols), "a non-empty H x W grid");
  const std::size_t s = psf.rows, c = s / 2;
  ComplexStack k(psf.planes, rows, cols);
  for (std::size_t b = 0; b < psf.planes; ++b)
    for (std::size_t y = 0; y < s; ++y)
      for (std::size_t x = 0; x < s; ++x) {
        const std::size_t ty = (y + rows * s - c) % rows, tx = (x + cols * s - c) % cols;
        k(b, ty, tx) += psf(b, y, x);
      }
  fft2(k, FFTW_FORWARD, Scale::None);
  return k;
}

RealStack psf_gradient(const ComplexStack& grad_otf, std::size_t psf_size) {
  if (grad_otf.size() == 0) reject("grad_otf", shape(grad_otf), "a non-empty B x H x W stack");
  if (psf_size == 0) reject("psf_size", psf_size, ">= 1");
  ComplexStack g = grad_otf;
  fft2(g, FFTW_BACKWARD, Scale::None);  // Σ_f G(f) e^{+i2π f·r}
  const std::size_t rows = g.rows, cols = g.cols, s = psf_size, c = s / 2;
  RealStack out(g.planes, s, s);
  for (std::size_t b = 0; b < g.planes; ++b)
    for (std::size_t y = 0; y < s; ++y)
      for (std::size_t x = 0; x < s; ++x) {
        const std::size_t ty = (y + rows * s - c) % rows, tx = (x + cols * s - c) % cols;
        out(b, y, x) = g(b, ty, tx).real();
      }
  return out;
}

RealStack simulate_measurement(const RealStack& cube, const ComplexStack& otf, const Eigen::MatrixXd& srf) {
  if (cube.size() == 0) reject("cube", shape(cube), "a non-empty B x H x W cube");
  if (otf.planes != cube.planes || otf.rows != cube.rows || otf.cols != cube.cols)
    reject("otf", shape(otf), "the cube's shape " + shape(cube));
  if (srf.rows() < 1 || static_cast<std::size_t>(srf.cols()) != cube.planes)
    reject("srf", to_str(srf.rows()) + " x " + to_str(srf.cols()), "C x B with B = " + to_str(cube.planes));
  const ComplexStack x = forward_fft(cube);
  const std::size_t n = cube.plane_size(), nc = static_cast<std::size_t>(srf.rows());
  ComplexStack y(nc, cube.rows, cube.cols);
  for (std::size_t c = 0; c < nc; ++c)
    for (std::size_t b = 0; b < cube.planes; ++b) {
      const double w = srf(static_cast<Eigen::Index>(c), static_cast<Eigen::Index>(b));
      if (w == 0) continue;
      const cdouble* xo = x.plane(b);
      const cdouble* o = otf.plane(b);
      cdouble* yo = y.plane(c);
      for (std::size_t f = 0; f < n; ++f) yo[f] += w * o[f] * xo[f];
    }
  return inverse_fft_real(std::move(y));
}

}  // namespace wiener
}  // namespace qdo
