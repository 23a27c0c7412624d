// The as-built fit (fit.hpp): Levenberg-Marquardt over AsBuiltModel (fit_model.cpp) with
// Gauss-Newton uncertainties, correlations and the report.
#include "qdo/fit.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <set>

#include "qdo/design.hpp"
#include "qdo/error.hpp"
#include "qdo/simulator.hpp"

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

// The mean over bands of the centroid of a minus that of b (sensor px, (columns, rows)), each
// over the pixels above 10 % of its band's peak (the noise of the dark background left out).
std::pair<double, double> centroid_difference_px(const RealStack& a, const RealStack& b) {
  const auto centroid = [](const RealStack& st, std::size_t band, double& cx, double& cy) {
    const std::size_t plane = st.rows * st.cols;
    const double* p = st.data.data() + band * plane;
    const double peak = *std::max_element(p, p + plane);
    double w = 0;
    cx = cy = 0;
    for (std::size_t i = 0; i < plane; ++i)
      if (p[i] > 0.1 * peak) {
        w += p[i];
        cx += p[i] * double(i % st.cols);
        cy += p[i] * double(i / st.cols);
      }
    if (w > 0) {
      cx /= w;
      cy /= w;
    }
    return w > 0;
  };
  double sx = 0, sy = 0;
  std::size_t used = 0;
  for (std::size_t band = 0; band < a.planes; ++band) {
    double ax, ay, bx, by;
    if (!centroid(a, band, ax, ay) || !centroid(b, band, bx, by)) continue;
    sx += ax - bx;
    sy += ay - by;
    ++used;
  }
  return used ? std::make_pair(sx / double(used), sy / double(used)) : std::make_pair(0.0, 0.0);
}

std::string values_line(const AsBuiltModel& m, const std::vector<double>& theta) {
  std::string s;
  for (std::size_t i = 0; i < theta.size(); ++i) {
    const std::string& u = m.parameter_units()[i];
    const std::string& n = m.parameter_names()[i];
    if (u == "m" && (n == "z" || n == "d"))
      s += " " + n + "=" + fmt("%.4f", theta[i] * 1e3) + "mm";
    else if (u == "m" && (n == "dx" || n == "dy"))
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
  // The lateral starts tried, with their losses; the index of the first lateral parameter (np when
  // there is no grid) and the distance below which two starts share a basin.
  std::vector<std::pair<double, std::vector<double>>> starts;
  std::size_t lateral_index = 0;
  double lateral_min_sep = 0;
  // The lateral start: a relief offset (dx, dy) moves the image of the on-axis point by
  // (dx, dy) (1 + z/d), while the blur it adds to the sampled relief is the same for +-dx: from
  // zero, the fit can fall into the mirror minimum. It starts from the centroid difference of the
  // measured and design stacks (shift when it is fitted, else offset).
  {
    const auto& names = model.parameter_names();
    const auto find = [&](const char* n) { return std::size_t(std::find(names.begin(), names.end(), n) - names.begin()); };
    const auto c = centroid_difference_px(measured, res.design_psf);
    const std::size_t sx = find("sx"), dx = find("dx");
    if (sx < np) {
      theta[sx] = c.first;
      theta[sx + 1] = c.second;
    } else if (dx < np) {
      const double mag = cfg.scene_at_infinity ? 1.0 : 1.0 + cfg.sensor_distance_m / cfg.scene_distance_m;
      theta[dx] = c.first * cfg.sensor_pitch_m / mag;
      theta[dx + 1] = c.second * cfg.sensor_pitch_m / mag;
    }
    if (sx < np || dx < np) {
      res.centroid_shift_px = {c.first, c.second};
      say("fit: centroid of the measured stack against the design's: (" + fmt("%+.4f", c.first) + ", " + fmt("%+.4f", c.second) +
          ") sensor px; the start of " + (sx < np ? "shift" : "offset"));
    }
    for (const auto& [name, value] : opt.start) {
      const std::size_t k = find(name.c_str());
      if (k >= np) reject("start", name, "a fitted parameter's name (" + [&] {
                            std::string all;
                            for (const auto& n : names) all += (all.empty() ? "" : ", ") + n;
                            return all;
                          }() + ")");
      if (!std::isfinite(value)) reject("start", name + "=" + fmt("%g", value), "a finite value");
      theta[k] = value;
    }
    // A grid of lateral starts (the centroid start among them), its points symmetric about zero
    // so that the mirror of each is one too. The grid is over the offset when it is fitted (with
    // shift fitted too, each offset's shift start keeps the image where the centroid says:
    // c - offset x magnification / sensor pitch), else over the shift. Each start's loss is kept:
    // the refinement below runs short fits from the lowest ones.
    const std::size_t lat = dx < np ? dx : sx;
    const bool grid = lat < np && opt.lateral_starts != 1;
    if (grid) {
      const double mag = cfg.scene_at_infinity ? 1.0 : 1.0 + cfg.sensor_distance_m / cfg.scene_distance_m;
      const double unit = lat == sx ? 1.0 : cfg.sensor_pitch_m / mag;  // sensor px -> the parameter's unit
      const double c_max = std::max(std::fabs(c.first), std::fabs(c.second));
      // The loss at a lateral start (ox, oy) in sensor px, each start recorded.
      const auto try_start = [&](std::vector<double> trial, double ox, double oy) {
        trial[lat] = ox * unit;
        trial[lat + 1] = oy * unit;
        if (lat == dx && sx < np) {
          trial[sx] = c.first - ox;
          trial[sx + 1] = c.second - oy;
        }
        double l = std::numeric_limits<double>::infinity();
        try {
          if (lat == dx && sx < np) {
            // The registration too: the model at zero shift once, then every whole-pixel shift
            // within +-3 px of the centroid's on the host (a whole-pixel shift is exact).
            trial[sx] = trial[sx + 1] = 0;
            const RealStack p0 = model.evaluate(trial);
            const long cx = std::lround(c.first - ox), cy = std::lround(c.second - oy);
            for (long jy = cy - 3; jy <= cy + 3; ++jy)
              for (long jx = cx - 3; jx <= cx + 3; ++jx) {
                const std::vector<double> sh = shift_bilinear(p0.data, p0.planes, p0.rows, p0.cols, double(jx), double(jy));
                double ls = 0;
                for (std::size_t i = 0; i < sh.size(); ++i) ls += (sh[i] - measured.data[i]) * (sh[i] - measured.data[i]);
                ls *= 0.5;
                if (ls < l) {
                  l = ls;
                  trial[sx] = double(jx);
                  trial[sx + 1] = double(jy);
                }
              }
          } else {
            l = model.loss(trial, measured);
          }
        } catch (const InputError&) {
        }
        if (std::isfinite(l)) starts.push_back({l, trial});
        return std::make_pair(l, trial);
      };
      double best = model.loss(theta, measured);
      starts.push_back({best, theta});
      const auto keep = [&](const std::pair<double, std::vector<double>>& r) {
        if (r.first < best) {
          best = r.first;
          theta = r.second;
        }
      };
      std::string how;
      if (opt.lateral_starts > 1 || lat == sx) {
        // A K x K grid (automatic for the shift alone: half a sensor px apart over the centroid's
        // reach plus 1 px, at most 15 a side).
        std::vector<double> axis;
        if (opt.lateral_starts > 1) {
          const double span = sx < np && dx < np ? 0.5 * opt.lateral_span_px : c_max + opt.lateral_span_px;
          const int k = opt.lateral_starts;
          for (int i = 0; i < k; ++i) axis.push_back(-span + 2 * span * i / (k - 1));
        } else {
          const int half = std::min(7, int(std::ceil(2 * (c_max + 1.0) - 1e-9)));
          for (int i = -half; i <= half; ++i) axis.push_back(0.5 * i);
        }
        const std::vector<double> base = theta;
        for (double oy : axis)
          for (double ox : axis) keep(try_start(base, ox, oy));
        how = std::to_string(axis.size() * axis.size()) + " lateral starts of " + names[lat] + ", " + names[lat + 1] + " on a grid within +-" +
              fmt("%.3g", axis.back()) + " sensor px";
      } else {
        // Automatic for the offset: scans of dx (dy held), then of dy (dx held), twice, an eighth
        // of a DOE pixel apart. The blur a sub-pixel offset adds to the sampled relief changes
        // with the offset's fraction of a DOE pixel, so the loss has minima about a quarter of a
        // DOE pixel wide, one per fraction, and the image shift (odd in the offset) picks one;
        // the blur is separable in x and y, so scans along each axis find the lowest. Over the
        // centroid's reach plus 1.5 DOE px (with shift fitted too: +-2 DOE px), at most 64 steps a side.
        const double doe_px = cfg.pitch_m / unit;  // one DOE pixel in sensor px
        const double step = doe_px / 8;
        const double span = sx < np ? 2.0 * doe_px : c_max + 1.5 * doe_px;
        const int half = std::min(64, int(std::ceil(span / step - 1e-9)));
        int evaluated = 0;
        for (int round = 0; round < 2; ++round)
          for (std::size_t axis = 0; axis < 2; ++axis) {
            const std::vector<double> base = theta;
            for (int i = -half; i <= half; ++i) {
              double o[2] = {base[lat] / unit, base[lat + 1] / unit};
              o[axis] = step * i;
              keep(try_start(base, o[0], o[1]));
              ++evaluated;
            }
          }
        how = std::to_string(evaluated) + " lateral starts of " + names[lat] + ", " + names[lat + 1] + " by scans of each within +-" +
              fmt("%.3g", step * half) + " sensor px, " + fmt("%.3g", step) + " apart";
      }
      // The mirrors of the lowest (the blur is even in the offset), recorded for the refinement below.
      {
        const std::vector<double> b0 = theta;
        const double bx = b0[lat] / unit, by = b0[lat + 1] / unit;
        for (const auto& [mx, my] : {std::make_pair(-1.0, 1.0), std::make_pair(1.0, -1.0), std::make_pair(-1.0, -1.0)})
          if ((mx < 0 && bx != 0) || (my < 0 && by != 0)) try_start(b0, mx * bx, my * by);
      }
      say("fit: " + how + ": the lowest loss " + fmt("%.6e", best) + " at " + names[lat] + " = " + fmt("%.4g", theta[lat]) + ", " +
          names[lat + 1] + " = " + fmt("%.4g", theta[lat + 1]));
      // Starts closer than this share a basin: a quarter of a DOE pixel for the offset, a sensor px for the shift.
      lateral_min_sep = lat == sx ? 1.0 : 0.25 * cfg.pitch_m;
    }
    lateral_index = grid ? lat : np;
  }
  double loss = model.loss(theta, measured), lambda = opt.lambda0;
  res.loss_initial = loss;
  res.loss_history.push_back(loss);
  for (std::size_t l : model.unused_levels())
    say("fit: level " + std::to_string(l) + " is used by no DOE pixel: held at its design value (the PSF does not depend on it)");
  res.unused_levels = model.unused_levels();
  say("fit: " + std::to_string(np) + " parameters, " + std::to_string(m) + " residuals; design loss " + fmt("%.6e", loss) +
      values_line(model, theta));
  const auto distance = [&](std::size_t k) { return !model.adjoint_parameter(k); };
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
      const Eigen::MatrixXd j = model.jacobian(th);
      const auto ts = std::chrono::steady_clock::now();
      const Eigen::VectorXd r = Eigen::Map<const Eigen::VectorXd>(current.data.data(), long(m)) - meas;
      Eigen::VectorXd g = Eigen::VectorXd::Zero(long(np));
      for (std::size_t k = 0; k < np; ++k) g(long(k)) = distance(k) ? j.col(long(k)).dot(r) : grad[k];
      const Eigen::MatrixXd a = j.transpose() * j;
      t.solve_s += since(ts);
      bool accepted = false;
      double trial_loss = l;
      std::vector<double> trial;
      for (int tries = 0; tries < 16 && !accepted; ++tries) {
        const auto t1 = std::chrono::steady_clock::now();
        Eigen::MatrixXd al = a;
        const double dmax = a.diagonal().maxCoeff();
        for (long k = 0; k < long(np); ++k) al(k, k) += lam * std::max(a(k, k), 1e-12 * dmax);
        const Eigen::VectorXd delta = al.ldlt().solve(-g);
        t.solve_s += since(t1);
        trial = th;
        for (std::size_t k = 0; k < np; ++k) trial[k] += delta(long(k));
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
        const Eigen::MatrixXd cov = a.completeOrthogonalDecomposition().pseudoInverse() * (2 * l / double(m - np));
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
    aperture.sigma = curv > 0 ? std::sqrt(2 * loss / double(m - np) / curv) : std::numeric_limits<double>::infinity();
    t.scan_s += since(t1);
    if (r == r0) return false;
    say("fit: aperture radius " + fmt("%.3f", r / cfg.pitch_m) + " px; the other parameters fitted (again) with it");
    return true;
  };
  if (scan_aperture) walk();  // first at the start values: a wrong aperture pulls the levels far
  refine_starts();
  if (!res.converged) run_lm(opt.max_iterations - res.iterations);  // what the refinement left of the budget
  for (int round = 0; scan_aperture && round < 3 && walk(); ++round) {
    lambda = opt.lambda0;
    res.converged = false;
    run_lm(opt.max_iterations);
  }
  // Uncertainties at the fit: Cov = s^2 (J^T J)^-1, in the unit-diagonal scaling.
  const Eigen::MatrixXd j = model.jacobian(theta);
  const auto t2 = std::chrono::steady_clock::now();
  const Eigen::MatrixXd a = j.transpose() * j;
  Eigen::VectorXd dinv = Eigen::VectorXd::Zero(long(np));
  for (long k = 0; k < long(np); ++k) dinv(k) = a(k, k) > 0 ? 1 / std::sqrt(a(k, k)) : 0;
  const Eigen::MatrixXd as = dinv.asDiagonal() * a * dinv.asDiagonal();
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(as);
  const Eigen::VectorXd ev = es.eigenvalues();
  const double evmax = ev.maxCoeff(), evmin = ev.minCoeff();
  res.condition = evmin > 0 ? evmax / evmin : std::numeric_limits<double>::infinity();
  Eigen::VectorXd evinv = Eigen::VectorXd::Zero(long(np));
  for (long k = 0; k < long(np); ++k) evinv(k) = ev(k) > 1e-15 * evmax ? 1 / ev(k) : 0;
  const Eigen::MatrixXd as_inv = es.eigenvectors() * evinv.asDiagonal() * es.eigenvectors().transpose();
  const double s2 = 2 * loss / double(m - np);
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
  t.solve_s += since(t2);
  if (scan_aperture) res.values.push_back(aperture);
  res.model_psf = model.evaluate(theta);
  res.loss_final = 0.5 * (Eigen::Map<const Eigen::VectorXd>(res.model_psf.data.data(), long(m)) - meas).squaredNorm();
  res.residual_rel_fit = band_residuals(res.model_psf, measured);
  res.as_built.height_m = model.heights(theta);
  res.as_built.pitch_m = design.pitch_m;
  res.as_built.levels_m = model.levels(theta);
  res.as_built_config = model.config(theta);
  if (scan_aperture) res.as_built_config.aperture_radius_m = aperture.value;
  res.times = t;
  return res;
}


}  // namespace qdo
