// The as-built fit's uncertainties (fit.hpp): the curvature sigma, the correlations and the
// degenerate pairs, the jackknife over band groups, and the verdict on whether sigma can be read as
// an error. Used by fit.cpp at the fit's end.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "qdo/asbuilt/fit.hpp"
#include "qdo/runtime/error.hpp"

#include "fit_internal.hpp"

namespace qdo::fit_detail {

namespace {

// The pseudo-inverse of a symmetric matrix: eigenvalues at or below rel x the largest dropped
// (their directions undetermined); the eigenvalues, ascending, into *eigenvalues when given.
Eigen::MatrixXd symmetric_pinv(const Eigen::MatrixXd& a, double rel, Eigen::VectorXd* eigenvalues = nullptr) {
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(a);
  const Eigen::VectorXd& ev = es.eigenvalues();
  Eigen::VectorXd inv = Eigen::VectorXd::Zero(ev.size());
  for (long k = 0; k < ev.size(); ++k) inv(k) = ev(k) > rel * ev.maxCoeff() ? 1 / ev(k) : 0;
  if (eigenvalues) *eigenvalues = ev;
  return es.eigenvectors() * inv.asDiagonal() * es.eigenvectors().transpose();
}

}  // namespace

void fit_uncertainties(AsBuiltModel& model, const SystemConfig& cfg, const RealStack& measured, const std::vector<double>& theta,
                       const std::vector<double>& theta0, double loss, double dof, int jackknife_groups, FitResult& res) {
  const std::size_t np = theta.size(), m = measured.data.size();
  const Eigen::Map<const Eigen::VectorXd> meas(measured.data.data(), long(m));
  // Cov = s^2 (J^T J)^-1, in the unit-diagonal scaling.
  const Eigen::MatrixXd j = model.jacobian(theta);
  const auto t2 = std::chrono::steady_clock::now();
  const Eigen::MatrixXd a = j.transpose() * j;
  Eigen::VectorXd dinv = Eigen::VectorXd::Zero(long(np));
  for (long k = 0; k < long(np); ++k) dinv(k) = a(k, k) > 0 ? 1 / std::sqrt(a(k, k)) : 0;
  const Eigen::MatrixXd as = dinv.asDiagonal() * a * dinv.asDiagonal();
  Eigen::VectorXd ev;
  const Eigen::MatrixXd as_inv = symmetric_pinv(as, 1e-15, &ev);
  const double evmax = ev.maxCoeff(), evmin = ev.minCoeff();
  res.condition = evmin > 0 ? evmax / evmin : std::numeric_limits<double>::infinity();
  const double s2 = 2 * loss / dof;
  res.residual_sigma = std::sqrt(s2);
  res.correlation = Eigen::MatrixXd::Zero(long(np), long(np));
  for (long a_ = 0; a_ < long(np); ++a_)
    for (long b = 0; b < long(np); ++b) {
      const double den = std::sqrt(as_inv(a_, a_) * as_inv(b, b));
      res.correlation(a_, b) = den > 0 ? as_inv(a_, b) / den : (a_ == b ? 1.0 : 0.0);
    }
  for (std::size_t k = 0; k < np; ++k) {
    FitValue v;
    v.name = model.parameter_names()[k];
    v.unit = model.parameter_units()[k];
    v.design = theta0[k];
    v.value = theta[k];
    v.sigma = as_inv(long(k), long(k)) > 0 ? std::sqrt(s2 * as_inv(long(k), long(k))) * dinv(long(k))
                                           : std::numeric_limits<double>::infinity();
    v.gradient = model.adjoint_parameter(k) ? "adjoint" : "central differences";
    res.values.push_back(v);
  }
  for (std::size_t x = 0; x < np; ++x)
    for (std::size_t y = x + 1; y < np; ++y)
      if (std::fabs(res.correlation(long(x), long(y))) > 0.95) res.degenerate.push_back({x, y});
  // The jackknife over band groups: the bands in jackknife_groups contiguous groups; for each, the
  // Gauss-Newton step from the fit with that group's residuals left out (linearised: the Jacobian
  // and residuals at the fit, no new model evaluation), sigma_jk^2 = (G - 1) / G sum (step -
  // mean step)^2. Where the model misses something that differs between wavelengths, the groups
  // pull the parameters apart and sigma_jk grows; the curvature sigma does not see it.
  res.model_psf = model.evaluate(theta);
  const std::size_t groups = std::min<std::size_t>(cfg.bands, std::size_t(std::max(0, jackknife_groups)));
  if (groups >= 2 && np > 0) {
    const Eigen::VectorXd r = Eigen::Map<const Eigen::VectorXd>(res.model_psf.data.data(), long(m)) - meas;
    const Eigen::VectorXd g_all = j.transpose() * r;
    const std::size_t plane = measured.rows * measured.cols;
    std::vector<Eigen::VectorXd> steps;
    for (std::size_t q = 0; q < groups; ++q) {
      const std::size_t b0 = q * cfg.bands / groups, b1 = (q + 1) * cfg.bands / groups;
      const long row0 = long(b0 * plane), rows = long((b1 - b0) * plane);
      const auto jq = j.middleRows(row0, rows);
      const Eigen::MatrixXd aq = a - jq.transpose() * jq;
      const Eigen::VectorXd gq = g_all - jq.transpose() * r.segment(row0, rows);
      // Solved in the unit-diagonal scaling of the full problem, small eigenvalues dropped (as the covariance).
      const Eigen::MatrixXd aqs_inv = symmetric_pinv(dinv.asDiagonal() * aq * dinv.asDiagonal(), 1e-12);
      steps.push_back(-(dinv.asDiagonal() * aqs_inv * (dinv.asDiagonal() * gq)));
    }
    Eigen::VectorXd mean = Eigen::VectorXd::Zero(long(np));
    for (const auto& d : steps) mean += d / double(groups);
    for (std::size_t k = 0; k < np; ++k) {
      double v = 0;
      for (const auto& d : steps) v += (d(long(k)) - mean(long(k))) * (d(long(k)) - mean(long(k)));
      res.values[k].sigma_jackknife = std::sqrt(v * double(groups - 1) / double(groups));
    }
    res.jackknife_groups = int(groups);
  }
  model.times().solve_s += since(t2);
}

void fit_sigma_verdict(const Design& design, const FitOptions& opt, FitResult& res) {
  if (res.jackknife_groups >= 2) {
    const double worst = *std::max_element(res.residual_rel_fit.begin(), res.residual_rel_fit.end());
    res.sigma_reliable = true;
    std::string names;
    for (const FitValue& v : res.values)
      if (worst >= 1e-6 && v.name != "sx" && v.name != "sy" && std::isfinite(v.sigma_jackknife) && std::isfinite(v.sigma) &&
          v.sigma_jackknife > 3 * v.sigma)
        names += (names.empty() ? "" : ", ") + v.name;
    if (!names.empty()) {
      res.sigma_reliable = false;
      res.sigma_unreliable_because = "the jackknife sigma over " + std::to_string(res.jackknife_groups) +
                                     " band groups is more than 3 x the curvature sigma for " + names +
                                     ": the model misses something that differs between wavelengths";
    }
  }
  const double chi2 = res.residual_sigma * res.residual_sigma;
  if (opt.observation && opt.observation->noise_units && chi2 > kReducedChi2Reliable) {
    res.sigma_reliable = false;
    res.sigma_unreliable_because += (res.sigma_unreliable_because.empty() ? "" : "; ") + std::string("the reduced chi^2 ") +
                                    to_str(chi2) + " is over " + to_str(kReducedChi2Reliable) +
                                    ": the model misses something larger than the noise";
  }
  // Where the relief was made with two masks or more and their own overlay is not fitted, say that
  // it is the first thing the model may miss (each mask's overlay bends the levels otherwise).
  if (!res.sigma_reliable && !res.sigma_unreliable_because.empty() &&
      std::find(opt.parameters.begin(), opt.parameters.end(), "overlay") == opt.parameters.end() && design.levels_m.size() >= 2) {
    const bool binary = std::find(opt.parameters.begin(), opt.parameters.end(), "masks") != opt.parameters.end();
    if (fit_mask_set(design, binary).open.size() >= 2)
      res.sigma_unreliable_because += "; if the DOE was made with several lithography masks, each mask's own overlay is not in "
                                      "this fit: add overlay to --fit";
  }
}

}  // namespace qdo::fit_detail
