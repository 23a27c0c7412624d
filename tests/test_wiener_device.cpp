// The Wiener expected-error objective on the device (include/qdo/decode/wiener_device.hpp,
// kernels/wiener.cl) against its CPU reference wiener::objective_psf(Loss::Expected, ...) in
// double: value and PSF gradient on seeded random problems (odd and even grids and band counts,
// PSFs smaller and larger than the grid, 1 to 4 channels), in float64 and float32 (with and
// without float64 accumulation), the adjoint ladder's finite-difference rungs on the device in
// float64, the refusals, and a singular filter.
#include <algorithm>
#include <cmath>
#include <random>
#include <string>

#include "adjoint_ladder.hpp"
#include "common.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/decode/wiener.hpp"
#include "qdo/decode/wiener_device.hpp"

using namespace qdo;
using namespace qdo::test;

namespace {

struct Problem {
  std::size_t bands, channels, rows, cols, psf_size, bins;
  double sigma;
  Eigen::MatrixXd srf;
  wiener::SpectralPrior prior;
  RealStack psf;
};

// Positive PSFs with each band summing to 1 and a peak at the axis (like a real PSF: a large DC
// OTF, small high frequencies); the prior is estimated from positive random scenes with a
// smooth component, so its DC bin holds H·W·μ² (the conditioning qdo's real priors have).
// one_spectrum: every scene has the same spectrum, so the prior's DC bin is nearly rank one
// (H·W·μμᵀ plus the ridge) and M = A P A^H + σ² I is within σ² of singular there.
Problem make_problem(std::size_t bands, std::size_t channels, std::size_t rows, std::size_t cols, std::size_t s,
                     double sigma, unsigned seed, bool one_spectrum = false) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  Problem p{bands, channels, rows, cols, s, 8, sigma, {}, {}, {}};
  p.srf.resize(static_cast<Eigen::Index>(channels), static_cast<Eigen::Index>(bands));
  for (Eigen::Index c = 0; c < p.srf.rows(); ++c) {
    for (Eigen::Index b = 0; b < p.srf.cols(); ++b) p.srf(c, b) = 0.05 + u(rng);
    p.srf.row(c) /= p.srf.row(c).sum();
  }
  std::vector<RealStack> scenes;
  for (int k = 0; k < 6; ++k) {
    RealStack sc(bands, rows, cols);
    const double fy = 1 + 2 * u(rng), fx = 1 + 2 * u(rng), fb = 0.2 + u(rng), phase = 6.283 * u(rng);
    for (std::size_t b = 0; b < bands; ++b) {
      const double spectrum = one_spectrum ? 1.0 : 0.6 + 0.4 * std::sin(fb * double(b) + phase);
      for (std::size_t y = 0; y < rows; ++y)
        for (std::size_t x = 0; x < cols; ++x)
          sc(b, y, x) = spectrum * (0.4 + 0.2 * std::sin(fy * double(y) / double(rows) * 6.283 + double(b) * 0.1) *
                                              std::cos(fx * double(x) / double(cols) * 6.283)) +
                        (one_spectrum ? 0.0 : 0.15 * u(rng));
    }
    scenes.push_back(std::move(sc));
  }
  p.prior = wiener::estimate_prior(scenes, p.bins);
  p.psf = RealStack(bands, s, s);
  const double c = double(s / 2);
  for (std::size_t b = 0; b < bands; ++b) {
    double sum = 0;
    const double w = 0.6 + 0.15 * double(b % 5);
    for (std::size_t y = 0; y < s; ++y)
      for (std::size_t x = 0; x < s; ++x) {
        const double r2 = (double(y) - c) * (double(y) - c) + (double(x) - c) * (double(x) - c);
        const double v = std::exp(-r2 / (2 * w * w)) + 0.02 * u(rng);
        p.psf(b, y, x) = v;
        sum += v;
      }
    for (std::size_t i = 0; i < s * s; ++i) p.psf.plane(b)[i] /= sum;
  }
  return p;
}

struct Compared {
  double value_rel, grad_rel, tol;
};

// The largest condition number over frequencies of M = A P A^H + σ² I: the solve Kh = M⁻¹ A P
// (and so the gradient, which is first order in Kh where the value is not) loses up to
// log10(κ_M) digits.
double solve_condition(const Problem& pb) {
  const ComplexStack otf = wiener::psf_to_otf(pb.psf, pb.rows, pb.cols);
  double worst = 1;
  const auto nb = static_cast<Eigen::Index>(pb.bands), nc = static_cast<Eigen::Index>(pb.channels);
  for (std::size_t f = 0; f < pb.rows * pb.cols; ++f) {
    const Eigen::MatrixXd p = pb.prior.bin(wiener::radial_bin(f / pb.cols, f % pb.cols, pb.rows, pb.cols, pb.prior.bins));
    Eigen::MatrixXcd a(nc, nb);
    for (Eigen::Index b = 0; b < nb; ++b) a.col(b) = pb.srf.col(b).cast<cdouble>() * otf.data[std::size_t(b) * pb.rows * pb.cols + f];
    Eigen::MatrixXcd m = a * p.cast<cdouble>() * a.adjoint();
    m.diagonal().array() += pb.sigma * pb.sigma;
    const Eigen::VectorXd ev = Eigen::SelfAdjointEigenSolver<Eigen::MatrixXcd>(m).eigenvalues();
    worst = std::max(worst, ev.maxCoeff() / std::max(ev.minCoeff(), 1e-300));
  }
  return worst;
}

// Tolerances are multiples of eps(precision) · sqrt(B·C) · max(κ, κ_M), the textbook bounds:
// κ, the cancellation factor of the objective: tr E(f) = tr P(f) − tr(Kh^H A P)(f) subtracts two
// numbers of size tr P, so relative rounding errors eps of the terms become eps · κ of the value,
// κ = Σ_f tr P(bin(f)) / Σ_f tr E(f) (the gradient −2c Kh E has the same difference inside);
// κ_M, the condition number of the C x C solve (below): relative errors eps of A P and M (the
// float32 OTF, the B-term sums) become up to eps · κ_M in Kh, to which the gradient is first
// order. sqrt(B·C) counts the rounding errors of the sums over bands and channels.
double cancellation(const Problem& pb, double value) {
  double trp = 0;
  for (std::size_t ky = 0; ky < pb.rows; ++ky)
    for (std::size_t kx = 0; kx < pb.cols; ++kx) {
      const std::size_t k = wiener::radial_bin(ky, kx, pb.rows, pb.cols, pb.prior.bins);
      for (std::size_t b = 0; b < pb.bands; ++b) trp += pb.prior.cov[(k * pb.bands + b) * pb.bands + b];
    }
  return trp / (value * double(pb.rows * pb.cols * pb.bands));
}

Compared compare(const Problem& pb, Precision prec, bool acc64) {
  wiener::DeviceObjective dev(runtime(), prec, pb.srf, pb.prior, pb.sigma, pb.psf_size, acc64);
  const wiener::PsfObjective d = dev.expected(pb.psf);
  const wiener::PsfObjective r = wiener::objective_psf(wiener::Loss::Expected, pb.psf, pb.srf, pb.prior, pb.sigma);
  const auto gd = diff(d.grad_psf.data, r.grad_psf.data);
  INFO("value device " << d.value << " reference " << r.value << "; gradient rel L2 " << gd.rel_l2 << ", worst index "
                       << gd.worst << " (device " << d.grad_psf.data[gd.worst] << ", reference "
                       << r.grad_psf.data[gd.worst] << ")");
  REQUIRE(std::isfinite(d.value));
  const double kappa = std::max(cancellation(pb, r.value), solve_condition(pb));
  return {std::fabs(d.value - r.value) / std::fabs(r.value), gd.rel_l2,
          16 * std::sqrt(double(pb.bands * pb.channels)) * kappa * eps(prec)};
}

std::string label(const Problem& p) {
  return std::to_string(p.bands) + " bands, " + std::to_string(p.channels) + " channels, " + std::to_string(p.rows) +
         " x " + std::to_string(p.cols) + " grid, S = " + std::to_string(p.psf_size);
}

}  // namespace

TEST_SUITE("wiener-device") {
  // Grids odd and even on each axis, band counts odd and even (the last pair half empty), PSFs
  // smaller than, equal to and larger than the grid (the wrap folds), C = 1 ... 4.
  const std::vector<Problem> problems = {
      make_problem(5, 3, 12, 10, 8, 1e-3, 1),   make_problem(4, 3, 9, 15, 20, 1e-3, 2),
      make_problem(31, 3, 16, 16, 16, 1e-3, 3), make_problem(7, 1, 10, 7, 6, 1e-2, 4),
      make_problem(6, 4, 8, 12, 12, 1e-3, 5),   make_problem(3, 2, 14, 14, 9, 0.0, 6),
      // well conditioned (noise 0.05: κ_M small), so the float32 tolerance is tight too
      make_problem(31, 3, 16, 16, 16, 0.05, 7), make_problem(5, 3, 12, 10, 8, 0.05, 8),
  };

  TEST_CASE("device objective equals the CPU reference (float64)") {
    if (!skip_unless(runtime().has_fp64(), "float64 comparison: the device has no float64")) return;
    for (const Problem& pb : problems) {
      INFO(label(pb));
      const Compared c = compare(pb, Precision::F64, true);
      MESSAGE(label(pb) << ", f64: value rel err " << c.value_rel << ", gradient rel L2 " << c.grad_rel << ", tolerance "
                        << c.tol);
      CHECK(c.value_rel <= c.tol);
      CHECK(c.grad_rel <= c.tol);
    }
  }

  TEST_CASE("device objective in float32 against the CPU reference in double") {
    for (const bool acc64 : {true, false}) {
      if (acc64 && !runtime().has_fp64()) continue;
      for (const Problem& pb : problems) {
        if (pb.sigma == 0) continue;  // σ = 0 leans on the exact solve: float64 only
        INFO(label(pb) << ", float64 accumulation " << acc64);
        const Compared c = compare(pb, Precision::F32, acc64);
        MESSAGE(label(pb) << ", f32, f64 accumulation " << acc64 << ": value rel err " << c.value_rel
                          << ", gradient rel L2 " << c.grad_rel << ", tolerance " << c.tol);
        CHECK(c.value_rel <= c.tol);
        CHECK(c.grad_rel <= c.tol);
      }
    }
  }

  TEST_CASE("a prior of one spectrum (M within sigma^2 of singular at DC) stays solvable in float32") {
    // Forming M from a float32 A P loses σ² against |M| and can make M indefinite; the kernel
    // forms M as the Gram matrix (A F)(A F)^H, positive definite whatever the rounding.
    for (const std::size_t bands : {std::size_t(3), std::size_t(31)}) {
      const Problem pb = make_problem(bands, 3, 16, 16, 16, 1e-3, 41, true);
      INFO(label(pb) << ", one spectrum");
      if (skip_unless(runtime().has_fp64(), "float64 accumulation: the device has no float64")) {
        const Compared c = compare(pb, Precision::F32, true);
        MESSAGE(label(pb) << ", one spectrum: value rel err " << c.value_rel << ", gradient rel L2 " << c.grad_rel);
        // κ_M ~ 1e9 here makes the textbook bound useless; the measured errors are ~2e-4.
        CHECK(c.value_rel <= 1e-2);
        CHECK(c.grad_rel <= 1e-2);
      }
      // Without float64 the C x C matrix is float32, which cannot hold σ² next to |M| ~ 1e3
      // (σ²/|M| ~ 1e-9 < eps): refused with the way out named, never a silent wrong value.
      wiener::DeviceObjective f32(runtime(), Precision::F32, pb.srf, pb.prior, pb.sigma, pb.psf_size, false);
      CHECK_THROWS_WITH_AS(f32.expected(pb.psf), doctest::Contains("--wiener-on cpu"), Error);
    }
  }

  TEST_CASE("adjoint ladder: device value and gradient in float64 (finite differences)") {
    if (!skip_unless(runtime().has_fp64(), "float64 ladder: the device has no float64")) return;
    const Problem pb = make_problem(5, 3, 12, 10, 8, 1e-3, 11);
    wiener::DeviceObjective dev(runtime(), Precision::F64, pb.srf, pb.prior, pb.sigma, pb.psf_size);
    const auto to_stack = [&](const std::vector<double>& x) {
      RealStack s(pb.bands, pb.psf_size, pb.psf_size);
      s.data = x;
      return s;
    };
    Stage st("wiener expected error (device, f64)", pb.psf.size(), 1);
    st.x0 = pb.psf.data;
    st.forward = [&](const std::vector<double>& x) { return std::vector<double>{dev.expected(to_stack(x)).value}; };
    st.vjp = [&](const std::vector<double>& x, const std::vector<double>& g) {
      std::vector<double> grad = dev.expected(to_stack(x)).grad_psf.data;
      for (double& v : grad) v *= g[0];
      return grad;
    };
    st.fd_step = 1e-5;
    st.fd_tol = 1e-6;
    st.samples = 6;
    check_ladder(st, 2026);
  }

  TEST_CASE("the device-resident form gives the host form's numbers") {
    const Problem& pb = problems[0];
    const Precision p = runtime().has_fp64() ? Precision::F64 : Precision::F32;
    wiener::DeviceObjective dev(runtime(), p, pb.srf, pb.prior, pb.sigma, pb.psf_size);
    const wiener::PsfObjective host = dev.expected(pb.psf);
    const std::size_t n = pb.psf.size();
    cl::Buffer psf(runtime().context(), CL_MEM_READ_WRITE, n * real_size(p));
    cl::Buffer grad(runtime().context(), CL_MEM_READ_WRITE, n * real_size(p));
    runtime().write_reals(psf, pb.psf.data.data(), n, p);
    const double v = dev.expected(psf, grad);
    std::vector<double> g(n);
    runtime().read_reals(grad, g.data(), n, p);
    CHECK(v == host.value);
    CHECK(g == host.grad_psf.data);
  }

  TEST_CASE("a singular filter (noise_sigma 0, a zero OTF) is an error naming the frequency, as on the CPU") {
    Problem pb = make_problem(4, 3, 8, 8, 8, 0.0, 21);
    for (double& v : pb.psf.data) v = 0;
    wiener::DeviceObjective dev(runtime(), Precision::F32, pb.srf, pb.prior, 0.0, pb.psf_size);
    CHECK_THROWS_WITH_AS(dev.expected(pb.psf), doctest::Contains("DFT index (0, 0)"), Error);
    CHECK_THROWS_AS(wiener::objective_psf(wiener::Loss::Expected, pb.psf, pb.srf, pb.prior, 0.0), Error);
  }

  TEST_CASE("bad arguments are refused naming the argument, before any device work") {
    const Problem pb = make_problem(4, 3, 8, 8, 8, 1e-3, 31);
    Runtime& rt = runtime();
    CHECK_THROWS_WITH_AS(wiener::DeviceObjective(rt, Precision::F32, pb.srf, pb.prior, -1.0, 8),
                         doctest::Contains("noise_sigma"), InputError);
    CHECK_THROWS_WITH_AS(wiener::DeviceObjective(rt, Precision::F32, pb.srf, pb.prior, 1e-3, 0),
                         doctest::Contains("psf_size"), InputError);
    Eigen::MatrixXd five = Eigen::MatrixXd::Constant(5, 4, 0.25);
    CHECK_THROWS_WITH_AS(wiener::DeviceObjective(rt, Precision::F32, five, pb.prior, 1e-3, 8),
                         doctest::Contains("channels"), InputError);
    Eigen::MatrixXd wrong = Eigen::MatrixXd::Constant(3, 5, 0.2);
    CHECK_THROWS_WITH_AS(wiener::DeviceObjective(rt, Precision::F32, wrong, pb.prior, 1e-3, 8),
                         doctest::Contains("srf"), InputError);
    wiener::DeviceObjective dev(rt, Precision::F32, pb.srf, pb.prior, 1e-3, 8);
    CHECK_THROWS_WITH_AS(dev.expected(RealStack(4, 9, 9)), doctest::Contains("psf"), InputError);
    RealStack bad = pb.psf;
    bad.data[3] = std::nan("");
    CHECK_THROWS_WITH_AS(dev.expected(bad), doctest::Contains("non-finite"), InputError);
  }
}
