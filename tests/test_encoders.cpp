// Other encoders (Table 3): the quantized Fresnel lens focuses at its design wavelength; CASSI's
// forward operator and adjoint, and the DOE camera's, are rows of the adjoint table
// (tests/adjoint_table.hpp, built here, run by the `adjoint` suite); the prior-regularised CG decoder agrees with
// a dense direct solve, recovers an identity camera exactly, improves as the noise falls and equals
// the Wiener decoder on a shift-invariant camera; evaluate_encoder matches the `qdo eval` pipeline.
// Every tolerance is stated next to its check.
#include <cmath>
#include <memory>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "adjoint_table.hpp"
#include "common.hpp"
#include "encoders_common.hpp"
#include "qdo/physics/cpu_reference.hpp"
#include "qdo/decode/encoders.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/fftw2.hpp"
#include "qdo/data/materials.hpp"
#include "qdo/physics/simulator.hpp"

using namespace qdo;
using namespace qdo::test;
using namespace qdo::test::encoders_suite;

namespace {

// Encircled energy of a PSF plane within radius r_px of (cy, cx).
double encircled(const RealStack& psf, std::size_t b, double cy, double cx, double r_px) {
  double e = 0;
  for (std::size_t y = 0; y < psf.rows; ++y)
    for (std::size_t x = 0; x < psf.cols; ++x)
      if (std::hypot(double(y) - cy, double(x) - cx) <= r_px) e += psf(b, y, x);
  return e;
}

}  // namespace

// Dot-product tests <A x, y> = <x, A^T y> (rounding only: within 1e-13 |x| |y|) for CASSI (mono,
// RGB, shifts 0..3) and the DOE camera (within 1e-12 |x| |y|; 1e-11 for an OTF that is not the DFT
// of a real PSF, where the Re of the IDFT is part of A).
QDO_ADJOINT_ROWS(encoders, "encoders") {
  std::vector<Stage> rows;
  const auto row = [](const std::string& name, std::shared_ptr<const Encoder> e, const RealStack& x, const RealStack& y,
                      double tol) {
    Stage st(name, x.size(), y.size());
    st.forward = [e, x](const std::vector<double>& v) {
      RealStack in(x.planes, x.rows, x.cols);
      in.data = v;
      return e->measure(in).data;
    };
    st.vjp = [e, y](const std::vector<double>&, const std::vector<double>& g) {
      RealStack out(y.planes, y.rows, y.cols);
      out.data = g;
      return e->adjoint(out).data;
    };
    st.jvp = [f = st.forward](const std::vector<double>&, const std::vector<double>& d) { return f(d); };
    st.d0 = x.data;
    st.g0 = y.data;
    st.dot_tol = 0;
    st.dot_norms = tol;
    return st;
  };
  Rng rng(11);
  const std::size_t nb = 5, h = 7, w = 9;
  for (std::size_t shift : {0u, 1u, 3u}) {
    for (bool rgb : {false, true}) {
      const auto e = std::make_shared<const CassiEncoder>(random_binary_mask(h, w, 0.5, 100 + shift), nb, shift,
                                                          rgb ? random_srf(rng, 3, nb) : Eigen::MatrixXd());
      const RealStack x = normal_stack(rng, nb, h, w), y = normal_stack(rng, e->channels(), h, e->out_cols());
      rows.push_back(row("CASSI, shift " + std::to_string(shift) + (rgb ? ", RGB" : ", mono"), e, x, y, 1e-13));
    }
  }
  // DOE camera from a random real PSF (folded when S > H).
  RealStack psf(nb, 11, 11);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (double& v : psf.data) v = u(rng);
  const auto doe = std::make_shared<const DoeEncoder>(wiener::psf_to_otf(psf, h, w), random_srf(rng, 3, nb));
  const RealStack x = normal_stack(rng, nb, h, w), y = normal_stack(rng, 3, h, w);
  rows.push_back(row("DOE camera, PSF folded (RGB)", doe, x, y, 1e-12));
  // and for an OTF that is not the DFT of a real PSF (the Re of the IDFT is part of A).
  ComplexStack otf(nb, h, w);
  for (cdouble& v : otf.data) v = cdouble(normal(rng), normal(rng));
  const auto doe2 = std::make_shared<const DoeEncoder>(otf, random_srf(rng, 2, nb));
  const RealStack y2 = normal_stack(rng, 2, h, w);
  rows.push_back(row("DOE camera, complex OTF (2 channels)", doe2, x, y2, 1e-11));
  // The DOE camera recording only a random half of its pixels (MaskedEncoder: a tile's window of
  // a linear capture, or pixels the sensor lost).
  const auto masked = std::make_shared<const MaskedEncoder>(doe, random_binary_mask(h, w, 0.5, 7));
  rows.push_back(row("DOE camera, masked pixels (RGB)", masked, x, y, 1e-12));
  return rows;
}

TEST_SUITE("encoders") {
  TEST_CASE("fresnel_lens_heights: L = 0 is lens_design; L levels on the lens's own 2 pi relief") {
    const SystemConfig c = tiny_config(32, 3);
    const Map2D full = lens_design(c, 500);
    const Map2D f0 = fresnel_lens_heights(c, 500, 0);
    CHECK(f0.data == full.data);
    const double h2pi = 500e-9 / (material_by_name(c.material).index(500) - 1.0);
    for (int levels : {2, 4, 8}) {
      for (Placement pl : {Placement::Wrapped, Placement::Inclusive}) {
        CAPTURE(levels);
        CAPTURE(to_string(pl));
        const Map2D q = fresnel_lens_heights(c, 500, levels, pl);
        std::set<long> distinct;
        const double step = pl == Placement::Wrapped ? h2pi / levels : h2pi / (levels - 1);
        for (std::size_t i = 0; i < q.data.size(); ++i) {
          const double k = q.data[i] / step;
          CHECK(std::fabs(k - std::round(k)) < 1e-9);  // on the level grid (relative 1e-9)
          distinct.insert(std::lround(k));
          // The nearest level (half a step), or, Wrapped, the top half-step wrapped to level 0.
          const bool nearest = std::fabs(q.data[i] - full.data[i]) <= 0.5 * step * (1 + 1e-12);
          const bool wrapped = pl == Placement::Wrapped && q.data[i] == 0.0 && full.data[i] >= h2pi - 0.5 * step * (1 + 1e-12);
          CHECK((nearest || wrapped));
        }
        CHECK(distinct.size() <= std::size_t(levels));
        CHECK(distinct.size() >= 2);
      }
    }
    CHECK_THROWS_WITH_AS(fresnel_lens_heights(c, 500, 1), doctest::Contains("levels"), InputError);
    CHECK_THROWS_AS(fresnel_lens_heights(c, 500, -3), InputError);
  }

  TEST_CASE("the Fresnel lens focuses at its design wavelength (full precision, 8 and 4 levels)") {
    // n = 64 at 4 µm, z = 3.125 mm, bands 450..550 nm every 25 nm; padding 24 -> M = 112 >=
    // λz / pitch² = 107 at 550 nm, so every band's transfer function is adequately sampled.
    // Depth of focus ±2λ(z/D)² ≈ ±150 µm against a focal shift z·Δλ/λ ≈ 160 µm per 25 nm.
    SystemConfig c = tiny_config(64, 5);
    c.padding_px = 24;
    c.wavelength_step_nm = 25;
    c.validate();
    Simulator sim(runtime(), c, runtime().has_fp64() ? Precision::F64 : Precision::F32);
    struct Case {
      double design_nm;
      std::size_t band;
      int levels;
    };
    std::vector<double> design_ee;  // encircled energy at the design band, 500 nm lens, per level count
    for (const Case& k : {Case{500, 2, 0}, Case{500, 2, 8}, Case{500, 2, 4}, Case{450, 0, 0}, Case{450, 0, 4},
                          Case{550, 4, 0}, Case{550, 4, 4}}) {
      CAPTURE(k.design_nm);
      CAPTURE(k.levels);
      sim.set_heights(fresnel_lens_heights(c, k.design_nm, k.levels));
      sim.compute_psf();
      CHECK_FALSE(sim.sampling().any_inaccurate());
      const RealStack psf = sim.psf_sensor();
      const std::size_t s = psf.rows, ctr = s / 2;
      // Airy radius 1.22 λ z / D = 7.4 µm ≈ 0.93 sensor px; encircled energy within 2 px.
      std::vector<double> peak(c.bands), ee(c.bands);
      for (std::size_t b = 0; b < c.bands; ++b) {
        const double* p = psf.plane(b);
        std::size_t best = 0;
        for (std::size_t i = 0; i < psf.plane_size(); ++i)
          if (p[i] > p[best]) best = i;
        peak[b] = p[best];
        ee[b] = encircled(psf, b, double(ctr), double(ctr), 2.0);
        if (b == k.band) {
          CHECK(best / s == ctr);  // peak on the optical axis
          CHECK(best % s == ctr);
        }
      }
      INFO("peaks " << peak[0] << " " << peak[1] << " " << peak[2] << " " << peak[3] << " " << peak[4]);
      INFO("encircled energy (2 px) " << ee[0] << " " << ee[1] << " " << ee[2] << " " << ee[3] << " " << ee[4]);
      for (std::size_t b = 0; b < c.bands; ++b) {
        if (b == k.band) continue;
        CAPTURE(b);
        CHECK(peak[k.band] > peak[b]);
        CHECK(ee[k.band] > ee[b]);
      }
      if (k.design_nm == 500) design_ee.push_back(ee[k.band]);
    }
    // Fewer levels, less light in the focus (scalar efficiency sinc²(1/L): 95 % at 8, 81 % at 4).
    REQUIRE(design_ee.size() == 3);
    CHECK(design_ee[0] > design_ee[1]);
    CHECK(design_ee[1] > design_ee[2]);
  }

  TEST_CASE("random_binary_mask: binary, seeded, fill factor") {
    const Map2D a = random_binary_mask(64, 48, 0.5, 7), b = random_binary_mask(64, 48, 0.5, 7),
                d = random_binary_mask(64, 48, 0.5, 8);
    CHECK(a.data == b.data);
    CHECK(a.data != d.data);
    double open = 0;
    for (double v : a.data) {
      CHECK((v == 0.0 || v == 1.0));
      open += v;
    }
    // 3072 Bernoulli(0.5) draws: standard deviation of the fraction 0.009; allow 4 sigma.
    CHECK(std::fabs(open / double(a.data.size()) - 0.5) < 0.036);
    for (double v : random_binary_mask(8, 8, 1.0, 3).data) CHECK(v == 1.0);
    for (double v : random_binary_mask(8, 8, 0.0, 3).data) CHECK(v == 0.0);
    CHECK_THROWS_WITH_AS(random_binary_mask(8, 8, 1.5, 3), doctest::Contains("fill_factor"), InputError);
  }

  TEST_CASE("CASSI geometry: an impulse in band b lands s*b columns to the right, weighted by mask and response") {
    const std::size_t nb = 4, h = 5, w = 6, s = 2;
    Map2D mask(h, w, 1.0);
    mask(2, 3) = 0.5;
    const CassiEncoder mono(mask, nb, s);
    CHECK(mono.channels() == 1);
    CHECK(mono.out_cols() == w + (nb - 1) * s);
    for (std::size_t b = 0; b < nb; ++b) {
      RealStack x(nb, h, w);
      x(b, 2, 3) = 1.0;
      const RealStack y = mono.measure(x);
      REQUIRE(y.planes == 1);
      REQUIRE(y.cols == 12);
      for (std::size_t r = 0; r < h; ++r)
        for (std::size_t col = 0; col < y.cols; ++col)
          CHECK(y(0, r, col) == ((r == 2 && col == 3 + s * b) ? 0.5 / double(nb) : 0.0));  // exact
    }
    // A flat unit cube through an open mask (mono, weights 1/B) reads 1 where every band overlaps.
    const CassiEncoder open(Map2D(h, w, 1.0), nb, 1);
    const RealStack y1 = open.measure(RealStack(nb, h, w, 1.0));
    CHECK(y1(0, 0, nb - 1) == doctest::Approx(1.0).epsilon(1e-15));
    CHECK(y1(0, 0, 0) == doctest::Approx(0.25).epsilon(1e-15));
  }

  TEST_CASE("apply_prior_power: C against the dense definition; C^1/2 C^1/2 = C; C^-1 C = I") {
    Rng rng(12);
    const wiener::SpectralPrior p = random_prior(rng, 3, 3, 6, 5);
    const RealStack x = normal_stack(rng, 3, 6, 5);
    const Eigen::VectorXd dense = dense_prior_covariance(p) * as_vector(x);
    const RealStack cx = apply_prior_power(p, x, 1.0);
    CHECK((as_vector(cx) - dense).norm() <= 1e-12 * dense.norm());
    const RealStack hh = apply_prior_power(p, apply_prior_power(p, x, 0.5), 0.5);
    CHECK((as_vector(hh) - dense).norm() <= 1e-12 * dense.norm());
    const RealStack back = apply_prior_power(p, cx, -1.0);
    CHECK(std::sqrt(mse(back, x)) <= 1e-12 * norm(x));
  }

  TEST_CASE("CG converges below its tolerance; an iteration cap is reported as not converged") {
    Rng rng(13);
    const std::size_t nb = 4, h = 16, w = 16;
    const wiener::SpectralPrior p = random_prior(rng, nb, 4, h, w);
    const auto enc = std::make_shared<CassiEncoder>(random_binary_mask(h, w, 0.5, 1), nb, 1);
    RealStack y = enc->measure(sample_from_prior(rng, p));
    ref::add_noise(y, 0.02, 0.0, 5);
    CgOptions o;
    o.tolerance = 1e-10;
    const CassiDecoder dec(enc, p, 0.02, o);
    const CgResult r = dec.solve(y);
    MESSAGE("CG: " << r.iterations << " iterations, residual " << r.residual);
    CHECK(r.converged);
    CHECK(r.residual <= 1e-10);
    CHECK(r.iterations > 1);
    CHECK(r.iterations < o.max_iterations);
    CHECK(dec.decode(y).data == r.x.data);  // deterministic
    CgOptions capped = o;
    capped.max_iterations = 2;
    const CgResult rc = solve_map_cg(*enc, y, p, 0.02, capped);
    CHECK(rc.iterations == 2);
    CHECK_FALSE(rc.converged);
    CHECK(rc.residual > 1e-10);
  }

  TEST_CASE("identity camera (shift 0, open mask, B = 1): exact reconstruction as sigma -> 0") {
    Rng rng(14);
    const std::size_t h = 12, w = 10;
    std::vector<RealStack> train;
    for (int i = 0; i < 4; ++i) train.push_back(random_cube(1, h, w, 40u + unsigned(i)));
    const wiener::SpectralPrior p = wiener::estimate_prior(train, 4);
    const auto enc = std::make_shared<CassiEncoder>(Map2D(h, w, 1.0), 1, 0);
    const RealStack x = random_cube(1, h, w, 99);
    const RealStack y = enc->measure(x);
    CHECK(y.data == x.data);  // A = I
    CgOptions o;
    o.tolerance = 1e-13;
    // σ = 0: G = C, b = C^1/2 y, so x̂ = y (to the solver's tolerance; 1e-10 absolute on [0, 1]).
    const CgResult r0 = solve_map_cg(*enc, y, p, 0.0, o);
    CHECK(r0.converged);
    CHECK(std::sqrt(mse(r0.x, x)) < 1e-10);
    // σ = 1e-6: bias ~ σ² / λ_min(P) with λ_min ~ 1e-2 here: 1e-7.
    const CgDecoder dec(enc, p, 1e-6, o);
    double worst = 0;
    const RealStack xh = dec.decode(y);
    for (std::size_t i = 0; i < x.size(); ++i) worst = std::max(worst, std::fabs(xh.data[i] - x.data[i]));
    CHECK(worst < 1e-7);
  }

  TEST_CASE("CG solution equals the dense direct solve of the normal equations (B = 4, 16 x 16) to 1e-8") {
    Rng rng(15);
    const std::size_t nb = 4, h = 16, w = 16;
    const wiener::SpectralPrior p = random_prior(rng, nb, 4, h, w);
    const double sigma = 0.05;
    const CassiEncoder enc(random_binary_mask(h, w, 0.5, 2), nb, 1);
    RealStack y = enc.measure(sample_from_prior(rng, p));
    ref::add_noise(y, sigma, 0.0, 6);
    // (AᵀA/σ² + C⁻¹) x = Aᵀy/σ², with A and C built densely and independently of the solver.
    const Eigen::MatrixXd a = dense_encoder(enc);
    const Eigen::MatrixXd cinv = dense_prior_covariance(p).llt().solve(Eigen::MatrixXd::Identity(ix(nb * h * w), ix(nb * h * w)));
    const Eigen::MatrixXd k = a.transpose() * a / (sigma * sigma) + cinv;
    const Eigen::VectorXd direct = k.llt().solve(a.transpose() * as_vector(y) / (sigma * sigma));
    CgOptions o;
    o.tolerance = 1e-13;
    const CgResult r = solve_map_cg(enc, y, p, sigma, o);
    CHECK(r.converged);
    const double rel = (as_vector(r.x) - direct).norm() / direct.norm();
    MESSAGE("CG vs direct: relative " << rel << " after " << r.iterations << " iterations");
    CHECK(rel < 1e-8);
    CHECK((as_vector(r.x) - direct).cwiseAbs().maxCoeff() < 1e-8 * direct.cwiseAbs().maxCoeff());
  }

  TEST_CASE("CASSI decode error falls as sigma falls (scene drawn from the prior, same noise pattern)") {
    Rng rng(16);
    const std::size_t nb = 4, h = 16, w = 16;
    const wiener::SpectralPrior p = random_prior(rng, nb, 4, h, w);
    const auto enc = std::make_shared<CassiEncoder>(random_binary_mask(h, w, 0.5, 3), nb, 1);
    const RealStack x = sample_from_prior(rng, p);
    const RealStack clean = enc->measure(x);
    double prev = 1e300;
    for (double sigma : {0.3, 0.1, 0.03, 0.01}) {
      RealStack y = clean;
      ref::add_noise(y, sigma, 0.0, 9);
      const double e = mse(CassiDecoder(enc, p, sigma).decode(y), x);
      MESSAGE("sigma " << sigma << " mse " << e);
      CHECK(e < prev);
      prev = e;
    }
  }

  TEST_CASE("one objective: CG on the DOE camera gives the Wiener decoder's result (8 x 8, B = 4, RGB)") {
    Rng rng(17);
    const std::size_t nb = 4, h = 8, w = 8;
    std::vector<RealStack> train;
    for (unsigned i = 0; i < 5; ++i) train.push_back(random_cube(nb, h, w, 70u + i));
    const wiener::SpectralPrior p = wiener::estimate_prior(train, 3);  // real estimate: ridge 1e-9
    RealStack psf(nb, 5, 5);
    std::uniform_real_distribution<double> u(0.05, 1.0);
    for (double& v : psf.data) v = u(rng);
    ref::normalize_planes(psf);
    const ComplexStack otf = wiener::psf_to_otf(psf, h, w);
    const Eigen::MatrixXd srf = random_srf(rng, 3, nb);
    const auto enc = std::make_shared<DoeEncoder>(otf, srf);
    const double sigma = 0.02;
    RealStack y = enc->measure(random_cube(nb, h, w, 80));
    ref::add_noise(y, sigma, 0.0, 10);
    CgOptions o;
    o.tolerance = 1e-13;
    o.max_iterations = 20000;
    const CgDecoder cg(enc, p, sigma, o);
    const CgResult r = cg.solve(y);
    const RealStack wz = WienerDecoder(otf, srf, p, sigma).decode(y);
    const double rel = std::sqrt(mse(r.x, wz) / mse(wz, RealStack(nb, h, w)));
    MESSAGE("CG vs Wiener: relative " << rel << " after " << r.iterations << " iterations, residual " << r.residual);
    CHECK(rel < 1e-6);
  }

  TEST_CASE("evaluate_encoder reproduces the qdo eval pipeline (noise draws, clipping, metric means)") {
    Rng rng(18);
    const std::size_t nb = 3, h = 16, w = 16;
    std::vector<RealStack> cubes;
    for (unsigned i = 0; i < 2; ++i) cubes.push_back(random_cube(nb, h, w, 90u + i));
    const wiener::SpectralPrior p = wiener::estimate_prior(cubes, 4);
    RealStack psf(nb, 3, 3, 0.02);
    for (std::size_t b = 0; b < nb; ++b) psf(b, 1, 1) = 1.0;
    ref::normalize_planes(psf);
    const ComplexStack otf = wiener::psf_to_otf(psf, h, w);
    const Eigen::MatrixXd srf = random_srf(rng, 3, nb);
    const DoeEncoder enc(otf, srf);
    const WienerDecoder dec(otf, srf, p, 0.01);
    const EncoderEval e = evaluate_encoder(enc, dec, cubes, 0.01, 123);
    EncoderEval m;
    for (std::size_t k = 0; k < cubes.size(); ++k) {
      RealStack y = wiener::simulate_measurement(cubes[k], otf, srf);
      ref::add_noise(y, 0.01, 0, 123, k);
      RealStack xh = dec.decode(y);
      for (double& v : xh.data) v = std::clamp(v, 0.0, 1.0);
      m.psnr_db += metrics::psnr(xh, cubes[k]) / 2;
      m.ssim += metrics::ssim(xh, cubes[k]) / 2;
      m.rmse += metrics::rmse(xh, cubes[k]) / 2;
      m.ergas += metrics::ergas(xh, cubes[k]) / 2;
      m.sam_rad += metrics::sam(xh, cubes[k]) / 2;
    }
    CHECK(e.cubes == 2);
    CHECK(e.psnr_db == doctest::Approx(m.psnr_db).epsilon(1e-12));
    CHECK(e.ssim == doctest::Approx(m.ssim).epsilon(1e-12));
    CHECK(e.rmse == doctest::Approx(m.rmse).epsilon(1e-12));
    CHECK(e.ergas == doctest::Approx(m.ergas).epsilon(1e-12));
    CHECK(e.sam_rad == doctest::Approx(m.sam_rad).epsilon(1e-12));
    // CASSI through the same helper: a finite, plausible result, and less noise does better.
    const auto cassi = std::make_shared<CassiEncoder>(random_binary_mask(h, w, 0.5, 4), nb, 1);
    const EncoderEval c1 = evaluate_encoder(*cassi, CassiDecoder(cassi, p, 0.1), cubes, 0.1, 5);
    const EncoderEval c2 = evaluate_encoder(*cassi, CassiDecoder(cassi, p, 0.001), cubes, 0.001, 5);
    MESSAGE("CASSI psnr " << c1.psnr_db << " (sigma 0.1), " << c2.psnr_db << " (sigma 0.001)");
    // A decoder that recovers anything beats 10 dB on scenes in [0, 1]; none reaches 60 dB here.
    CHECK(c1.psnr_db > 10);
    CHECK(c2.psnr_db < 60);
    CHECK(c2.psnr_db > c1.psnr_db);
    CHECK(c2.rmse < c1.rmse);
  }

  TEST_CASE("input validation names the argument") {
    Rng rng(19);
    CHECK_THROWS_WITH_AS(CassiEncoder(Map2D(4, 4, 1.0), 0, 1), doctest::Contains("bands"), InputError);
    CHECK_THROWS_WITH_AS(CassiEncoder(Map2D(4, 4, 1.0), 3, 1, Eigen::MatrixXd::Ones(1, 2)), doctest::Contains("response"),
                         InputError);
    const auto enc = std::make_shared<CassiEncoder>(Map2D(4, 4, 1.0), 2, 1);
    CHECK_THROWS_WITH_AS(enc->measure(RealStack(2, 4, 5)), doctest::Contains("'x'"), InputError);
    CHECK_THROWS_WITH_AS(enc->adjoint(RealStack(1, 4, 4)), doctest::Contains("'y'"), InputError);
    const wiener::SpectralPrior p = random_prior(rng, 2, 3, 4, 4);
    CHECK_THROWS_WITH_AS(CgDecoder(enc, p, -1.0), doctest::Contains("noise_sigma"), InputError);
    CHECK_THROWS_WITH_AS(CgDecoder(enc, random_prior(rng, 3, 3, 4, 4), 0.1), doctest::Contains("prior"), InputError);
    CHECK_THROWS_WITH_AS(CgDecoder(nullptr, p, 0.1), doctest::Contains("encoder"), InputError);
    CHECK_THROWS_WITH_AS(evaluate_encoder(*enc, CgDecoder(enc, p, 0.1), {}, 0.1, 1), doctest::Contains("cubes"), InputError);
    CHECK_THROWS_WITH_AS(DoeEncoder(ComplexStack(2, 4, 4), Eigen::MatrixXd::Ones(3, 3)), doctest::Contains("srf"), InputError);
  }
}
