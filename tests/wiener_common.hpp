// Helpers of the Wiener decoder's tests (test_wiener.cpp, test_wiener_sigma.cpp): seeded random
// stacks, PSFs, sensor responses and priors, a naive DFT, and scenes drawn from a prior.
#pragma once
#include <doctest/doctest.h>

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <complex>
#include <random>
#include <vector>

#include "qdo/decode/wiener.hpp"
#include "qdo/physics/cpu_reference.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo::test::wiener_suite {

using namespace qdo::wiener;

using Rng = std::mt19937_64;

inline double uniform(Rng& r, double lo = 0.0, double hi = 1.0) { return std::uniform_real_distribution<double>(lo, hi)(r); }
inline double normal(Rng& r) { return std::normal_distribution<double>(0.0, 1.0)(r); }

inline RealStack random_stack(Rng& r, std::size_t p, std::size_t h, std::size_t w, double lo = 0.0, double hi = 1.0) {
  RealStack s(p, h, w);
  for (double& v : s.data) v = uniform(r, lo, hi);
  return s;
}

// Positive PSFs, each band summing to 1.
inline RealStack random_psf(Rng& r, std::size_t bands, std::size_t size) {
  RealStack p = random_stack(r, bands, size, size, 0.05, 1.0);
  ref::normalize_planes(p);
  return p;
}

// C x B positive response with rows summing to 1, like sensor_response().
inline Eigen::MatrixXd random_srf(Rng& r, std::size_t channels, std::size_t bands) {
  Eigen::MatrixXd s(static_cast<Eigen::Index>(channels), static_cast<Eigen::Index>(bands));
  for (Eigen::Index c = 0; c < s.rows(); ++c) {
    for (Eigen::Index b = 0; b < s.cols(); ++b) s(c, b) = uniform(r, 0.05, 1.0);
    s.row(c) /= s.row(c).sum();
  }
  return s;
}

inline Eigen::MatrixXd random_spd(Rng& r, std::size_t n, double scale) {
  const auto k = static_cast<Eigen::Index>(n);
  Eigen::MatrixXd a(k, k);
  for (Eigen::Index i = 0; i < k; ++i)
    for (Eigen::Index j = 0; j < k; ++j) a(i, j) = normal(r);
  return scale * (a * a.transpose() / double(n) + 0.2 * Eigen::MatrixXd::Identity(k, k));
}

// A random SPD prior; the DC bin is larger (it holds the scene mean).
inline SpectralPrior random_prior(Rng& r, std::size_t bands, std::size_t bins, std::size_t rows, std::size_t cols) {
  SpectralPrior p;
  p.bands = bands;
  p.bins = bins;
  p.rows = rows;
  p.cols = cols;
  p.cov.resize(bins * bands * bands);
  for (std::size_t k = 0; k < bins; ++k) {
    const Eigen::MatrixXd m = random_spd(r, bands, k == 0 ? 2.0 : 0.05 / double(k));
    for (std::size_t i = 0; i < bands; ++i)
      for (std::size_t j = 0; j < bands; ++j)
        p.cov[(k * bands + i) * bands + j] = m(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(j));
  }
  return p;
}

// Naive DFT of every plane, independent of the FFTW code under test. sign -1: forward
// (unnormalised), +1: inverse (divided by rows*cols).
inline ComplexStack naive_dft(const ComplexStack& in, int sign) {
  ComplexStack out(in.planes, in.rows, in.cols);
  const double h = double(in.rows), w = double(in.cols);
  for (std::size_t b = 0; b < in.planes; ++b)
    for (std::size_t ky = 0; ky < in.rows; ++ky)
      for (std::size_t kx = 0; kx < in.cols; ++kx) {
        cdouble acc = 0;
        for (std::size_t y = 0; y < in.rows; ++y)
          for (std::size_t x = 0; x < in.cols; ++x) {
            const double ph = double(sign) * 2.0 * M_PI * (double(ky * y) / h + double(kx * x) / w);
            acc += in(b, y, x) * std::polar(1.0, ph);
          }
        out(b, ky, kx) = sign > 0 ? acc / (h * w) : acc;
      }
  return out;
}

// A scene whose DFT has E[X(f) X(f)^H] = H W P(bin(f)) exactly: white noise coloured by the
// Cholesky factor of each bin (real factor, same for f and -f, so the scene stays real).
inline RealStack sample_from_prior(Rng& r, const SpectralPrior& p) {
  ComplexStack z(p.bands, p.rows, p.cols);
  for (cdouble& v : z.data) v = normal(r);
  const ComplexStack zf = naive_dft(z, -1);
  ComplexStack xf(p.bands, p.rows, p.cols);
  std::vector<Eigen::MatrixXd> chol;
  for (std::size_t k = 0; k < p.bins; ++k) chol.push_back(p.bin(k).llt().matrixL());
  const std::size_t n = p.rows * p.cols;
  for (std::size_t ky = 0; ky < p.rows; ++ky)
    for (std::size_t kx = 0; kx < p.cols; ++kx) {
      const std::size_t f = ky * p.cols + kx;
      const Eigen::MatrixXd& l = chol[radial_bin(ky, kx, p.rows, p.cols, p.bins)];
      for (std::size_t i = 0; i < p.bands; ++i) {
        cdouble acc = 0;
        for (std::size_t j = 0; j <= i; ++j) acc += l(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(j)) * zf.data[j * n + f];
        xf.data[i * n + f] = acc;
      }
    }
  const ComplexStack x = naive_dft(xf, +1);
  RealStack out(p.bands, p.rows, p.cols);
  double max_imag = 0;
  for (std::size_t i = 0; i < x.size(); ++i) {
    max_imag = std::max(max_imag, std::abs(x.data[i].imag()));
    out.data[i] = x.data[i].real();
  }
  REQUIRE(max_imag < 1e-12);  // Hermitian symmetry kept
  return out;
}

}  // namespace qdo::test::wiener_suite
