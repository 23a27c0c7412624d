// The Wiener decoder's objective for a camera that records part of its grid (wiener_masked.hpp).
#include "qdo/decode/wiener_masked.hpp"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <exception>
#include <thread>
#include <utility>

#include "qdo/runtime/error.hpp"
#include "qdo/runtime/fftw2.hpp"

namespace qdo {

namespace {

using Index = Eigen::Index;
using CMat = Eigen::MatrixXcd;

Index idx(std::size_t i) { return static_cast<Index>(i); }

double dot(const std::vector<double>& a, const std::vector<double>& b) {
  double s = 0;
  for (std::size_t i = 0; i < a.size(); ++i) s += a[i] * b[i];
  return s;
}

std::string shape3(std::size_t a, std::size_t b, std::size_t c) { return to_str(a) + " x " + to_str(b) + " x " + to_str(c); }

}  // namespace

MaskedWienerDecoder::MaskedWienerDecoder(ComplexStack otf_in, Eigen::MatrixXd srf, const wiener::SpectralPrior& prior, Map2D mask,
                                         double noise_sigma, CgOptions options)
    : srf_(std::move(srf)), prior_(prior), mask_(std::move(mask)), sigma_(noise_sigma), options_(options) {
  const ComplexStack& otf = otf_in;
  const std::size_t nb = otf.planes, h = otf.rows, w = otf.cols, n = h * w;
  if (n == 0 || nb == 0) reject("otf", shape3(nb, h, w), "a non-empty B x H x W stack");
  if (srf_.rows() < 1 || static_cast<std::size_t>(srf_.cols()) != nb || !srf_.allFinite())
    reject("srf", to_str(srf_.rows()) + " x " + to_str(srf_.cols()), "finite C x B with B = " + to_str(nb));
  prior_.validate();
  if (prior_.bands != nb || prior_.rows != h || prior_.cols != w)
    reject("prior", shape3(prior_.bands, prior_.rows, prior_.cols) + " (B x H x W)", "the OTF's " + shape3(nb, h, w));
  if (mask_.rows != h || mask_.cols != w) reject("mask", to_str(mask_.rows) + " x " + to_str(mask_.cols), "the grid's " + to_str(h) + " x " + to_str(w));
  for (std::size_t i = 0; i < n; ++i)
    if (mask_.data[i] != 0.0 && mask_.data[i] != 1.0) reject("mask[" + to_str(i) + "]", mask_.data[i], "0 or 1");
  if (!(sigma_ > 0) || !std::isfinite(sigma_)) reject("noise_sigma", sigma_, "> 0 and finite (the recorded window's system is singular at 0)");
  if (!(options_.tolerance > 0 && options_.tolerance < 1)) reject("tolerance", options_.tolerance, "in (0, 1)");
  if (options_.max_iterations < 1) reject("max_iterations", options_.max_iterations, ">= 1");
  for (std::size_t i = 0; i < otf.size(); ++i)
    if (!std::isfinite(otf.data[i].real()) || !std::isfinite(otf.data[i].imag())) reject("otf[" + to_str(i) + "]", otf.data[i], "finite values");

  // P per bin with its eigenvalues clamped at 0 (apply_prior_power's C^1).
  std::vector<Eigen::MatrixXd> p(prior_.bins);
  for (std::size_t k = 0; k < prior_.bins; ++k) {
    const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(prior_.bin(k));
    const Eigen::VectorXd ev = es.eigenvalues().cwiseMax(0.0);
    p[k] = es.eigenvectors() * ev.asDiagonal() * es.eigenvectors().transpose();
  }
  const std::size_t nc = channels(), hc = w / 2 + 1;  // the half spectrum of a real image (rfftw2)
  q_.assign(h * hc * nc * nc, cdouble(0));
  q_inv_.assign(h * hc * nc * nc, cdouble(0));
  CMat v(idx(nc), idx(nb));
  for (std::size_t ky = 0; ky < h; ++ky)
    for (std::size_t kx = 0; kx < hc; ++kx) {
      const std::size_t f = ky * w + kx, fh = ky * hc + kx;
      const std::size_t k = wiener::radial_bin(ky, kx, h, w, prior_.bins);
      for (std::size_t c = 0; c < nc; ++c)
        for (std::size_t b = 0; b < nb; ++b) v(idx(c), idx(b)) = srf_(idx(c), idx(b)) * otf.data[b * n + f];
      const CMat q = v * p[k].cast<cdouble>() * v.adjoint();
      const CMat qi = (q + CMat::Identity(idx(nc), idx(nc)) * (sigma_ * sigma_)).inverse();
      for (std::size_t i = 0; i < nc; ++i)
        for (std::size_t j = 0; j < nc; ++j) {
          q_[(fh * nc + i) * nc + j] = q(idx(i), idx(j));
          q_inv_[(fh * nc + i) * nc + j] = qi(idx(i), idx(j));
        }
    }
  camera_ = std::make_shared<const DoeEncoder>(std::move(otf_in), srf_);
}

CgResult MaskedWienerDecoder::solve(const RealStack& y) const {
  const std::size_t nc = channels(), h = camera_->rows(), w = camera_->cols(), n = h * w;
  if (y.planes != nc || y.rows != h || y.cols != w) reject("y", shape3(y.planes, y.rows, y.cols), "C x H x W = " + shape3(nc, h, w));
  for (double v : y.data)
    if (!std::isfinite(v)) reject("y", v, "finite values");
  // out = M F⁻¹ (per-frequency C x C matrices m) F u, on the recorded pixels (u: C x H x W), on
  // the half spectrum (u and out are real; m(-f) = conj m(f)).
  const std::size_t nh = h * (w / 2 + 1);
  RealStack in(nc, h, w);
  std::vector<cdouble> t(nc);
  auto apply = [&](const std::vector<cdouble>& m, const std::vector<double>& u, std::vector<double>& out) {
    in.data = u;
    ComplexStack work = rfftw2(in);
    for (std::size_t f = 0; f < nh; ++f) {
      for (std::size_t i = 0; i < nc; ++i) {
        cdouble s = 0;
        for (std::size_t j = 0; j < nc; ++j) s += m[(f * nc + i) * nc + j] * work.data[j * nh + f];
        t[i] = s;
      }
      for (std::size_t i = 0; i < nc; ++i) work.data[i * nh + f] = t[i];
    }
    const RealStack back = irfftw2(work, w);
    out.resize(u.size());
    for (std::size_t c = 0; c < nc; ++c)
      for (std::size_t i = 0; i < n; ++i) out[c * n + i] = back.data[c * n + i] * mask_.data[i];
  };
  const double s2 = sigma_ * sigma_;
  auto apply_g = [&](const std::vector<double>& u, std::vector<double>& gu) {
    apply(q_, u, gu);
    for (std::size_t i = 0; i < u.size(); ++i) gu[i] += s2 * u[i];
  };

  std::vector<double> b(y.data.size());
  for (std::size_t c = 0; c < nc; ++c)
    for (std::size_t i = 0; i < n; ++i) b[c * n + i] = y.data[c * n + i] * mask_.data[i];
  const double b_norm = std::sqrt(dot(b, b));
  CgResult res;
  std::vector<double> u(b.size(), 0.0);
  if (b_norm > 0) {
    std::vector<double> r = b, z, p, gp;
    apply(q_inv_, r, z);
    p = z;
    double rz = dot(r, z);
    const double stop = options_.tolerance * b_norm;
    std::size_t it = 0;
    while (it < options_.max_iterations && std::sqrt(dot(r, r)) > stop) {
      apply_g(p, gp);
      const double pgp = dot(p, gp);
      if (!(pgp > 0)) break;
      const double alpha = rz / pgp;
      for (std::size_t i = 0; i < u.size(); ++i) {
        u[i] += alpha * p[i];
        r[i] -= alpha * gp[i];
      }
      apply(q_inv_, r, z);
      const double rz_new = dot(r, z);
      const double beta = rz_new / rz;
      rz = rz_new;
      for (std::size_t i = 0; i < p.size(); ++i) p[i] = z[i] + beta * p[i];
      ++it;
    }
    apply_g(u, gp);  // the true residual (the recursion drifts from it in long runs)
    double rr = 0;
    for (std::size_t i = 0; i < b.size(); ++i) rr += (b[i] - gp[i]) * (b[i] - gp[i]);
    res.iterations = it;
    res.residual = std::sqrt(rr) / b_norm;
  }
  res.converged = res.residual <= options_.tolerance;
  // x̂ = C A_cᵀ u.
  RealStack ut(nc, h, w);
  ut.data = std::move(u);
  res.x = apply_prior_power(prior_, camera_->adjoint(ut), 1.0);
  {
    const std::lock_guard<std::mutex> lock(stats_mutex_);
    ++stats_.solves;
    stats_.max_iterations = std::max(stats_.max_iterations, res.iterations);
    stats_.worst_residual = std::max(stats_.worst_residual, res.residual);
    stats_.all_converged = stats_.all_converged && res.converged;
  }
  return res;
}

MaskedWienerDecoder::Stats MaskedWienerDecoder::stats() const {
  const std::lock_guard<std::mutex> lock(stats_mutex_);
  return stats_;
}

RealStack MaskedWienerDecoder::decode(const RealStack& y) const { return solve(y).x; }

std::size_t MaskedWienerDecoder::batch() const {
  return std::clamp<std::size_t>(std::thread::hardware_concurrency(), 1, 8);
}

std::vector<RealStack> MaskedWienerDecoder::decode_batch(const std::vector<RealStack>& ys) const {
  std::vector<RealStack> xs(ys.size());
  if (ys.size() <= 1) {
    for (std::size_t i = 0; i < ys.size(); ++i) xs[i] = decode(ys[i]);
    return xs;
  }
  std::vector<std::exception_ptr> errors(ys.size());
  std::vector<std::thread> threads;
  threads.reserve(ys.size());
  for (std::size_t i = 0; i < ys.size(); ++i)
    threads.emplace_back([&, i] {
      try {
        xs[i] = decode(ys[i]);
      } catch (...) {
        errors[i] = std::current_exception();
      }
    });
  for (std::thread& t : threads) t.join();
  for (const std::exception_ptr& e : errors)
    if (e) std::rethrow_exception(e);
  return xs;
}

}  // namespace qdo
