// The as-built fit (fit.hpp): Levenberg-Marquardt over AsBuiltModel (fit_model.cpp) with
// Gauss-Newton uncertainties, correlations and the report.
#include "qdo/asbuilt/fit.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <set>
#include <utility>

#include "qdo/design/design.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/physics/simulator.hpp"

#include "fit_internal.hpp"

namespace qdo {

using fit_detail::fmt;
using fit_detail::since;

// ---------------------------------------------------------------------------------------------
// The fit
// ---------------------------------------------------------------------------------------------

namespace {

std::vector<double> band_residuals(const RealStack& model, const RealStack& meas) {
  const std::size_t plane = meas.rows * meas.cols;
  std::vector<double> out(meas.planes, 0.0);
  for (std::size_t b = 0; b < meas.planes; ++b) {
    double rr = 0, mm = 0;
    for (std::size_t i = b * plane; i < (b + 1) * plane; ++i) {
      const double r = model.data[i] - meas.data[i];
      rr += r * r;
      mm += meas.data[i] * meas.data[i];
    }
    out[b] = mm > 0 ? std::sqrt(rr / mm) : std::sqrt(rr);
  }
  return out;
}

std::string values_line(const AsBuiltModel& m, const std::vector<double>& theta) {
  std::string s;
  for (std::size_t i = 0; i < theta.size(); ++i) {
    const std::string& u = m.parameter_units()[i];
    const std::string& n = m.parameter_names()[i];
    if (u == "m" && (n == "z" || n == "d"))
      s += " " + n + "=" + fmt("%.4f", theta[i] * 1e3) + "mm";
    else if (u == "m" && (n == "dx" || n == "dy" || is_overlay_parameter(n)))
      s += " " + n + "=" + fmt("%.3f", theta[i] * 1e6) + "um";
    else if (u == "m")
      s += " " + n + "=" + fmt("%.2f", theta[i] * 1e9) + "nm";
    else
      s += " " + n + "=" + fmt("%.5f", theta[i]);
  }
  return s;
}

}  // namespace

FitResult fit_as_built(Runtime& rt, const SystemConfig& cfg, Precision p, const Design& design, const RealStack& measured,
                       const FitOptions& opt_in) {
  FitOptions opt = opt_in;
  if (opt.parameters.empty()) opt.parameters = default_fit_parameters(design);
  if (opt.max_iterations < 1) reject("--iterations", opt.max_iterations, "an integer >= 1");
  const std::size_t s = cfg.sensor_size_px();
  if (measured.planes != cfg.bands || measured.rows != s || measured.cols != s)
    throw InputError("the measured PSF stack is " + shape(measured) + "; the configuration needs bands x S x S = " +
                     shape(cfg.bands, s, s));
  for (double v : measured.data)
    if (!std::isfinite(v)) throw InputError("the measured PSF stack holds a non-finite value");
  const bool scan_aperture = std::find(opt.parameters.begin(), opt.parameters.end(), "aperture") != opt.parameters.end();
  AsBuiltModel model(rt, cfg, p, design, opt.parameters, opt);  // every other check, before device work
  const std::size_t np = model.parameter_names().size(), m = measured.data.size();
  if (m <= np) throw InputError("the measured PSF stack has " + std::to_string(m) + " values for " + std::to_string(np) + " parameters");
  // The residuals s^2 counts: every value of the stack, or an observation's data less its own unknowns.
  const FitObservation* obs = opt.observation.get();
  if (obs && obs->residuals <= obs->nuisance + np)
    throw InputError("the measurement has " + std::to_string(obs->residuals) + " usable values for " +
                     std::to_string(np) + " parameters and " + std::to_string(obs->nuisance) + " source powers");
  const double dof = obs ? double(obs->residuals - obs->nuisance - np) : double(m - np);
  const auto say = [&](const std::string& l) {
    if (opt.progress) opt.progress(l);
  };
  const Eigen::Map<const Eigen::VectorXd> meas(measured.data.data(), long(m));
  FitResult res;
  FitTimes& t = model.times();
  const auto wall0 = std::chrono::steady_clock::now();
  const std::vector<double> theta0 = model.design_values();
  std::vector<double> theta = theta0;
  res.design_psf = model.evaluate(theta0);
  res.loss_design = 0.5 * (Eigen::Map<const Eigen::VectorXd>(res.design_psf.data.data(), long(m)) - meas).squaredNorm();
  res.residual_rel_design = band_residuals(res.design_psf, measured);
  // The start: the centroid, the given values, the lateral grid or scans (fit_starts.cpp).
  fit_detail::LateralStarts lateral = fit_detail::find_lateral_starts(model, cfg, measured, res.design_psf, opt, theta, say);
  res.centroid_shift_px = lateral.centroid_shift_px;
  std::vector<std::pair<double, std::vector<double>>> starts = std::move(lateral.starts);
  const std::size_t lateral_index = lateral.lateral_index;
  const double lateral_min_sep = lateral.min_separation;
  double loss = model.loss(theta, measured), lambda = opt.lambda0;
  res.loss_initial = loss;
  res.loss_history.push_back(loss);
  for (std::size_t l : model.unused_levels())
    say("fit: level " + std::to_string(l) + " is used by no DOE pixel: held at its design value (the PSF does not depend on it)");
  res.unused_levels = model.unused_levels();
  say("fit: " + std::to_string(np) + " parameters, " + std::to_string(m) + " residuals; design loss " + fmt("%.6e", loss) +
      values_line(model, theta));
  const auto distance = [&](std::size_t k) { return !model.adjoint_parameter(k); };
  // The overlay's parameters (oxM, oyM): piecewise linear in the relief, kinked at whole DOE pixels.
  std::vector<std::size_t> overlay_index;
  for (std::size_t k = 0; k < np; ++k)
    if (is_overlay_parameter(model.parameter_names()[k])) overlay_index.push_back(k);
  // Levenberg-Marquardt: the adjoint gradient (the distances' entries from the Jacobian's
  // columns), J^T J from the Jacobian, Marquardt's damping on its diagonal.
  // One run from th (in place, with its loss l and damping lam): at most max_it iterations numbered
  // from first, each accepted loss appended to history when given, a line each when lines.
  // Returns the iterations done and whether it stopped at a minimum (not at max_it).
  const auto levenberg_marquardt = [&](std::vector<double>& th, double& l, double& lam, int max_it, int first, bool lines,
                                       std::vector<double>* history) {
    int done = 0;
    const int total = first - 1 + max_it;
    for (int it = first; it <= total; ++it) {
      std::vector<double> grad;
      RealStack current;
      l = model.adjoint_gradient(th, measured, grad, &current);
      const Eigen::MatrixXd j = model.jacobian(th, &current);  // one-sided: J^T J for the step
      const auto ts = std::chrono::steady_clock::now();
      const Eigen::VectorXd r = Eigen::Map<const Eigen::VectorXd>(current.data.data(), long(m)) - meas;
      Eigen::VectorXd g = Eigen::VectorXd::Zero(long(np));
      for (std::size_t k = 0; k < np; ++k) g(long(k)) = distance(k) ? j.col(long(k)).dot(r) : grad[k];
      Eigen::MatrixXd a = j.transpose() * j;
      t.solve_s += since(ts);
      // An overlay on a kink (a whole DOE pixel): its column above is the right one (the next
      // cell); the left one too, so a step may take the side it goes to (or none where both rise).
      std::vector<std::size_t> at_kink;
      std::vector<Eigen::VectorXd> left_columns;
      for (std::size_t k : overlay_index) {
        const double px = th[k] / cfg.pitch_m;
        if (px != std::round(px)) continue;
        std::vector<double> b = th;
        b[k] -= opt.fd_px * cfg.pitch_m;
        const RealStack fb = model.evaluate(b);
        left_columns.push_back((Eigen::Map<const Eigen::VectorXd>(current.data.data(), long(m)) -
                                Eigen::Map<const Eigen::VectorXd>(fb.data.data(), long(m))) /
                               (opt.fd_px * cfg.pitch_m));
        at_kink.push_back(k);
        g(long(k)) = j.col(long(k)).dot(r);  // the right derivative, as the column
      }
      // The damped Gauss-Newton step; an overlay on a kink takes the right column, or the left one
      // when the step goes left, or stays where the step with either column goes back across.
      std::vector<int> side(at_kink.size(), 1);
      const auto step = [&](double damping) {
        Eigen::VectorXd delta;
        for (int pass = 0; pass < 1 + 2 * int(at_kink.size()); ++pass) {
          Eigen::MatrixXd jj = j;
          for (std::size_t q = 0; q < at_kink.size(); ++q) {
            const long k = long(at_kink[q]);
            if (side[q] == -1) jj.col(k) = left_columns[q];
            if (side[q] == 0) jj.col(k).setZero();
          }
          Eigen::VectorXd gg = g;
          if (!at_kink.empty()) {
            a = jj.transpose() * jj;
            for (std::size_t q = 0; q < at_kink.size(); ++q) gg(long(at_kink[q])) = jj.col(long(at_kink[q])).dot(r);
          }
          Eigen::MatrixXd al = a;
          const double dmax = a.diagonal().maxCoeff();
          for (long k = 0; k < long(np); ++k) al(k, k) += damping * std::max(a(k, k), 1e-12 * dmax);
          for (std::size_t q = 0; q < at_kink.size(); ++q)
            if (side[q] == 0) al(long(at_kink[q]), long(at_kink[q])) = 1;  // held: zero row, column and gradient
          delta = al.ldlt().solve(-gg);
          bool changed = false;
          for (std::size_t q = 0; q < at_kink.size(); ++q) {
            const double dq = delta(long(at_kink[q]));
            if (side[q] == 1 && dq < 0) side[q] = -1, changed = true;
            else if (side[q] == -1 && dq > 0) side[q] = 0, changed = true;
          }
          if (!changed) break;
        }
        return delta;
      };
      bool accepted = false;
      double trial_loss = l;
      std::vector<double> trial;
      for (int tries = 0; tries < 16 && !accepted; ++tries) {
        const auto t1 = std::chrono::steady_clock::now();
        std::fill(side.begin(), side.end(), 1);
        const Eigen::VectorXd delta = step(lam);
        t.solve_s += since(t1);
        trial = th;
        for (std::size_t k = 0; k < np; ++k) trial[k] += delta(long(k));
        // An overlay stops at the next whole DOE pixel in its step's direction: past it the
        // column it was stepped with no longer holds (the next iteration takes that cell's).
        for (std::size_t k : overlay_index) {
          const double px = th[k] / cfg.pitch_m, to = trial[k] / cfg.pitch_m;
          const double bound = to > px ? (px == std::floor(px) ? px + 1 : std::ceil(px)) : (px == std::ceil(px) ? px - 1 : std::floor(px));
          if ((to > px && to > bound) || (to < px && to < bound)) trial[k] = bound * cfg.pitch_m;
        }
        try {
          trial_loss = model.loss(trial, measured);
        } catch (const InputError&) {  // a step outside the valid heights or geometry
          trial_loss = std::numeric_limits<double>::infinity();
        }
        if (std::isfinite(trial_loss) && trial_loss < l) {
          accepted = true;
          lam = std::max(lam / 10, 1e-12);
        } else {
          lam *= 10;
        }
      }
      ++done;
      if (!accepted) {
        if (lines) say("fit: iteration " + std::to_string(it) + ": no step lowers the loss (lambda " + fmt("%.1e", lam) + "); stopping");
        return std::make_pair(done, true);
      }
      const double drop = (l - trial_loss) / l;
      // The step against the current 1-sigma (s^2 diag((J^T J)^-1), s^2 from the loss before it).
      double step_sigmas = 0;
      {
        const Eigen::MatrixXd cov = a.completeOrthogonalDecomposition().pseudoInverse() * (2 * l / dof);
        for (std::size_t k = 0; k < np; ++k) {
          const double sg = std::sqrt(std::max(cov(long(k), long(k)), 0.0));
          step_sigmas = std::max(step_sigmas, sg > 0 ? std::fabs(trial[k] - th[k]) / sg : 0.0);
        }
      }
      th = trial;
      l = trial_loss;
      if (history) history->push_back(l);
      if (lines)
        say("fit: iteration " + std::to_string(it) + "/" + std::to_string(total) + " loss " + fmt("%.6e", l) + " (-" +
          fmt("%.2e", drop) + ") lambda " + fmt("%.1e", lam) + " step " + fmt("%.2g", step_sigmas) + " sigma" +
          values_line(model, th) + " [" + fmt("%.1f", since(wall0)) + " s]");
      if (drop < opt.tolerance || step_sigmas < opt.step_sigmas) return std::make_pair(done, true);
    }
    return std::make_pair(done, false);
  };
  // A run from theta, at most budget iterations.
  const auto run_lm = [&](int budget) {
    if (budget < 1) return;
    const auto [done, at_minimum] = levenberg_marquardt(theta, loss, lambda, budget, res.iterations + 1, true, &res.loss_history);
    res.iterations += done;
    res.converged = at_minimum;
  };
  // The refinement of the lateral starts: a short run (refine_iterations) from each of the
  // refine_starts lowest grid starts that lie in different basins (at least lateral_min_sep
  // apart), the mirrors of the lowest always among them (the blur of a relief offset is even in
  // the offset: the loss at a start does not tell its basin from its mirror's); the fit goes on
  // from the run that ends lowest, its iterations counted.
  const auto names_lateral = [&](const std::vector<double>& th) {
    const auto& names = model.parameter_names();
    std::string out;
    for (std::size_t k = lateral_index; k < np && k < lateral_index + 2; ++k)
      out += names[k] + "=" + (model.parameter_units()[k] == "m" ? fmt("%.3f", th[k] * 1e6) + "um " : fmt("%.3f", th[k]) + "px ");
    return out;
  };
  const auto refine_starts = [&]() {
    if (starts.size() < 2 || opt.refine_starts < 2 || opt.refine_iterations < 1) return;
    std::stable_sort(starts.begin(), starts.end(), [](const auto& x, const auto& y) { return x.first < y.first; });
    const std::size_t li = lateral_index;
    const auto apart = [&](const std::vector<double>& x, const std::vector<double>& y) {
      return std::hypot(x[li] - y[li], x[li + 1] - y[li + 1]) >= 0.999 * lateral_min_sep;
    };
    std::vector<std::vector<double>> chosen{starts.front().second};
    const auto take = [&](const std::vector<double>& cand) {
      if (int(chosen.size()) >= opt.refine_starts) return;
      for (const auto& q : chosen)
        if (!apart(q, cand)) return;
      chosen.push_back(cand);
    };
    // The mirrors of the lowest: the grid start nearest to each.
    for (const auto& [mx, my] : {std::make_pair(-1.0, 1.0), std::make_pair(1.0, -1.0), std::make_pair(-1.0, -1.0)}) {
      const std::vector<double>& b0 = starts.front().second;
      const double tx = mx * b0[li], ty = my * b0[li + 1];
      const std::vector<double>* nearest = nullptr;
      double dmin = std::numeric_limits<double>::infinity();
      for (const auto& st : starts) {
        const double dd = std::hypot(st.second[li] - tx, st.second[li + 1] - ty);
        if (dd < dmin) {
          dmin = dd;
          nearest = &st.second;
        }
      }
      if (nearest) take(*nearest);
    }
    for (const auto& st : starts) take(st.second);
    if (chosen.size() < 2) return;
    const int iters = std::min(opt.refine_iterations, opt.max_iterations);
    say("fit: " + std::to_string(chosen.size()) + " lateral starts in different basins (the lowest, its mirrors, the next lowest), " +
        std::to_string(iters) + " iterations from each; the fit goes on from the lowest");
    double best = std::numeric_limits<double>::infinity();
    std::vector<double> best_theta, best_history;
    double best_lambda = opt.lambda0;
    int best_done = 0;
    bool best_min = false;
    for (std::size_t q = 0; q < chosen.size(); ++q) {
      std::vector<double> th = chosen[q];
      double l = model.loss(th, measured), lam = opt.lambda0;
      std::vector<double> hist{l};
      const auto [done, at_minimum] = levenberg_marquardt(th, l, lam, iters, 1, false, &hist);
      say("fit: start " + std::to_string(q + 1) + " at " + names_lateral(chosen[q]) + "loss " + fmt("%.6e", hist.front()) + " -> " +
          fmt("%.6e", l) + " in " + std::to_string(done) + " iterations at" + values_line(model, th));
      if (l < best) {
        best = l;
        best_theta = th;
        best_history = hist;
        best_lambda = lam;
        best_done = done;
        best_min = at_minimum;
      }
    }
    theta = best_theta;
    loss = best;
    lambda = best_lambda;
    res.loss_initial = best_history.front();
    res.loss_history = best_history;
    res.iterations = best_done;
    res.converged = best_min;
  };

  // The aperture: a walk of the loss over radii in half-pixel steps, downhill from the current
  // radius until the loss rises (at most 40 steps, radii in (0, N/2 pitch]), the rest at their
  // fit; when the radius moved, the rest are fitted again with it and the walk repeated (3 rounds
  // at most). The vertex of the parabola through the minimum and its neighbours is the reported
  // radius, its curvature the sigma; the configuration takes the vertex.
  FitValue aperture;
  const double r_design = model.aperture_radius(), h = 0.5 * cfg.pitch_m, rmax = 0.5 * double(cfg.n) * cfg.pitch_m;
  // One walk; whether the radius moved.
  const auto walk = [&]() {
    const auto t1 = std::chrono::steady_clock::now();
    const double r0 = model.aperture_radius();
    const auto loss_at = [&](double r) {
      model.set_aperture_radius(r);
      const double l = model.loss(theta, measured);
      say("fit: aperture scan radius " + fmt("%.3f", r / cfg.pitch_m) + " px loss " + fmt("%.6e", l));
      return l;
    };
    const auto valid = [&](double r) { return r > 0 && r <= rmax * (1 + 1e-12); };
    double l0 = loss, lm = valid(r0 - h) ? loss_at(r0 - h) : std::numeric_limits<double>::infinity(),
           lp = valid(r0 + h) ? loss_at(r0 + h) : std::numeric_limits<double>::infinity();
    double r = r0;
    const double dir = lm < l0 && lm <= lp ? -1.0 : lp < l0 ? 1.0 : 0.0;
    for (int k = 0; dir != 0 && k < 40; ++k) {
      // Step: (lm, l0, lp) become the triple around r + dir h.
      const double next = r + 2 * dir * h;
      const double l_next = valid(next) ? loss_at(next) : std::numeric_limits<double>::infinity();
      if (dir < 0) {
        lp = l0;
        l0 = lm;
        lm = l_next;
      } else {
        lm = l0;
        l0 = lp;
        lp = l_next;
      }
      r += dir * h;
      if ((dir < 0 ? lm : lp) >= l0) break;  // bracketed
    }
    double r_fit = r, curv = 0;
    if (std::isfinite(lm) && std::isfinite(lp)) {
      curv = (lm + lp - 2 * l0) / (h * h);
      if (curv > 0) r_fit = r - h * (lp - lm) / (2 * (lp + lm - 2 * l0));
    }
    model.set_aperture_radius(r);
    loss = l0;
    aperture = {"aperture", "m", r_design, r_fit, 0, "scan"};
    aperture.sigma = curv > 0 ? std::sqrt(2 * loss / dof / curv) : std::numeric_limits<double>::infinity();
    t.scan_s += since(t1);
    if (r == r0) return false;
    say("fit: aperture radius " + fmt("%.3f", r / cfg.pitch_m) + " px; the other parameters fitted (again) with it");
    return true;
  };
  if (scan_aperture) walk();  // first at the start values: a wrong aperture pulls the levels far
  refine_starts();
  if (!res.converged) run_lm(opt.max_iterations - res.iterations);  // what the refinement left of the budget
  // The overlay's other cells. The loss has a minimum in each pixel cell next to a whole pixel (the
  // relief is linear in an overlay inside a cell and kinks between), and from the start (0, a
  // kink) the first steps choose a side while the other parameters are still far off: on simulated
  // cameras the fit then ended with overlays a few hundredths of a pixel on the wrong side and the
  // levels tens of nm off. So each overlay is tried mirrored about its nearest whole pixel (at
  // least 2 difference steps past it) and fitted again (2 x refine_iterations iterations, the rest
  // held at the fit's values to start); the lower loss is kept, overlay by overlay, in two rounds.
  for (int round = 0; round < 2 && !overlay_index.empty(); ++round) {
    bool improved = false;
    for (std::size_t k : overlay_index) {
      const double px = theta[k] / cfg.pitch_m, whole = std::round(px), frac = px - whole;
      std::vector<double> th = theta;
      const double away = std::max(std::fabs(frac), 2 * opt.fd_px);
      th[k] = (whole - (frac >= 0 ? away : -away)) * cfg.pitch_m;
      double l = model.loss(th, measured), lam = opt.lambda0;
      const double l_start = l;
      const auto [done, at_minimum] = levenberg_marquardt(th, l, lam, 2 * std::max(1, opt.refine_iterations), 1, false, nullptr);
      const bool keep = l < loss * (1 - 1e-9);
      say("fit: " + model.parameter_names()[k] + " tried on the other side of " + fmt("%.0f", whole) + " DOE px: loss " +
          fmt("%.6e", l_start) + " -> " + fmt("%.6e", l) + " in " + std::to_string(done) + " iterations (" +
          (keep ? "kept" : "not kept") + "; the fit's " + fmt("%.6e", loss) + ")");
      if (!keep) continue;
      theta = th;
      loss = l;
      lambda = lam;
      res.loss_history.push_back(l);
      res.iterations += done;
      res.converged = at_minimum;
      improved = true;
    }
    if (!improved) break;
    if (!res.converged) run_lm(std::max(1, opt.max_iterations - res.iterations));
  }
  for (int round = 0; scan_aperture && round < 3 && walk(); ++round) {
    lambda = opt.lambda0;
    res.converged = false;
    run_lm(opt.max_iterations);
  }
  // Uncertainties at the fit, the jackknife and the model's stack (fit_sigma.cpp).
  fit_detail::fit_uncertainties(model, cfg, measured, theta, theta0, loss, dof, opt.jackknife_groups, res);
  if (scan_aperture) res.values.push_back(aperture);
  res.loss_final = 0.5 * (Eigen::Map<const Eigen::VectorXd>(res.model_psf.data.data(), long(m)) - meas).squaredNorm();
  res.residual_rel_fit = band_residuals(res.model_psf, measured);
  fit_detail::fit_sigma_verdict(design, opt, res);
  res.as_built.height_m = model.heights(theta);
  res.as_built.pitch_m = design.pitch_m;
  res.as_built.levels_m = model.levels(theta);
  // A level fitted below level 0, or an overlay's edge pixels rounding a hair below it, leaves a
  // height below 0, which no design file takes: the map and its levels are lifted by one constant
  // (a piston: the same PSF), as the model does before each PSF.
  {
    const double lowest = *std::min_element(res.as_built.height_m.data.begin(), res.as_built.height_m.data.end());
    if (lowest < 0) {
      for (double& v : res.as_built.height_m.data) v -= lowest;
      for (double& v : res.as_built.levels_m) v -= lowest;
    }
  }
  res.as_built_config = model.config(theta);
  if (scan_aperture) res.as_built_config.aperture_radius_m = aperture.value;
  res.times = t;
  return res;
}


}  // namespace qdo
