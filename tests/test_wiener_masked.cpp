// The Wiener decoder for a camera that records part of its grid (MaskedWienerDecoder,
// wiener_masked.hpp), and the linear tile boundary built on it (tiled.hpp):
//  - every pixel recorded: the Wiener decoder itself (closed form per frequency);
//  - a window: the dense MAP solve, built from the definitions of the camera, the mask and the
//    prior covariance (encoders_common.hpp), and the primal CG on a MaskedEncoder (another route);
//  - at small sigma (down to 1e-5) it still reaches the dense solution;
//  - at the default tolerance the estimate is within 1e-3 of the converged one;
//  - refusals name the argument.
// The MaskedEncoder's dot-product test is a row of the adjoint table (test_encoders.cpp).
#include <cmath>
#include <memory>
#include <random>
#include <vector>

#include "common.hpp"
#include "encoders_common.hpp"
#include "qdo/decode/encoders.hpp"
#include "qdo/decode/tiled.hpp"
#include "qdo/decode/wiener.hpp"
#include "qdo/decode/wiener_masked.hpp"
#include "qdo/physics/cpu_reference.hpp"
#include "qdo/runtime/error.hpp"

using namespace qdo;
using namespace qdo::test;
using namespace qdo::test::encoders_suite;

namespace {

RealStack random_psf(Rng& rng, std::size_t nb, std::size_t size) {
  RealStack psf(nb, size, size);
  std::uniform_real_distribution<double> u(0.05, 1.0);
  for (double& v : psf.data) v = u(rng);
  ref::normalize_planes(psf);
  return psf;
}

// A random camera (a PSF of psf_px, RGB) and prior (bins) for nb bands on an h x w grid, drawn in
// that order.
struct Problem {
  wiener::SpectralPrior prior;
  ComplexStack otf;
  Eigen::MatrixXd srf;
};
Problem random_problem(Rng& rng, std::size_t nb, std::size_t bins, std::size_t h, std::size_t w, std::size_t psf_px) {
  Problem q;
  q.prior = random_prior(rng, nb, bins, h, w);
  q.otf = wiener::psf_to_otf(random_psf(rng, nb, psf_px), h, w);
  q.srf = random_srf(rng, 3, nb);
  return q;
}

// A rows x cols mask recording the window [r0, r0 + h) x [c0, c0 + w).
Map2D window_mask(std::size_t rows, std::size_t cols, std::size_t r0, std::size_t c0, std::size_t h, std::size_t w) {
  Map2D m(rows, cols, 0.0);
  for (std::size_t r = r0; r < r0 + h; ++r)
    for (std::size_t c = c0; c < c0 + w; ++c) m(r, c) = 1.0;
  return m;
}

double rel_diff(const RealStack& a, const RealStack& b) { return std::sqrt(mse(a, b) / mse(b, RealStack(b.planes, b.rows, b.cols))); }

}  // namespace

TEST_SUITE("wiener-masked") {
  TEST_CASE("every pixel recorded: the Wiener decoder's estimate (15 x 11, odd sizes, B = 5, RGB) to 1e-8") {
    Rng rng(31);
    const std::size_t nb = 5, h = 15, w = 11;
    const auto [p, otf, srf] = random_problem(rng, nb, 5, h, w, 7);
    const double sigma = 0.03;
    RealStack y = DoeEncoder(otf, srf).measure(sample_from_prior(rng, p));
    ref::add_noise(y, sigma, 0.0, 3);
    const MaskedWienerDecoder dec(otf, srf, p, Map2D(h, w, 1.0), sigma, CgOptions{1e-13, 100});
    const CgResult r = dec.solve(y);
    const RealStack wz = wiener::decode(y, otf, srf, p, sigma);
    const double rel = rel_diff(r.x, wz);
    // With M = I the preconditioner is the exact inverse: one iteration.
    MESSAGE("masked (all recorded) vs Wiener: relative " << rel << " after " << r.iterations << " iterations");
    CHECK(r.iterations <= 2);
    CHECK(rel < 1e-8);
  }

  TEST_CASE("a recorded window: the dense MAP solve and the primal CG agree (10 x 8 grid, B = 3)") {
    Rng rng(32);
    const std::size_t nb = 3, h = 10, w = 8;
    const auto [p, otf, srf] = random_problem(rng, nb, 4, h, w, 5);
    const Map2D mask = window_mask(h, w, 3, 2, 5, 4);
    const double sigma = 0.02;
    const auto masked = std::make_shared<const MaskedEncoder>(std::make_shared<const DoeEncoder>(otf, srf), mask);
    RealStack y = masked->measure(sample_from_prior(rng, p));
    ref::add_noise(y, sigma, 0.0, 4);
    // (AᵀA/σ² + C⁻¹) x = Aᵀy/σ² with A = M A_c and C dense from their definitions.
    const Eigen::MatrixXd a = dense_encoder(*masked);
    const std::size_t nx = nb * h * w;
    const Eigen::MatrixXd cinv = dense_prior_covariance(p).llt().solve(Eigen::MatrixXd::Identity(ix(nx), ix(nx)));
    const Eigen::VectorXd direct =
        (a.transpose() * a / (sigma * sigma) + cinv).llt().solve(a.transpose() * as_vector(y) / (sigma * sigma));
    const CgResult r = MaskedWienerDecoder(otf, srf, p, mask, sigma, CgOptions{1e-13, 1000}).solve(y);
    CHECK(r.converged);
    const double rel = (as_vector(r.x) - direct).norm() / direct.norm();
    const CgResult primal = solve_map_cg(*masked, y, p, sigma, CgOptions{1e-13, 20000});
    const double rel_primal = rel_diff(r.x, primal.x);
    MESSAGE("masked Wiener vs dense: " << rel << " (" << r.iterations << " iterations); vs primal CG: " << rel_primal << " ("
                                       << primal.iterations << " iterations)");
    CHECK(rel < 1e-8);
    CHECK(rel_primal < 1e-7);
    // The unrecorded pixels' values do not matter.
    RealStack y2 = y;
    for (std::size_t c = 0; c < 3; ++c) y2(c, 0, 0) = 5.0;
    CHECK(rel_diff(MaskedWienerDecoder(otf, srf, p, mask, sigma, CgOptions{1e-13, 1000}).decode(y2), r.x) < 1e-10);
  }

  TEST_CASE("small sigma: still the dense MAP solve, and the iterations it takes are reported (10 x 8 grid, B = 3)") {
    // Stability: as sigma falls the system's condition number grows as 1/sigma^2 (eigenvalues in
    // [sigma^2, sigma^2 + |A|^2 lambda_max(C)]); the preconditioned solve must still reach the
    // dense solution, or say it did not (converged = false).
    Rng rng(35);
    const std::size_t nb = 3, h = 10, w = 8;
    const auto [p, otf, srf] = random_problem(rng, nb, 4, h, w, 5);
    const Map2D mask = window_mask(h, w, 2, 1, 6, 5);
    const auto masked = std::make_shared<const MaskedEncoder>(std::make_shared<const DoeEncoder>(otf, srf), mask);
    const RealStack clean = masked->measure(sample_from_prior(rng, p));
    const Eigen::MatrixXd a = dense_encoder(*masked);
    const Eigen::MatrixXd c = dense_prior_covariance(p);
    for (double sigma : {1e-3, 1e-4, 1e-5}) {
      CAPTURE(sigma);
      RealStack y = clean;
      ref::add_noise(y, sigma, 0.0, 6);
      // The Woodbury form x = C Aᵀ (A C Aᵀ + σ² I)⁻¹ y, dense: better conditioned than the normal
      // equations at small sigma.
      const Eigen::MatrixXd k = a * c * a.transpose() + sigma * sigma * Eigen::MatrixXd::Identity(a.rows(), a.rows());
      const Eigen::VectorXd direct = c * a.transpose() * k.ldlt().solve(as_vector(y));
      const CgResult r = MaskedWienerDecoder(otf, srf, p, mask, sigma, CgOptions{1e-12, 5000}).solve(y);
      const double rel = (as_vector(r.x) - direct).norm() / direct.norm();
      MESSAGE("sigma " << sigma << ": " << r.iterations << " iterations, residual " << r.residual << ", vs dense " << rel);
      CHECK(r.converged);
      CHECK(rel < 1e-8);  // measured 3e-12 .. 6e-12 in 63 .. 81 iterations
    }
  }

  TEST_CASE("the default tolerance: within 1e-3 of the converged estimate on a linear tile (B = 8, tile 24)") {
    Rng rng(33);
    const std::size_t nb = 8, t = 24;
    const wiener::SpectralPrior p = random_prior(rng, nb, 6, t, t);
    const RealStack psf = random_psf(rng, nb, t);  // a PSF filling its tile: the widest the boundary allows
    const Eigen::MatrixXd srf = random_srf(rng, 3, nb);
    const wiener::SpectralPrior p2 = regrid_prior(p, 2 * t, 2 * t);
    const ComplexStack otf = wiener::psf_to_otf(psf, 2 * t, 2 * t);
    const Map2D mask = window_mask(2 * t, 2 * t, t / 2, t / 2, t, t);
    for (double sigma : {0.03, 0.003}) {
      CAPTURE(sigma);
      RealStack y = MaskedEncoder(std::make_shared<const DoeEncoder>(otf, srf), mask).measure(sample_from_prior(rng, p2));
      ref::add_noise(y, sigma, 0.0, 5);
      const CgResult fine = MaskedWienerDecoder(otf, srf, p2, mask, sigma, CgOptions{1e-12, 5000}).solve(y);
      const CgResult def = MaskedWienerDecoder(otf, srf, p2, mask, sigma).solve(y);
      const double rel = rel_diff(def.x, fine.x);
      MESSAGE("default tolerance: " << def.iterations << " iterations, " << rel << " from the converged (" << fine.iterations
                                    << " iterations)");
      CHECK(def.converged);
      CHECK(rel < 1e-3);
    }
  }

  TEST_CASE("input validation names the argument") {
    Rng rng(34);
    const std::size_t nb = 2, h = 6, w = 6;
    const auto [p, otf, srf] = random_problem(rng, nb, 3, h, w, 3);
    CHECK_THROWS_WITH_AS(MaskedWienerDecoder(otf, srf, p, Map2D(h, w, 1.0), 0.0), doctest::Contains("noise_sigma"), InputError);
    CHECK_THROWS_WITH_AS(MaskedWienerDecoder(otf, srf, p, Map2D(h, w, 0.5), 0.1), doctest::Contains("mask[0]"), InputError);
    CHECK_THROWS_WITH_AS(MaskedWienerDecoder(otf, srf, p, Map2D(h, w + 1, 1.0), 0.1), doctest::Contains("mask"), InputError);
    CHECK_THROWS_WITH_AS(MaskedWienerDecoder(otf, random_srf(rng, 3, nb + 1), p, Map2D(h, w, 1.0), 0.1), doctest::Contains("srf"),
                         InputError);
    CHECK_THROWS_WITH_AS(MaskedWienerDecoder(otf, srf, regrid_prior(p, h, w + 2), Map2D(h, w, 1.0), 0.1), doctest::Contains("prior"),
                         InputError);
    CHECK_THROWS_WITH_AS(MaskedWienerDecoder(otf, srf, p, Map2D(h, w, 1.0), 0.1, CgOptions{0.0, 10}), doctest::Contains("tolerance"),
                         InputError);
    const MaskedWienerDecoder dec(otf, srf, p, Map2D(h, w, 1.0), 0.1);
    CHECK_THROWS_WITH_AS(dec.decode(RealStack(3, h, w + 1)), doctest::Contains("y"), InputError);
    CHECK_THROWS_WITH_AS(MaskedEncoder(std::make_shared<const DoeEncoder>(otf, srf), Map2D(h, w, 2.0)), doctest::Contains("mask[0]"),
                         InputError);
    CHECK_THROWS_WITH_AS(linear_tile_encoder(random_psf(rng, nb, 9), srf, 8), doctest::Contains("PSF"), InputError);
  }
}
