// Linear MMSE (Wiener) decoder and its objectives with exact OTF / PSF gradients (the spectral
// prior and the PSF <-> OTF transforms are in src/decode/wiener_model.cpp, the metrics in
// src/decode/metrics.cpp).
// Conventions: see include/qdo/decode/wiener.hpp.
//
// Gradient derivation (per frequency, A = srf·diag(OTF), M = A P A^H + σ² I, K = P A^H M⁻¹,
// T = K A, E = P − T P; for a real L, G_A = ∂L/∂Re A + i ∂L/∂Im A, dL = Re tr(G_A^H dA)):
//  - expected error L = c tr(E):           G_A = −2c M⁻¹ A P E  (= −2c K^H E)
//  - any L with dL = Re tr(U dT), U ∈ C^{B×B}:
//        G_A = K^H U^H (I − T)^H + M⁻¹ A U E
//    MSE: L = c tr((T − I) Σ (T − I)^H), Σ = Σ_s X_s X_s^H  →  U = 2c Σ (T − I)^H, c = 1/(N·B·n²)
//    MAE: L = Σ |Re IDFT((T − I) X_s)| / (N·B·n)          →  U = Σ_s X_s F[sign_s]^H / (N·B·n²)
//  - chain to the OTF: G_OTF_b = Σ_c srf(c, b) G_A(c, b) (srf real).
// T and E are never formed: with Kh = K^H = M⁻¹ A P (C x B) and AP = A P, T = Kh^H A and
// E = P − Kh^H AP have rank-C structure, so every product costs O(C·B²) instead of O(B³).
#include "qdo/decode/wiener.hpp"
#include "qdo/runtime/fftw2.hpp"

#include <fftw3.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

#include "decode/wiener_internal.hpp"
#include "qdo/runtime/error.hpp"

namespace qdo {
namespace wiener {
using namespace detail;

namespace {

void check_sigma(double noise_sigma) {
  if (!(noise_sigma >= 0) || !std::isfinite(noise_sigma)) reject("noise_sigma", noise_sigma, ">= 0 and finite");
}

// Checks otf / srf / prior / sigma against each other.
void check_model(const ComplexStack& otf, const MatrixXd& srf, const SpectralPrior& prior, double noise_sigma,
                 const char* otf_name = "otf") {
  prior.validate();
  check_sigma(noise_sigma);
  if (otf.planes == 0 || otf.rows == 0 || otf.cols == 0) reject(otf_name, shape(otf), "a non-empty B x H x W stack");
  if (otf.planes != prior.bands || otf.rows != prior.rows || otf.cols != prior.cols)
    reject(otf_name, shape(otf), "the prior's shape " + shape(prior.bands, prior.rows, prior.cols));
  if (srf.rows() < 1 || static_cast<std::size_t>(srf.cols()) != otf.planes)
    reject("srf", to_str(srf.rows()) + " x " + to_str(srf.cols()), "C x B with C >= 1 and B = " + to_str(otf.planes));
  if (!srf.allFinite()) reject("srf", "non-finite entries", "finite values");
  for (const cdouble& v : otf.data)
    if (!std::isfinite(v.real()) || !std::isfinite(v.imag())) reject(otf_name, "non-finite entries", "finite values");
}

// Everything that does not change from frequency to frequency.
struct Setup {
  std::size_t bands = 0, channels = 0, rows = 0, cols = 0, n = 0;
  std::vector<MatrixXcd> p;        // per bin, B x B
  MatrixXcd srf;                   // C x B
  double sigma2 = 0;
  std::vector<std::size_t> bin_of;  // per frequency index ky*cols + kx

  Setup(const MatrixXd& srf_real, const SpectralPrior& prior, double noise_sigma)
      : bands(prior.bands),
        channels(static_cast<std::size_t>(srf_real.rows())),
        rows(prior.rows),
        cols(prior.cols),
        n(prior.rows * prior.cols),
        srf(srf_real.cast<cdouble>()),
        sigma2(noise_sigma * noise_sigma),
        bin_of(n) {
    for (std::size_t k = 0; k < prior.bins; ++k) p.push_back(prior.bin(k).cast<cdouble>());
    for (std::size_t ky = 0; ky < rows; ++ky)
      for (std::size_t kx = 0; kx < cols; ++kx) bin_of[ky * cols + kx] = radial_bin(ky, kx, rows, cols, prior.bins);
  }
  const MatrixXcd& prior_at(std::size_t f) const { return p[bin_of[f]]; }
};

// The filter at one frequency: A, AP = A P, M and its LU, Kh = K^H = M⁻¹ A P.
struct Filter {
  MatrixXcd a;   // C x B
  MatrixXcd ap;  // C x B
  MatrixXcd m;   // C x C, A P A^H + σ² I
  Eigen::PartialPivLU<MatrixXcd> lu;
  MatrixXcd kh;  // C x B

  void build(const Setup& s, const ComplexStack& otf, std::size_t f) {
    const MatrixXcd& p = s.prior_at(f);
    a.resize(static_cast<Eigen::Index>(s.channels), static_cast<Eigen::Index>(s.bands));
    for (std::size_t b = 0; b < s.bands; ++b)
      a.col(static_cast<Eigen::Index>(b)) = s.srf.col(static_cast<Eigen::Index>(b)) * otf.data[b * s.n + f];
    ap.noalias() = a * p;
    m.noalias() = ap * a.adjoint();
    m.diagonal().array() += s.sigma2;
    lu.compute(m);
    kh = lu.solve(ap);
    if (!kh.allFinite())
      throw Error("Wiener filter: A P A^H + sigma^2 I is singular at DFT index (" + to_str(f / s.cols) + ", " +
                  to_str(f % s.cols) + "); use noise_sigma > 0 or an OTF without zeros there");
  }
  // (T − I) v = Kh^H (A v) − v.
  VectorXcd residual(const VectorXcd& v) const { return kh.adjoint() * (a * v) - v; }
};

// tr(X^H Y) = Σ conj(X) ⊙ Y.
cdouble trace_xh_y(const MatrixXcd& x, const MatrixXcd& y) { return (x.conjugate().cwiseProduct(y)).sum(); }

// G_OTF_b(f) = Σ_c srf(c, b) G_A(c, b).
void chain_to_otf(const Setup& s, const MatrixXcd& grad_a, std::size_t f, ComplexStack& grad_otf) {
  for (std::size_t b = 0; b < s.bands; ++b) {
    const auto bi = static_cast<Eigen::Index>(b);
    cdouble g = 0;
    for (std::size_t c = 0; c < s.channels; ++c) {
      const auto ci = static_cast<Eigen::Index>(c);
      g += s.srf(ci, bi).real() * grad_a(ci, bi);
    }
    grad_otf.data[b * s.n + f] = g;
  }
}

// G_A for dL = Re tr(U dT): Kh U^H (I − T)^H + M⁻¹ A U E, expanded with T^H = A^H Kh and
// E = P − Kh^H AP:  R1 − (R1 A^H) Kh + R2 P − (R2 Kh^H) AP,  R1 = Kh U^H, R2 = M⁻¹ A U.
MatrixXcd grad_a_from_u(const Filter& q, const MatrixXcd& p, const MatrixXcd& u) {
  const MatrixXcd r1 = q.kh * u.adjoint();
  const MatrixXcd r2 = q.lu.solve(q.a) * u;
  MatrixXcd g = r1;
  g.noalias() -= (r1 * q.a.adjoint()) * q.kh;
  g.noalias() += r2 * p;
  g.noalias() -= (r2 * q.kh.adjoint()) * q.ap;
  return g;
}

void check_finite_value(double v, const char* what) {
  if (!std::isfinite(v)) throw Error(std::string(what) + " is not finite: the filter is ill-conditioned (noise_sigma too small?)");
}

OtfObjective objective_expected(const Setup& s, const ComplexStack& otf) {
  OtfObjective out;
  out.grad_otf = ComplexStack(s.bands, s.rows, s.cols);
  const double c = 1.0 / double(s.n * s.bands);
  Filter q;
  double acc = 0;
  for (std::size_t f = 0; f < s.n; ++f) {
    q.build(s, otf, f);
    const MatrixXcd& p = s.prior_at(f);
    acc += p.trace().real() - trace_xh_y(q.kh, q.ap).real();  // tr E = tr P − tr(Kh^H AP)
    // G_A = −2c Kh E = −2c (Kh P − (Kh Kh^H) AP)
    MatrixXcd grad_a = q.kh * p;
    grad_a.noalias() -= (q.kh * q.kh.adjoint()) * q.ap;
    grad_a *= -2.0 * c;
    chain_to_otf(s, grad_a, f, out.grad_otf);
  }
  out.value = c * acc;
  check_finite_value(out.value, "the expected error");
  return out;
}

std::vector<ComplexStack> scene_spectra(const std::vector<RealStack>& scenes) {
  std::vector<ComplexStack> x;
  x.reserve(scenes.size());
  for (const RealStack& sc : scenes) x.push_back(forward_fft(sc));
  return x;
}

OtfObjective objective_mse(const Setup& s, const ComplexStack& otf, const std::vector<RealStack>& scenes) {
  const std::vector<ComplexStack> x = scene_spectra(scenes);
  OtfObjective out;
  out.grad_otf = ComplexStack(s.bands, s.rows, s.cols);
  const double c = 1.0 / (double(scenes.size()) * double(s.bands) * double(s.n) * double(s.n));
  const auto nb = static_cast<Eigen::Index>(s.bands);
  Filter q;
  MatrixXcd sigma(nb, nb);
  double acc = 0;
  for (std::size_t f = 0; f < s.n; ++f) {
    q.build(s, otf, f);
    sigma.setZero();
    for (const ComplexStack& xs : x) {
      const VectorXcd v = gather(xs, f);
      sigma.noalias() += v * v.adjoint();
    }
    // Σ (T − I)^H = (Σ A^H) Kh − Σ;  tr((T − I) Σ (T − I)^H) = tr Σ − 2 Re tr(Kh^H A Σ)
    // + tr((A Σ A^H)(Kh Kh^H)).
    const MatrixXcd sah = sigma * q.a.adjoint();  // B x C
    MatrixXcd sd = sah * q.kh;
    sd -= sigma;
    const MatrixXcd as = sah.adjoint();  // A Σ (Σ Hermitian)
    acc += sigma.trace().real() - 2.0 * trace_xh_y(q.kh, as).real() +
           ((q.a * sah) * (q.kh * q.kh.adjoint())).trace().real();
    chain_to_otf(s, grad_a_from_u(q, s.prior_at(f), (2.0 * c) * sd), f, out.grad_otf);
  }
  out.value = c * acc;
  check_finite_value(out.value, "the empirical MSE");
  return out;
}

OtfObjective objective_mae(const Setup& s, const ComplexStack& otf, const std::vector<RealStack>& scenes) {
  const std::vector<ComplexStack> x = scene_spectra(scenes);
  const auto nb = static_cast<Eigen::Index>(s.bands);
  // Pass 1: error spectra (T − I) X_s, then spatial errors, their signs and the signs' spectra.
  std::vector<ComplexStack> err(x.size(), ComplexStack(s.bands, s.rows, s.cols));
  Filter q;
  for (std::size_t f = 0; f < s.n; ++f) {
    q.build(s, otf, f);
    for (std::size_t i = 0; i < x.size(); ++i) scatter(err[i], f, q.residual(gather(x[i], f)));
  }
  double acc = 0;
  for (ComplexStack& e : err) {
    fft2(e, FFTW_BACKWARD, Scale::InverseN);
    for (cdouble& v : e.data) {
      const double r = v.real();
      acc += std::fabs(r);
      v = r > 0 ? 1.0 : (r < 0 ? -1.0 : 0.0);
    }
    fft2(e, FFTW_FORWARD, Scale::None);  // now F[sign(Re e_s)]
  }
  const double denom = double(x.size()) * double(s.bands) * double(s.n);
  OtfObjective out;
  out.value = acc / denom;
  check_finite_value(out.value, "the empirical MAE");
  // Pass 2: dL = 1/(N·B·n²) Re Σ_s Σ_f F[sign_s]^H dT X_s  →  U = c Σ_s X_s F[sign_s]^H.
  out.grad_otf = ComplexStack(s.bands, s.rows, s.cols);
  const double c = 1.0 / (denom * double(s.n));
  MatrixXcd u(nb, nb);
  for (std::size_t f = 0; f < s.n; ++f) {
    q.build(s, otf, f);
    u.setZero();
    for (std::size_t i = 0; i < x.size(); ++i) u.noalias() += gather(x[i], f) * gather(err[i], f).adjoint();
    chain_to_otf(s, grad_a_from_u(q, s.prior_at(f), c * u), f, out.grad_otf);
  }
  return out;
}

}  // namespace

// ---------------------------------------------------------------------------------------------
RealStack decode(const RealStack& y, const ComplexStack& otf, const Eigen::MatrixXd& srf, const SpectralPrior& prior,
                 double noise_sigma) {
  check_model(otf, srf, prior, noise_sigma);
  if (y.planes != static_cast<std::size_t>(srf.rows()) || y.rows != otf.rows || y.cols != otf.cols)
    reject("y", shape(y), "C x H x W = " + shape(static_cast<std::size_t>(srf.rows()), otf.rows, otf.cols));
  const Setup s(srf, prior, noise_sigma);
  const ComplexStack yf = forward_fft(y);
  ComplexStack xf(s.bands, s.rows, s.cols);
  Filter q;
  for (std::size_t f = 0; f < s.n; ++f) {
    q.build(s, otf, f);
    scatter(xf, f, q.kh.adjoint() * gather(yf, f));
  }
  return inverse_fft_real(std::move(xf));
}

namespace {

SigmaSearch sigma_from_data(bool likelihood, const std::vector<RealStack>& ys, const ComplexStack& otf, const Eigen::MatrixXd& srf,
                            const SpectralPrior& prior, double sigma_min, double sigma_max, std::size_t points) {
  check_model(otf, srf, prior, 0.0);
  if (ys.empty()) reject("images", 0, "at least one C x H x W image");
  if (!(sigma_min > 0) || !(sigma_max > sigma_min) || !std::isfinite(sigma_max))
    reject("sigma range", to_str(sigma_min) + " .. " + to_str(sigma_max), "0 < sigma_min < sigma_max, finite");
  if (points < 3) reject("points", points, "at least 3");
  for (const RealStack& y : ys)
    if (y.planes != static_cast<std::size_t>(srf.rows()) || y.rows != otf.rows || y.cols != otf.cols)
      reject("images", shape(y), "C x H x W = " + shape(static_cast<std::size_t>(srf.rows()), otf.rows, otf.cols));
  const Setup s(srf, prior, 0.0);
  std::vector<ComplexStack> yf;
  yf.reserve(ys.size());
  for (const RealStack& y : ys) yf.push_back(forward_fft(y));
  SigmaSearch r;
  std::vector<double> s2(points);
  for (std::size_t j = 0; j < points; ++j) {
    const double t = double(j) / double(points - 1);
    r.sigmas.push_back(sigma_min * std::pow(sigma_max / sigma_min, t));
    s2[j] = r.sigmas[j] * r.sigmas[j];
  }
  std::vector<double> res(points, 0.0), tr(points, 0.0), nll(points, 0.0);
  const double images = double(ys.size());
  const double per_pixel = 1.0 / double(s.n);  // |Y(f)|^2 of the unnormalised DFT is H W x a per-pixel variance
  Eigen::SelfAdjointEigenSolver<MatrixXcd> es;
  MatrixXcd a(static_cast<Eigen::Index>(s.channels), static_cast<Eigen::Index>(s.bands));
  Eigen::VectorXd zsq(static_cast<Eigen::Index>(s.channels));
  for (std::size_t f = 0; f < s.n; ++f) {
    for (std::size_t b = 0; b < s.bands; ++b)
      a.col(static_cast<Eigen::Index>(b)) = s.srf.col(static_cast<Eigen::Index>(b)) * otf.data[b * s.n + f];
    const MatrixXcd m = a * s.prior_at(f) * a.adjoint();
    es.compute(m);
    const Eigen::VectorXd lam = es.eigenvalues().cwiseMax(0.0);
    zsq.setZero();
    for (const ComplexStack& y : yf) zsq += (es.eigenvectors().adjoint() * gather(y, f)).cwiseAbs2();
    for (std::size_t j = 0; j < points; ++j)
      for (Eigen::Index k = 0; k < lam.size(); ++k) {
        const double w = s2[j] / (lam(k) + s2[j]);  // the eigenvalue of I - T
        res[j] += w * w * zsq(k);
        tr[j] += w * images;
        nll[j] += images * std::log(lam(k) + s2[j]) + per_pixel * zsq(k) / (lam(k) + s2[j]);
      }
  }
  const double n = double(s.n) * double(s.channels) * images;
  std::size_t best = 0;
  for (std::size_t j = 0; j < points; ++j) {
    if (likelihood)
      r.scores.push_back(nll[j]);
    else
      r.scores.push_back(tr[j] > 0 ? n * res[j] / (tr[j] * tr[j]) : std::numeric_limits<double>::infinity());
    if (r.scores[j] < r.scores[best]) best = j;
  }
  const double low = r.scores[best];
  for (double& v : r.scores) v = likelihood ? v - low : v / low;
  r.sigma = r.sigmas[best];
  r.at_edge = best == 0 || best + 1 == points;
  if (!r.at_edge) {  // the parabola through the three lowest points, in log sigma
    const double y0 = r.scores[best - 1], y1 = r.scores[best], y2 = r.scores[best + 1];
    const double den = y0 - 2 * y1 + y2;
    if (den > 0) {
      const double step = std::log(r.sigmas[best + 1] / r.sigmas[best]);
      r.sigma = r.sigmas[best] * std::exp(std::clamp(0.5 * (y0 - y2) / den, -0.5, 0.5) * step);
    }
  }
  return r;
}

}  // namespace

SigmaSearch gcv_noise_sigma(const std::vector<RealStack>& ys, const ComplexStack& otf, const Eigen::MatrixXd& srf,
                            const SpectralPrior& prior, double sigma_min, double sigma_max, std::size_t points) {
  return sigma_from_data(false, ys, otf, srf, prior, sigma_min, sigma_max, points);
}

SigmaSearch ml_noise_sigma(const std::vector<RealStack>& ys, const ComplexStack& otf, const Eigen::MatrixXd& srf,
                           const SpectralPrior& prior, double sigma_min, double sigma_max, std::size_t points) {
  return sigma_from_data(true, ys, otf, srf, prior, sigma_min, sigma_max, points);
}

RealStack decode_mismatched(const RealStack& scene, const ComplexStack& otf_actual, const ComplexStack& otf_design,
                            const Eigen::MatrixXd& srf, const SpectralPrior& prior, double noise_sigma) {
  check_model(otf_actual, srf, prior, noise_sigma, "otf_actual");
  check_model(otf_design, srf, prior, noise_sigma, "otf_design");
  return decode(simulate_measurement(scene, otf_actual, srf), otf_design, srf, prior, noise_sigma);
}

double expected_error_mismatched(const ComplexStack& otf_actual, const ComplexStack& otf_design,
                                 const Eigen::MatrixXd& srf, const SpectralPrior& prior, double noise_sigma) {
  check_model(otf_actual, srf, prior, noise_sigma, "otf_actual");
  check_model(otf_design, srf, prior, noise_sigma, "otf_design");
  const Setup s(srf, prior, noise_sigma);
  Filter q;
  MatrixXcd a_act(static_cast<Eigen::Index>(s.channels), static_cast<Eigen::Index>(s.bands));
  double acc = 0;
  for (std::size_t f = 0; f < s.n; ++f) {
    q.build(s, otf_design, f);
    const MatrixXcd& p = s.prior_at(f);
    for (std::size_t b = 0; b < s.bands; ++b)
      a_act.col(static_cast<Eigen::Index>(b)) = s.srf.col(static_cast<Eigen::Index>(b)) * otf_actual.data[b * s.n + f];
    // tr((K A − I) P (K A − I)^H) + σ² ‖K‖² with K = Kh^H:
    // tr P − 2 Re tr(Kh^H A P) + tr((A P A^H)(Kh Kh^H)) + σ² ‖Kh‖².
    const MatrixXcd ap = a_act * p;
    acc += p.trace().real() - 2.0 * trace_xh_y(q.kh, ap).real() +
           ((ap * a_act.adjoint()) * (q.kh * q.kh.adjoint())).trace().real() + s.sigma2 * q.kh.squaredNorm();
  }
  const double v = acc / double(s.n * s.bands);
  check_finite_value(v, "the expected error");
  return v;
}

// ---------------------------------------------------------------------------------------------
OtfObjective objective(Loss loss, const ComplexStack& otf, const Eigen::MatrixXd& srf, const SpectralPrior& prior,
                       double noise_sigma, const std::vector<RealStack>& scenes) {
  check_model(otf, srf, prior, noise_sigma);
  const Setup s(srf, prior, noise_sigma);
  switch (loss) {
    case Loss::Expected:
      return objective_expected(s, otf);
    case Loss::Mse:
      check_scenes(scenes, otf.planes, otf.rows, otf.cols);
      return objective_mse(s, otf, scenes);
    case Loss::Mae:
      check_scenes(scenes, otf.planes, otf.rows, otf.cols);
      return objective_mae(s, otf, scenes);
  }
  reject("loss", static_cast<int>(loss), "Expected, Mse or Mae");
}

PsfObjective objective_psf(Loss loss, const RealStack& psf, const Eigen::MatrixXd& srf, const SpectralPrior& prior,
                           double noise_sigma, const std::vector<RealStack>& scenes) {
  prior.validate();
  if (psf.planes != prior.bands) reject("psf", shape(psf), "B x S x S with B = " + to_str(prior.bands));
  const OtfObjective o = objective(loss, psf_to_otf(psf, prior.rows, prior.cols), srf, prior, noise_sigma, scenes);
  PsfObjective out;
  out.value = o.value;
  out.grad_psf = psf_gradient(o.grad_otf, psf.rows);
  return out;
}

}  // namespace wiener

// ---------------------------------------------------------------------------------------------
WienerDecoder::WienerDecoder(ComplexStack otf, Eigen::MatrixXd srf, wiener::SpectralPrior prior, double noise_sigma)
    : otf_(std::move(otf)), srf_(std::move(srf)), prior_(std::move(prior)), noise_sigma_(noise_sigma) {
  wiener::check_model(otf_, srf_, prior_, noise_sigma_);
}

// The filter Kh(f) (C x B per frequency, the same Filter::build as wiener::decode) is made on the
// first decode and kept: every later image (a reconstruction's tiles, a test set) costs two FFTs
// and one C x B product per frequency. Memory: H·W·C·B complex values (16 bytes each); above
// kFilterCacheBytes (a paper-preset grid: 512² x 3 x 31 is 390 MB) nothing is kept and every
// decode builds the filter as wiener::decode does.
RealStack WienerDecoder::decode(const RealStack& y) const {
  if (y.planes != static_cast<std::size_t>(srf_.rows()) || y.rows != otf_.rows || y.cols != otf_.cols)
    reject("y", shape(y), "C x H x W = " + shape(static_cast<std::size_t>(srf_.rows()), otf_.rows, otf_.cols));
  const std::size_t c = static_cast<std::size_t>(srf_.rows()), b = otf_.planes, n = otf_.rows * otf_.cols;
  if (n * c * b * sizeof(cdouble) > kFilterCacheBytes) return wiener::decode(y, otf_, srf_, prior_, noise_sigma_);
  std::call_once(filter_once_, [&] {
    const wiener::Setup s(srf_, prior_, noise_sigma_);
    wiener::Filter q;
    filter_.resize(n * c * b);
    for (std::size_t f = 0; f < n; ++f) {
      q.build(s, otf_, f);
      for (std::size_t i = 0; i < c; ++i)
        for (std::size_t j = 0; j < b; ++j) filter_[(f * c + i) * b + j] = q.kh(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(j));
    }
  });
  const ComplexStack yf = wiener::forward_fft(y);
  ComplexStack xf(b, otf_.rows, otf_.cols);
  for (std::size_t f = 0; f < n; ++f)
    for (std::size_t j = 0; j < b; ++j) {
      cdouble acc = 0;  // X(j) = Σ_i conj(Kh(i, j)) Y(i): Kh^H Y
      for (std::size_t i = 0; i < c; ++i) acc += std::conj(filter_[(f * c + i) * b + j]) * yf.data[i * n + f];
      xf.data[j * n + f] = acc;
    }
  return wiener::inverse_fft_real(std::move(xf));
}

}  // namespace qdo
