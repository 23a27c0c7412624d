// Wiener (linear MMSE) decoder: exactness, Monte Carlo agreement of the expected error, the
// mismatch decode and the metrics; its adjoints (PSF -> OTF, the objectives' gradients with respect
// to the OTF and the PSF) are rows of the adjoint table, defined here (QDO_ADJOINT_ROWS wiener) and
// run by the suite `adjoint`. Every tolerance is stated next to its check.
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <complex>
#include <functional>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/physics/cpu_reference.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/decode/wiener.hpp"

#include "adjoint_table.hpp"
#include "wiener_common.hpp"

using namespace qdo;
using namespace qdo::wiener;
using namespace qdo::test::wiener_suite;

namespace {

double max_abs_diff(const std::vector<double>& a, const std::vector<double>& b) {
  REQUIRE(a.size() == b.size());
  double m = 0;
  for (std::size_t i = 0; i < a.size(); ++i) m = std::max(m, std::fabs(a[i] - b[i]));
  return m;
}

std::string loss_name(Loss l) {
  return l == Loss::Expected ? "Expected" : (l == Loss::Mse ? "Mse" : "Mae");
}

// SSIM straight from the definition (11 x 11 Gaussian window σ 1.5, valid positions, K1 0.01,
// K2 0.03, range 1), one band, for comparison with the separable implementation.
double naive_ssim_band(const RealStack& a, const RealStack& b, std::size_t band) {
  double g[11], gs = 0;
  for (int i = 0; i < 11; ++i) gs += (g[i] = std::exp(-(i - 5) * (i - 5) / (2 * 1.5 * 1.5)));
  double acc = 0;
  const std::size_t oh = a.rows - 10, ow = a.cols - 10;
  for (std::size_t oy = 0; oy < oh; ++oy)
    for (std::size_t ox = 0; ox < ow; ++ox) {
      double mx = 0, my = 0, sxx = 0, syy = 0, sxy = 0;
      for (std::size_t i = 0; i < 11; ++i)
        for (std::size_t j = 0; j < 11; ++j) {
          const double wgt = g[i] * g[j] / (gs * gs), x = a(band, oy + i, ox + j), y = b(band, oy + i, ox + j);
          mx += wgt * x;
          my += wgt * y;
          sxx += wgt * x * x;
          syy += wgt * y * y;
          sxy += wgt * x * y;
        }
      const double c1 = 1e-4, c2 = 9e-4;
      acc += (2 * mx * my + c1) * (2 * (sxy - mx * my) + c2) /
             ((mx * mx + my * my + c1) * (sxx - mx * mx + syy - my * my + c2));
    }
  return acc / double(oh * ow);
}

// The tiny problem used by the gradient checks: B = 4, C = 3, H = W = 6, 3 bins, 3 scenes.
struct Tiny {
  Rng rng{20240611};
  std::size_t bands = 4, rows = 6, cols = 6;
  Eigen::MatrixXd srf = random_srf(rng, 3, bands);
  SpectralPrior prior = random_prior(rng, bands, 3, rows, cols);
  std::vector<RealStack> scenes{random_stack(rng, bands, rows, cols), random_stack(rng, bands, rows, cols),
                                random_stack(rng, bands, rows, cols)};
  double sigma = 0.05;
};

}  // namespace

// The Wiener decoder's rows of the adjoint table (suite `adjoint`, tests/adjoint_table.hpp), all
// on the host in double: the PSF -> OTF chain (wrap/fold onto the grid, then the DFT) against its
// transpose, and the three objectives' gradients with respect to the OTF (every entry, re and im)
// and to the PSF (unfolded and folded onto the grid).
QDO_ADJOINT_ROWS(wiener, "Wiener decoder") {
  using namespace qdo::test;
  std::vector<Stage> rows;
  struct Case {
    std::size_t s, h, w;
  };
  // <A x, y> = <x, A^T y> within 1e-12 (|<A x, y>| + |x| |A^T y|): the same sums in another order.
  for (const Case c : {Case{5, 7, 6}, Case{9, 6, 4}, Case{4, 8, 8}}) {
    Stage st("Wiener PSF -> OTF, S = " + std::to_string(c.s) + " on " + std::to_string(c.h) + " x " + std::to_string(c.w),
             3 * c.s * c.s, 2 * 3 * c.h * c.w);
    st.forward = [c](const std::vector<double>& x) {
      RealStack psf(3, c.s, c.s);
      psf.data = x;
      return interleave(psf_to_otf(psf, c.h, c.w).data);
    };
    st.vjp = [c](const std::vector<double>&, const std::vector<double>& g) {
      ComplexStack y(3, c.h, c.w);
      y.data = deinterleave(g);
      return psf_gradient(y, c.s).data;
    };
    st.jvp = [f = st.forward](const std::vector<double>&, const std::vector<double>& d) { return f(d); };
    rows.push_back(st);
  }
  // The objectives: the tiny problem (B = 4, C = 3, 6 x 6, 3 bins, 3 scenes). Smooth losses:
  // step 1e-5 on an entry (truncation ~h^2, rounding ~1e-16/h), within 1e-7 of the gradient's rms
  // (observed ~1e-9 of its largest entry); along a direction, step 1e-6, within 1e-7 of the
  // derivative plus the difference's rounding, 10 eps |L| / step (a direction along which L
  // changes little, -2.4e-3 against L ~ 1, is at that floor: 8e-10). MAE is piecewise linear in
  // each error: steps 1e-6 / 1e-7 keep every error's sign (checked by the seed), within 1e-6 / 1e-5.
  const auto t = std::make_shared<Tiny>();
  const RealStack psf5 = random_psf(t->rng, t->bands, 5);
  const ComplexStack otf = psf_to_otf(psf5, t->rows, t->cols);
  const RealStack psf8 = random_psf(t->rng, t->bands, 8);  // 8 > 6: folded onto the grid
  const std::shared_ptr<const Tiny> tc = t;
  for (Loss loss : {Loss::Expected, Loss::Mse, Loss::Mae}) {
    const bool mae = loss == Loss::Mae;
    const auto tolerances = [mae](Stage& st) {
      st.fd_tol = 0;
      st.probe_step = mae ? 1e-6 : 1e-5;
      st.dir_step = mae ? 1e-7 : 1e-6;
      st.probe_rms = mae ? 1e-6 : 1e-7;
      st.dir_rel = mae ? 1e-5 : 1e-7;
      st.g0 = {1.0};
      for (std::size_t i = 0; i < st.inputs; ++i) st.probes.push_back(i);  // every entry
      st.dir_abs = 10 * 2.2e-16 * std::fabs(st.forward(st.x0)[0]) / st.dir_step;  // forward and x0 are set
    };
    {
      Stage st("Wiener objective " + loss_name(loss) + " -> OTF", 2 * otf.size(), 1);
      st.forward = [tc, loss, otf](const std::vector<double>& x) {
        ComplexStack o(otf.planes, otf.rows, otf.cols);
        o.data = deinterleave(x);
        return std::vector<double>{objective(loss, o, tc->srf, tc->prior, tc->sigma, tc->scenes).value};
      };
      st.vjp = [tc, loss, otf](const std::vector<double>& x, const std::vector<double>& g) {
        ComplexStack o(otf.planes, otf.rows, otf.cols);
        o.data = deinterleave(x);
        std::vector<double> r = interleave(objective(loss, o, tc->srf, tc->prior, tc->sigma, tc->scenes).grad_otf.data);
        for (double& v : r) v *= g[0];
        return r;
      };
      st.x0 = interleave(otf.data);
      tolerances(st);
      rows.push_back(st);
    }
    for (const RealStack* psf : {&psf5, &psf8}) {
      Stage st("Wiener objective " + loss_name(loss) + " -> PSF, S = " + std::to_string(psf->rows), psf->size(), 1);
      const std::size_t b = psf->planes, s = psf->rows;
      st.forward = [tc, loss, b, s](const std::vector<double>& x) {
        RealStack p(b, s, s);
        p.data = x;
        return std::vector<double>{objective_psf(loss, p, tc->srf, tc->prior, tc->sigma, tc->scenes).value};
      };
      st.vjp = [tc, loss, b, s](const std::vector<double>& x, const std::vector<double>& g) {
        RealStack p(b, s, s);
        p.data = x;
        const PsfObjective r = objective_psf(loss, p, tc->srf, tc->prior, tc->sigma, tc->scenes);
        REQUIRE(r.grad_psf.rows == s);
        std::vector<double> v = r.grad_psf.data;
        for (double& e : v) e *= g[0];
        return v;
      };
      st.x0 = psf->data;
      tolerances(st);
      rows.push_back(st);
    }
  }
  return rows;
}

TEST_SUITE("wiener") {
  TEST_CASE("radial bins: DC alone, f and -f share a bin, every bin index in range") {
    for (std::size_t rows : {6u, 7u, 8u})
      for (std::size_t cols : {5u, 8u}) {
        const std::size_t bins = 4;
        CHECK(radial_bin(0, 0, rows, cols, bins) == 0);
        for (std::size_t ky = 0; ky < rows; ++ky)
          for (std::size_t kx = 0; kx < cols; ++kx) {
            const std::size_t k = radial_bin(ky, kx, rows, cols, bins);
            CHECK(k < bins);
            if (ky || kx) CHECK(k >= 1);
            CHECK(k == radial_bin((rows - ky) % rows, (cols - kx) % cols, rows, cols, bins));
          }
      }
    // Corner of an even grid (ρ = 1/√2) is in the last bin; the lowest frequency in bin 1.
    CHECK(radial_bin(4, 4, 8, 8, 5) == 4);
    CHECK(radial_bin(0, 1, 64, 64, 5) == 1);
    CHECK_THROWS_AS(radial_bin(0, 0, 4, 4, 1), InputError);
    CHECK_THROWS_AS(radial_bin(4, 0, 4, 4, 3), InputError);
  }

  TEST_CASE("delta PSF, B = 3, S = identity: exact reconstruction as sigma -> 0") {
    Rng rng(1);
    const std::size_t b = 3, h = 8, w = 8;
    std::vector<RealStack> train;
    for (int i = 0; i < 6; ++i) train.push_back(random_stack(rng, b, h, w));
    const SpectralPrior prior = estimate_prior(train, 4);
    RealStack delta(b, 1, 1, 1.0);
    const ComplexStack otf = psf_to_otf(delta, h, w);
    for (const cdouble& v : otf.data) CHECK(std::abs(v - 1.0) < 1e-15);  // OTF ≡ 1
    const Eigen::MatrixXd srf = Eigen::MatrixXd::Identity(3, 3);
    const RealStack x = random_stack(rng, b, h, w);
    const RealStack y = simulate_measurement(x, otf, srf);
    CHECK(max_abs_diff(y.data, x.data) < 1e-14);  // identity camera
    // sigma = 0: K = P P^-1 = I up to rounding (tolerance 1e-10 absolute on values in [0, 1]).
    CHECK(max_abs_diff(decode(y, otf, srf, prior, 0.0).data, x.data) < 1e-10);
    // sigma = 1e-6: the bias is ~ sigma² / λ_min(P) (λ_min >~ 1e-3 here): tolerance 1e-7.
    const WienerDecoder dec(otf, srf, prior, 1e-6);
    CHECK(dec.bands() == 3);
    CHECK(dec.channels() == 3);
    CHECK(max_abs_diff(dec.decode(y).data, x.data) < 1e-7);
    // and it degrades gracefully: sigma = 0.1 is visibly biased.
    CHECK(max_abs_diff(decode(y, otf, srf, prior, 0.1).data, x.data) > 1e-4);
  }

  TEST_CASE("the camera model matches ref::convolve (circular) + ref::sensor_integrate, folded PSFs too") {
    Rng rng(2);
    for (std::size_t s : {1u, 5u, 9u}) {  // 9 > 6 and > 8: folded
      const std::size_t b = 4, h = 6, w = 8;
      const RealStack cube = random_stack(rng, b, h, w);
      const RealStack psf = random_psf(rng, b, s);
      const Eigen::MatrixXd srf = random_srf(rng, 3, b);
      const RealStack mine = simulate_measurement(cube, psf_to_otf(psf, h, w), srf);
      const RealStack theirs = ref::sensor_integrate(ref::convolve(cube, psf, ConvolutionMode::Circular), srf);
      INFO("S = " << s);
      CHECK(max_abs_diff(mine.data, theirs.data) < 1e-13);  // values ~0.5, double rounding
      // OTF against a naive DFT of the folded PSF (independent of FFTW).
      ComplexStack wrapped(b, h, w);
      for (std::size_t p = 0; p < b; ++p)
        for (std::size_t y = 0; y < s; ++y)
          for (std::size_t x = 0; x < s; ++x) wrapped(p, (y + h * s - s / 2) % h, (x + w * s - s / 2) % w) += psf(p, y, x);
      const ComplexStack otf_ref = naive_dft(wrapped, -1), otf = psf_to_otf(psf, h, w);
      double d = 0;
      for (std::size_t i = 0; i < otf.size(); ++i) d = std::max(d, std::abs(otf.data[i] - otf_ref.data[i]));
      CHECK(d < 1e-13);
    }
  }

  TEST_CASE("estimate_prior: second moment with the mean in the DC bin, recovers a known prior") {
    // Constant scene μ: X(0) = HW μ, every other X(f) = 0, so P(DC) = HW μ μᵀ and the other
    // bins are zero (ridge 1e-9 tr/B only). Tolerance 1e-8 relative (the ridge is 1e-9).
    const std::size_t b = 3, h = 6, w = 5, n = h * w;
    const double mu[3] = {0.2, 0.5, 0.9};
    RealStack flat(b, h, w);
    for (std::size_t p = 0; p < b; ++p)
      for (std::size_t i = 0; i < n; ++i) flat.plane(p)[i] = mu[p];
    const SpectralPrior pf = estimate_prior({flat}, 3);
    CHECK(pf.rows == h);
    CHECK(pf.cols == w);
    const Eigen::MatrixXd dc = pf.bin(0);
    for (std::size_t i = 0; i < b; ++i)
      for (std::size_t j = 0; j < b; ++j)
        CHECK(dc(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(j)) ==
              doctest::Approx(double(n) * mu[i] * mu[j]).epsilon(1e-8));
    CHECK(pf.bin(1).cwiseAbs().maxCoeff() < 1e-20);
    CHECK(pf.bin(2).cwiseAbs().maxCoeff() < 1e-20);

    // Scenes drawn from a known prior: each bin holds 16..30 frequencies x 300 scenes, so the
    // sample second moment is within a few % (tolerance: 10 % relative Frobenius).
    Rng rng(4);
    const SpectralPrior truth = random_prior(rng, 3, 3, 8, 8);
    std::vector<RealStack> scenes;
    for (int i = 0; i < 300; ++i) scenes.push_back(sample_from_prior(rng, truth));
    const SpectralPrior est = estimate_prior(scenes, 3);
    for (std::size_t k = 1; k < 3; ++k) {  // DC has only 1 frequency per scene: checked at 20 %
      const Eigen::MatrixXd e = est.bin(k), t = truth.bin(k);
      INFO("bin " << k);
      CHECK((e - e.transpose()).norm() == 0.0);  // symmetrised exactly
      CHECK((e - t).norm() / t.norm() < 0.10);
    }
    CHECK((est.bin(0) - truth.bin(0)).norm() / truth.bin(0).norm() < 0.20);
  }

  TEST_CASE("expected error equals the Monte Carlo MSE of noisy decodes (matched and mismatched)") {
    Rng rng(5);
    const std::size_t b = 4, h = 8, w = 8;
    const SpectralPrior prior = random_prior(rng, b, 3, h, w);
    const Eigen::MatrixXd srf = random_srf(rng, 3, b);
    const ComplexStack otf = psf_to_otf(random_psf(rng, b, 3), h, w);
    const ComplexStack otf_other = psf_to_otf(random_psf(rng, b, 5), h, w);
    const double sigma = 0.05;
    const double e_matched = objective(Loss::Expected, otf, srf, prior, sigma).value;
    const double e_mismatch = expected_error_mismatched(otf_other, otf, srf, prior, sigma);
    CHECK(expected_error_mismatched(otf, otf, srf, prior, sigma) == doctest::Approx(e_matched).epsilon(1e-12));
    CHECK(e_mismatch > e_matched);  // the Wiener filter is optimal for its own OTF

    const int trials = 400;
    double s1 = 0, s2 = 0, m1 = 0, m2 = 0;
    for (int t = 0; t < trials; ++t) {
      const RealStack x = sample_from_prior(rng, prior);
      for (int which = 0; which < 2; ++which) {
        RealStack y = simulate_measurement(x, which == 0 ? otf : otf_other, srf);
        for (double& v : y.data) v += sigma * normal(rng);
        const double e = metrics::mse(decode(y, otf, srf, prior, sigma), x);
        (which == 0 ? s1 : m1) += e;
        (which == 0 ? s2 : m2) += e * e;
      }
    }
    const auto check_mc = [&](double sum, double sum2, double expected, const char* what) {
      const double mean = sum / trials, sd = std::sqrt(std::max(0.0, sum2 / trials - mean * mean));
      INFO(what << ": Monte Carlo " << mean << " +- " << sd / std::sqrt(double(trials)) << ", expected " << expected);
      // 5 standard errors (false alarm ~ 6e-7), and never more than 10 % off.
      CHECK(std::fabs(mean - expected) <= 5.0 * sd / std::sqrt(double(trials)));
      CHECK(std::fabs(mean - expected) <= 0.10 * expected);
    };
    check_mc(s1, s2, e_matched, "matched");
    check_mc(m1, m2, e_mismatch, "mismatched");
  }

  TEST_CASE("expected error decreases monotonically as sigma decreases and is <= mean tr(P)") {
    Tiny t;
    const ComplexStack otf = psf_to_otf(random_psf(t.rng, t.bands, 3), t.rows, t.cols);
    double trace_mean = 0;  // 1/(B HW) Σ_f tr P(f): the error of the all-zero estimate
    for (std::size_t ky = 0; ky < t.rows; ++ky)
      for (std::size_t kx = 0; kx < t.cols; ++kx) trace_mean += t.prior.bin(radial_bin(ky, kx, t.rows, t.cols, 3)).trace();
    trace_mean /= double(t.bands * t.rows * t.cols);
    double previous = trace_mean;
    for (double sigma : {3.0, 1.0, 0.3, 0.1, 0.03, 0.01, 1e-3, 1e-4}) {
      const double e = objective(Loss::Expected, otf, t.srf, t.prior, sigma).value;
      INFO("sigma = " << sigma << ": " << e);
      CHECK(e > 0);
      CHECK(e < previous);
      previous = e;
    }
    // σ → ∞: nothing is learnt from the measurement; relative 1e-6 at σ = 1e5.
    CHECK(objective(Loss::Expected, otf, t.srf, t.prior, 1e5).value == doctest::Approx(trace_mean).epsilon(1e-6));
  }

  TEST_CASE("empirical objectives equal the spatial MSE / MAE of the decoded scenes (real PSF)") {
    Tiny t;
    const RealStack psf = random_psf(t.rng, t.bands, 5);
    const ComplexStack otf = psf_to_otf(psf, t.rows, t.cols);
    double mse = 0, mae = 0;
    for (const RealStack& x : t.scenes) {
      const RealStack xh = decode(simulate_measurement(x, otf, t.srf), otf, t.srf, t.prior, t.sigma);
      mse += metrics::mse(xh, x);
      for (std::size_t i = 0; i < x.size(); ++i) mae += std::fabs(xh.data[i] - x.data[i]);
    }
    mse /= double(t.scenes.size());
    mae /= double(t.scenes.size() * t.scenes[0].size());
    // relative 1e-10: the same numbers through different FFT paths
    CHECK(objective(Loss::Mse, otf, t.srf, t.prior, t.sigma, t.scenes).value == doctest::Approx(mse).epsilon(1e-10));
    CHECK(objective(Loss::Mae, otf, t.srf, t.prior, t.sigma, t.scenes).value == doctest::Approx(mae).epsilon(1e-10));
    CHECK(objective_psf(Loss::Mse, psf, t.srf, t.prior, t.sigma, t.scenes).value == doctest::Approx(mse).epsilon(1e-10));
  }

  TEST_CASE("mismatch decode: equal OTFs give the matched decode; different OTFs do worse") {
    Tiny t;
    const ComplexStack design = psf_to_otf(random_psf(t.rng, t.bands, 3), t.rows, t.cols);
    const ComplexStack actual = psf_to_otf(random_psf(t.rng, t.bands, 5), t.rows, t.cols);
    const RealStack& x = t.scenes[0];
    const RealStack matched = decode(simulate_measurement(x, design, t.srf), design, t.srf, t.prior, t.sigma);
    CHECK(max_abs_diff(decode_mismatched(x, design, design, t.srf, t.prior, t.sigma).data, matched.data) < 1e-14);
    const RealStack mism = decode_mismatched(x, actual, design, t.srf, t.prior, t.sigma);
    const RealStack by_hand = decode(simulate_measurement(x, actual, t.srf), design, t.srf, t.prior, t.sigma);
    CHECK(max_abs_diff(mism.data, by_hand.data) < 1e-14);
    CHECK(max_abs_diff(mism.data, matched.data) > 1e-3);
  }

  TEST_CASE("input validation names the argument") {
    Tiny t;
    const ComplexStack otf = psf_to_otf(random_psf(t.rng, t.bands, 3), t.rows, t.cols);
    CHECK_THROWS_AS(objective(Loss::Expected, otf, t.srf, t.prior, -1.0), InputError);
    CHECK_THROWS_AS(objective(Loss::Mse, otf, t.srf, t.prior, t.sigma), InputError);  // no scenes
    CHECK_THROWS_AS(objective(Loss::Mse, otf, t.srf, t.prior, t.sigma, {RealStack(t.bands, 5, 6)}), InputError);
    CHECK_THROWS_AS(objective(Loss::Expected, psf_to_otf(random_psf(t.rng, t.bands, 3), 8, 8), t.srf, t.prior, t.sigma),
                    InputError);
    CHECK_THROWS_AS(decode(RealStack(2, t.rows, t.cols), otf, t.srf, t.prior, t.sigma), InputError);
    CHECK_THROWS_AS(WienerDecoder(otf, Eigen::MatrixXd::Ones(3, 2), t.prior, t.sigma), InputError);
    SpectralPrior bad = t.prior;
    bad.cov.pop_back();
    CHECK_THROWS_AS(decode(RealStack(3, t.rows, t.cols), otf, t.srf, bad, t.sigma), InputError);
    CHECK_THROWS_AS(estimate_prior({}, 3), InputError);
    // bins bounded before the bins x B x B covariances are allocated.
    CHECK_THROWS_WITH_AS(estimate_prior(t.scenes, 1000000000), doctest::Contains("in [2, 4096]"), InputError);
    CHECK_THROWS_WITH_AS(estimate_prior({RealStack(301, 4, 4, 0.5)}, 4096), doctest::Contains("bins x bands^2 <= 2^27"), InputError);
    // σ = 0 with an OTF that vanishes at a frequency: singular, reported as qdo::Error.
    ComplexStack zero = otf;
    for (std::size_t b = 0; b < t.bands; ++b) zero(b, 1, 2) = 0;
    CHECK_THROWS_AS(objective(Loss::Expected, zero, t.srf, t.prior, 0.0), Error);
  }

  TEST_CASE("metrics against hand-computed values") {
    const std::size_t b = 3, h = 12, w = 13;
    RealStack truth(b, h, w), est(b, h, w);
    const double mu[3] = {0.25, 0.5, 0.8};
    for (std::size_t p = 0; p < b; ++p)
      for (std::size_t i = 0; i < h * w; ++i) {
        truth.plane(p)[i] = mu[p];
        est.plane(p)[i] = mu[p] + 0.01;
      }
    // Offset 0.01 everywhere: MSE 1e-4, PSNR 40 dB, RMSE 0.01 (relative 1e-12).
    CHECK(metrics::mse(est, truth) == doctest::Approx(1e-4).epsilon(1e-12));
    CHECK(metrics::psnr(est, truth) == doctest::Approx(40.0).epsilon(1e-12));
    CHECK(metrics::psnr_per_band(est, truth) == doctest::Approx(40.0).epsilon(1e-12));
    CHECK(metrics::rmse(est, truth) == doctest::Approx(0.01).epsilon(1e-12));
    // PSNR-H: peak = band max μ_b: mean_b 10 log10(μ_b² / 1e-4).
    double ph = 0, erg = 0;
    for (double m : mu) {
      ph += 10.0 * std::log10(m * m / 1e-4) / 3.0;
      erg += 1e-4 / (m * m) / 3.0;
    }
    CHECK(metrics::psnr_hyper(est, truth) == doctest::Approx(ph).epsilon(1e-12));
    CHECK(metrics::ergas(est, truth) == doctest::Approx(100.0 * std::sqrt(erg)).epsilon(1e-12));
    CHECK(std::isinf(metrics::psnr(truth, truth)));
    // SSIM of constant images a, b: (2ab + C1) / (a² + b² + C1) per band (relative 1e-12).
    double ss = 0;
    const double c1 = 1e-4;
    for (double m : mu) ss += (2 * m * (m + 0.01) + c1) / (m * m + (m + 0.01) * (m + 0.01) + c1) / 3.0;
    CHECK(metrics::ssim(est, truth) == doctest::Approx(ss).epsilon(1e-12));
    Rng rng(6);
    const RealStack noisy = random_stack(rng, b, h, w);
    CHECK(metrics::ssim(noisy, noisy) == doctest::Approx(1.0).epsilon(1e-12));
    const RealStack other = random_stack(rng, b, h, w);
    CHECK(metrics::ssim(other, noisy) < 0.5);
    RealStack blend = noisy;  // correlated pair: exercises the variance and covariance terms
    for (std::size_t i = 0; i < blend.size(); ++i) blend.data[i] = 0.7 * noisy.data[i] + 0.3 * other.data[i];
    double naive = 0;
    for (std::size_t p = 0; p < b; ++p) naive += naive_ssim_band(blend, noisy, p) / double(b);
    CHECK(metrics::ssim(blend, noisy) == doctest::Approx(naive).epsilon(1e-12));  // relative 1e-12
    CHECK(naive > 0.5);
    CHECK_THROWS_AS(metrics::ssim(RealStack(1, 10, 20), RealStack(1, 10, 20)), InputError);
    // SAM: orthogonal spectra π/2, parallel (scaled) 0, 45° π/4 (absolute 1e-12).
    RealStack e1(2, 1, 1), e2(2, 1, 1);
    e1(0, 0, 0) = 1;
    e2(1, 0, 0) = 3;
    CHECK(metrics::sam(e1, e2) == doctest::Approx(M_PI / 2).epsilon(1e-12));
    CHECK(metrics::sam(e1, e1) == doctest::Approx(0.0).epsilon(1e-12));
    RealStack diag(2, 1, 1, 0.7);
    CHECK(metrics::sam(diag, e1) == doctest::Approx(M_PI / 4).epsilon(1e-12));
    CHECK(metrics::sam(est, truth) < 0.05);
    CHECK_THROWS_AS(metrics::mse(RealStack(2, 3, 3), RealStack(3, 3, 3)), InputError);
  }

  TEST_CASE("SAM on zero spectra: pi/2 against a non-zero spectrum, 0 between two zeros; every pixel counts") {
    // Zero pixels used to be skipped, so an all-zero reconstruction scored a perfect 0.
    RealStack truth(3, 2, 2, 0.5), zero(3, 2, 2, 0.0);
    truth(1, 0, 1) = 0.9;
    CHECK(metrics::sam(zero, truth) == doctest::Approx(M_PI / 2).epsilon(1e-12));
    CHECK(metrics::sam(truth, zero) == doctest::Approx(M_PI / 2).epsilon(1e-12));
    CHECK(metrics::sam(zero, zero) == 0.0);
    CHECK(metrics::sam(truth, truth) == doctest::Approx(0.0).epsilon(1e-12));
    // One of four pixels zeroed in the estimate: (π/2) / 4 on top of three exact pixels.
    RealStack holed = truth;
    for (std::size_t b = 0; b < 3; ++b) holed(b, 1, 1) = 0;
    CHECK(metrics::sam(holed, truth) == doctest::Approx(M_PI / 8).epsilon(1e-12));
    // Zero in both at the same pixel: agreement, the mean still over all four pixels.
    RealStack both = truth;
    for (std::size_t b = 0; b < 3; ++b) both(b, 1, 1) = 0;
    CHECK(metrics::sam(both, holed) == doctest::Approx(0.0).epsilon(1e-12));
  }
}
