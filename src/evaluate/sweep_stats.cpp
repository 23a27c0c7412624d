#include "qdo/evaluate/sweep_stats.hpp"

#include <algorithm>
#include <cstdio>
#include <string>
#include <cmath>
#include <limits>
#include <map>
#include <tuple>

#include "qdo/runtime/error.hpp"
#include "qdo/data/figure.hpp"
#include "qdo/data/io.hpp"

namespace qdo {

double student_t_975(std::size_t dof) {
  if (dof < 1) reject("degrees of freedom", dof, "at least 1");
  // t_{0.975, dof}, dof = 1..30 (standard tables, e.g. NIST/SEMATECH e-Handbook 1.3.6.7.2).
  static const double t[30] = {12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228,
                               2.201,  2.179, 2.160, 2.145, 2.131, 2.120, 2.110, 2.101, 2.093, 2.086,
                               2.080,  2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048, 2.045, 2.042};
  if (dof <= 30) return t[dof - 1];
  // Beyond 30: linear in 1/dof between 30, 40, 60, 120 and infinity (1/dof = 0).
  static const double knots_dof[4] = {30, 40, 60, 120};
  static const double knots_t[5] = {2.042, 2.021, 2.000, 1.980, 1.95996};
  const double x = 1.0 / double(dof);
  for (int k = 0; k < 4; ++k) {
    const double x0 = 1.0 / knots_dof[k], x1 = k + 1 < 4 ? 1.0 / knots_dof[k + 1] : 0.0;
    if (x <= x0 && x >= x1) return knots_t[k] + (knots_t[k + 1] - knots_t[k]) * (x0 - x) / (x0 - x1);
  }
  return 1.95996;
}

MeanInterval mean_interval(const std::vector<double>& v) {
  MeanInterval m;
  m.n = v.size();
  const double nan = std::numeric_limits<double>::quiet_NaN();
  if (v.empty()) {
    m.mean = m.sd = m.half_width = nan;
    return m;
  }
  double s = 0;
  for (double x : v) s += x;
  m.mean = s / double(v.size());
  if (v.size() < 2) {
    m.sd = m.half_width = nan;
    return m;
  }
  double ss = 0;
  for (double x : v) ss += (x - m.mean) * (x - m.mean);
  m.sd = std::sqrt(ss / double(v.size() - 1));
  m.half_width = student_t_975(v.size() - 1) * m.sd / std::sqrt(double(v.size()));
  return m;
}

std::vector<PairedDifference> paired_differences(const std::vector<SceneScore>& scores,
                                                 const std::vector<std::pair<std::string, std::string>>& comparisons) {
  // (mode, levels, seed, scene) -> score
  std::map<std::tuple<std::string, int, std::uint64_t, std::string>, const SceneScore*> at;
  std::vector<int> levels;
  std::vector<std::uint64_t> seeds;
  for (const auto& s : scores) {
    at[{s.mode, s.levels, s.seed, s.scene}] = &s;
    if (std::find(levels.begin(), levels.end(), s.levels) == levels.end()) levels.push_back(s.levels);
    if (std::find(seeds.begin(), seeds.end(), s.seed) == seeds.end()) seeds.push_back(s.seed);
  }
  std::sort(seeds.begin(), seeds.end());
  std::vector<PairedDifference> out;
  for (const auto& [a, b] : comparisons)
    for (int L : levels) {
      std::vector<double> dpsnr, dssim, per_seed;
      std::size_t n_seeds = 0;
      for (std::uint64_t seed : seeds) {
        std::vector<double> d_seed;
        for (const auto& s : scores) {
          if (s.mode != a || s.levels != L || s.seed != seed) continue;
          const auto it = at.find({b, L, seed, s.scene});
          if (it == at.end()) continue;
          dpsnr.push_back(s.psnr_db - it->second->psnr_db);
          dssim.push_back(s.ssim - it->second->ssim);
          d_seed.push_back(dpsnr.back());
        }
        if (!d_seed.empty()) {
          ++n_seeds;
          per_seed.push_back(mean_interval(d_seed).mean);
        }
      }
      if (dpsnr.empty()) continue;
      PairedDifference d;
      d.a = a;
      d.b = b;
      d.levels = L;
      d.seeds = n_seeds;
      d.psnr_db = mean_interval(dpsnr);
      d.ssim = mean_interval(dssim);
      d.psnr_db_seeds = mean_interval(per_seed);
      out.push_back(d);
    }
  return out;
}

// Row labels: "L4  qdo+a − do  @spec  (9 pairs, 3 seeds)", a decoder spec both sides share written once.
std::string difference_label(const PairedDifference& d) {
  const auto at_a = d.a.find('@'), at_b = d.b.find('@');
  const std::string spec_a = at_a == std::string::npos ? "" : d.a.substr(at_a), spec_b = at_b == std::string::npos ? "" : d.b.substr(at_b);
  const bool shared = spec_a == spec_b;
  const std::string a = shared ? d.a.substr(0, at_a) : d.a, b = shared ? d.b.substr(0, at_b) : d.b;
  return (d.levels == 0 ? std::string("full") : "L" + std::to_string(d.levels)) + "  " + a + " − " + b + "  " +
         (shared && !spec_a.empty() ? spec_a + "  " : "") + "(" + std::to_string(d.psnr_db.n) + " pairs, " + std::to_string(d.seeds) +
         " seeds)";
}

void write_difference_figure(const std::string& png_path, const std::vector<PairedDifference>& diffs) {
  if (diffs.empty()) reject("diffs", "(none)", "at least one paired difference");
  LinePlot lp;
  lp.title = "ΔPSNR paired by seed and test scene, mean and 95 % intervals";
  lp.x_label = "comparison (legend order)";
  lp.y_label = "ΔPSNR a − b (dB)";
  lp.hlines.push_back(0.0);
  PlotSeries seeds{"over seeds (each seed's mean difference)", {}, {}, {}, {}, true};
  for (std::size_t k = 0; k < diffs.size(); ++k) {
    const PairedDifference& d = diffs[k];
    const double x = double(k + 1);
    lp.series.push_back(PlotSeries{difference_label(d) + ", over pairs", {x}, {d.psnr_db.mean}, {d.psnr_db.lo()}, {d.psnr_db.hi()}, true});
    if (d.psnr_db_seeds.n > 1) {
      seeds.x.push_back(x + 0.25);
      seeds.y.push_back(d.psnr_db_seeds.mean);
      seeds.y_low.push_back(d.psnr_db_seeds.lo());
      seeds.y_high.push_back(d.psnr_db_seeds.hi());
    }
  }
  if (!seeds.x.empty()) lp.series.push_back(seeds);
  write_line_plot(png_path, lp);
}

}  // namespace qdo
