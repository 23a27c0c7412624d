// The as-built fit's start (fit_internal.hpp: find_lateral_starts): the centroid difference, the
// given start values, and the lateral grid or scans whose starts the fit refines (fit.cpp).
#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

#include "qdo/runtime/error.hpp"
#include "qdo/asbuilt/fit.hpp"
#include "qdo/physics/simulator.hpp"

#include "fit_internal.hpp"

namespace qdo::fit_detail {

namespace {

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

}  // namespace

LateralStarts find_lateral_starts(AsBuiltModel& model, const SystemConfig& cfg, const RealStack& measured, const RealStack& design_psf,
                                  const FitOptions& opt, std::vector<double>& theta, const std::function<void(const std::string&)>& say) {
  LateralStarts out;
  const std::size_t np = model.parameter_names().size();
  out.lateral_index = np;
  const auto& names = model.parameter_names();
  const auto find = [&](const char* n) { return std::size_t(std::find(names.begin(), names.end(), n) - names.begin()); };
  const auto c = centroid_difference_px(measured, design_psf);
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
    out.centroid_shift_px = {c.first, c.second};
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
          // With an observation the PSF stack is shifted, then observed (the observation is
          // per sensor pixel: it does not commute with the shift).
          trial[sx] = trial[sx + 1] = 0;
          const RealStack p0 = model.observed() ? model.evaluate_psf(trial) : model.evaluate(trial);
          const long cx = std::lround(c.first - ox), cy = std::lround(c.second - oy);
          for (long jy = cy - 3; jy <= cy + 3; ++jy)
            for (long jx = cx - 3; jx <= cx + 3; ++jx) {
              std::vector<double> sh = shift_bilinear(p0.data, p0.planes, p0.rows, p0.cols, double(jx), double(jy));
              if (model.observed()) {
                RealStack moved(p0.planes, p0.rows, p0.cols);
                moved.data = std::move(sh);
                sh = model.observe(moved).data;
              }
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
      if (std::isfinite(l)) out.starts.push_back({l, trial});
      return std::make_pair(l, trial);
    };
    double best = model.loss(theta, measured);
    out.starts.push_back({best, theta});
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
      // Automatic for the offset: scans of dx (dy held), then of dy (dx held), twice, a quarter
      // of a DOE pixel apart, a safeguard against starting a basin away. (The bilinear blend of
      // heights qdo once moved reliefs with had a narrow minimum per fraction of a pixel and took
      // an eighth; the exact move has no such blur, and from the centroid alone the fit found the
      // truth on a trained DOE's speckled PSF, suite fit.) Over the centroid's reach plus 1.5 DOE
      // px (with shift fitted too: +-2 DOE px), at most 64 steps a side.
      const double doe_px = cfg.pitch_m / unit;  // one DOE pixel in sensor px
      const double step = doe_px / 4;
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
    out.min_separation = lat == sx ? 1.0 : 0.25 * cfg.pitch_m;
  }
  out.lateral_index = grid ? lat : np;
  return out;
}

}  // namespace qdo::fit_detail
