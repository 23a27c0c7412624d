// The Wiener decoder's sigma chosen from the measurements (wiener::gcv_noise_sigma and
// wiener::ml_noise_sigma, what `qdo reconstruct --noise-sigma gcv|ml` runs): on measurements drawn
// from the decoder's own model both find the noise's sigma; power the model does not predict
// raises the likelihood's; bad input is refused.
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "qdo/decode/wiener.hpp"
#include "qdo/runtime/error.hpp"

#include "wiener_common.hpp"

using namespace qdo;
using namespace qdo::wiener;
using namespace qdo::test::wiener_suite;

TEST_SUITE("wiener") {
  TEST_CASE("cross-validation and the marginal likelihood find the noise sigma of measurements drawn from the model") {
    // Scenes drawn from the prior, measured through the OTF with white noise of a known sigma: the
    // model holds, so GCV's minimiser and the likelihood's maximiser estimate that sigma (consistent
    // as the frequencies grow; 12 images of 16 x 16 x 3 here), and the decode at either is nearly as
    // good as at the true sigma.
    Rng rng(9);
    const std::size_t b = 4, h = 16, w = 16;
    const SpectralPrior prior = random_prior(rng, b, 3, h, w);
    const Eigen::MatrixXd srf = random_srf(rng, 3, b);
    const ComplexStack otf = psf_to_otf(random_psf(rng, b, 5), h, w);
    std::vector<RealStack> scenes, clean;
    double rms = 0;
    for (int k = 0; k < 12; ++k) {
      scenes.push_back(sample_from_prior(rng, prior));
      clean.push_back(simulate_measurement(scenes.back(), otf, srf));
      for (double v : clean.back().data) rms += v * v / double(clean.back().data.size() * 12);
    }
    rms = std::sqrt(rms);
    for (const double rel : {0.05, 0.3}) {
      const double sigma = rel * rms;
      std::vector<RealStack> ys = clean;
      for (RealStack& y : ys)
        for (double& v : y.data) v += sigma * normal(rng);
      for (const bool ml : {false, true}) {
        const SigmaSearch g = ml ? ml_noise_sigma(ys, otf, srf, prior, 1e-4 * rms, 10 * rms, 61)
                               : gcv_noise_sigma(ys, otf, srf, prior, 1e-4 * rms, 10 * rms, 61);
        INFO((ml ? "marginal likelihood" : "GCV") << ": true sigma " << sigma << ", found " << g.sigma);
        CHECK_FALSE(g.at_edge);
        CHECK(g.sigma > 0.75 * sigma);
        CHECK(g.sigma < 1.33 * sigma);
        REQUIRE(g.scores.size() == 61);
        CHECK(*std::min_element(g.scores.begin(), g.scores.end()) == doctest::Approx(ml ? 0.0 : 1.0));
        double e_found = 0, e_true = 0;
        for (std::size_t k = 0; k < ys.size(); ++k) {
          e_found += metrics::mse(decode(ys[k], otf, srf, prior, g.sigma), scenes[k]);
          e_true += metrics::mse(decode(ys[k], otf, srf, prior, sigma), scenes[k]);
        }
        CHECK(e_found < 1.05 * e_true);
      }
    }
    // Power the model does not predict raises the likelihood's sigma: the same images with a
    // pattern of one pixel period added (a mosaic-like error, 0.3 of the clean RMS) ask for more.
    std::vector<RealStack> odd = clean;
    for (RealStack& y : odd)
      for (std::size_t c = 0; c < y.planes; ++c)
        for (std::size_t r = 0; r < y.rows; ++r)
          for (std::size_t x = 0; x < y.cols; ++x) y(c, r, x) += 0.3 * rms * (((r + x + c) % 2) ? 1.0 : -1.0) + 0.05 * rms * normal(rng);
    std::vector<RealStack> plain = clean;
    for (RealStack& y : plain)
      for (double& v : y.data) v += 0.05 * rms * normal(rng);
    CHECK(ml_noise_sigma(odd, otf, srf, prior, 1e-4 * rms, 10 * rms).sigma > 2 * ml_noise_sigma(plain, otf, srf, prior, 1e-4 * rms, 10 * rms).sigma);
    // Refused, naming what: no image, an image off the OTF's grid, a range that is none.
    CHECK_THROWS_AS(gcv_noise_sigma({}, otf, srf, prior), InputError);
    CHECK_THROWS_AS(gcv_noise_sigma({RealStack(3, h, w + 1, 0.0)}, otf, srf, prior), InputError);
    CHECK_THROWS_AS(gcv_noise_sigma(clean, otf, srf, prior, 0.1, 0.01), InputError);
    CHECK_THROWS_AS(gcv_noise_sigma(clean, otf, srf, prior, 0.0, 1.0), InputError);
  }
}
