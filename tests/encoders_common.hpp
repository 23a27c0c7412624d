// Helpers of the encoder and masked-decoder tests (test_encoders.cpp, test_wiener_masked.cpp):
// seeded random stacks, responses and priors, scenes drawn from a prior, and dense matrices of a
// prior covariance and of an encoder built from their definitions (independent of the solvers).
#pragma once
#include <doctest/doctest.h>

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "adjoint_ladder.hpp"
#include "common.hpp"
#include "wiener_common.hpp"
#include "qdo/decode/encoders.hpp"
#include "qdo/decode/wiener.hpp"
#include "qdo/runtime/fftw2.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo::test::encoders_suite {

// Random responses (C x B, rows summing to 1) and well-conditioned SPD priors with a larger DC bin
// (eigenvalues >= 0.2 x scale, so a dense inverse is accurate): the Wiener suite's.
using wiener_suite::random_prior;
using wiener_suite::random_srf;

using Rng = std::mt19937_64;
using Eigen::Index;

inline Index ix(std::size_t i) { return static_cast<Index>(i); }

inline double normal(Rng& r) { return std::normal_distribution<double>(0.0, 1.0)(r); }

inline RealStack normal_stack(Rng& r, std::size_t p, std::size_t h, std::size_t w) {
  RealStack s(p, h, w);
  for (double& v : s.data) v = normal(r);
  return s;
}

inline double norm(const RealStack& a) { return std::sqrt(dot(a.data, a.data)); }

inline double mse(const RealStack& a, const RealStack& b) {
  REQUIRE(a.size() == b.size());
  double s = 0;
  for (std::size_t i = 0; i < a.size(); ++i) s += (a.data[i] - b.data[i]) * (a.data[i] - b.data[i]);
  return s / double(a.size());
}



// A zero-mean Gaussian scene with E[X(f) X(f)^H] = H W P(bin f): real white noise z (so
// E[Z Z^H] = H W I) coloured in the DFT domain by the Cholesky factor of each bin (the same real
// factor at f and -f, so the scene stays real). Independent of apply_prior_power (eigenvectors).
inline RealStack sample_from_prior(Rng& r, const wiener::SpectralPrior& p) {
  ComplexStack z(p.bands, p.rows, p.cols);
  for (cdouble& v : z.data) v = normal(r);
  fftw2(z, true);
  const std::size_t n = p.rows * p.cols;
  std::vector<Eigen::MatrixXd> chol;
  for (std::size_t k = 0; k < p.bins; ++k) chol.push_back(p.bin(k).llt().matrixL());
  ComplexStack xf(p.bands, p.rows, p.cols);
  for (std::size_t ky = 0; ky < p.rows; ++ky)
    for (std::size_t kx = 0; kx < p.cols; ++kx) {
      const std::size_t f = ky * p.cols + kx;
      const Eigen::MatrixXd& l = chol[wiener::radial_bin(ky, kx, p.rows, p.cols, p.bins)];
      for (std::size_t i = 0; i < p.bands; ++i) {
        cdouble acc = 0;
        for (std::size_t j = 0; j <= i; ++j) acc += l(ix(i), ix(j)) * z.data[j * n + f];
        xf.data[i * n + f] = acc;
      }
    }
  fftw2(xf, false, true);
  RealStack out(p.bands, p.rows, p.cols);
  double max_imag = 0;
  for (std::size_t i = 0; i < out.size(); ++i) {
    out.data[i] = xf.data[i].real();
    max_imag = std::max(max_imag, std::fabs(xf.data[i].imag()));
  }
  REQUIRE(max_imag < 1e-12);  // Hermitian symmetry kept
  return out;
}

// Dense C (B·H·W square, index (b·H + y)·W + x) straight from the definition
// C[(b,r),(b',r')] = 1/(HW) Σ_f P_bb'(bin f) e^{i2π f·(r − r')}: a circulant block per (b, b').
inline Eigen::MatrixXd dense_prior_covariance(const wiener::SpectralPrior& p) {
  const std::size_t h = p.rows, w = p.cols, nb = p.bands, n = h * w;
  // c[(b, b')][dy, dx]
  std::vector<Eigen::MatrixXd> c(n, Eigen::MatrixXd::Zero(ix(nb), ix(nb)));
  for (std::size_t dy = 0; dy < h; ++dy)
    for (std::size_t dx = 0; dx < w; ++dx) {
      Eigen::MatrixXd acc = Eigen::MatrixXd::Zero(ix(nb), ix(nb));
      for (std::size_t ky = 0; ky < h; ++ky)
        for (std::size_t kx = 0; kx < w; ++kx) {
          const double ph = 2.0 * M_PI * (double(ky * dy) / double(h) + double(kx * dx) / double(w));
          acc += std::cos(ph) * p.bin(wiener::radial_bin(ky, kx, h, w, p.bins));  // imaginary parts cancel (f, -f)
        }
      c[dy * w + dx] = acc / double(n);
    }
  Eigen::MatrixXd out(ix(nb * n), ix(nb * n));
  for (std::size_t b = 0; b < nb; ++b)
    for (std::size_t y = 0; y < h; ++y)
      for (std::size_t x = 0; x < w; ++x)
        for (std::size_t b2 = 0; b2 < nb; ++b2)
          for (std::size_t y2 = 0; y2 < h; ++y2)
            for (std::size_t x2 = 0; x2 < w; ++x2) {
              const std::size_t dy = (y + h - y2) % h, dx = (x + w - x2) % w;
              out(ix((b * h + y) * w + x), ix((b2 * h + y2) * w + x2)) = c[dy * w + dx](ix(b), ix(b2));
            }
  return out;
}

// Dense matrix of an encoder, columns = measure(unit vectors).
inline Eigen::MatrixXd dense_encoder(const Encoder& e) {
  const std::size_t nin = e.bands() * e.rows() * e.cols(), nout = e.channels() * e.rows() * e.out_cols();
  Eigen::MatrixXd a(ix(nout), ix(nin));
  RealStack u(e.bands(), e.rows(), e.cols());
  for (std::size_t j = 0; j < nin; ++j) {
    u.data[j] = 1.0;
    const RealStack col = e.measure(u);
    u.data[j] = 0.0;
    for (std::size_t i = 0; i < nout; ++i) a(ix(i), ix(j)) = col.data[i];
  }
  return a;
}

inline Eigen::VectorXd as_vector(const RealStack& s) {
  return Eigen::Map<const Eigen::VectorXd>(s.data.data(), ix(s.size()));
}

}  // namespace qdo::test::encoders_suite
