#include "qdo/sweep_stats.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <tuple>

#include "qdo/error.hpp"
#include "qdo/io.hpp"

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

void write_difference_plot_png(const std::string& path, const std::vector<PairedDifference>& diffs, std::size_t width,
                               std::size_t height) {
  const std::size_t row_px = 28, margin = 20;
  if (height == 0) height = std::max<std::size_t>(80, 2 * margin + row_px * std::max<std::size_t>(diffs.size(), 1));
  std::vector<unsigned char> px(width * height * 3, 255);
  double lo = 0, hi = 0;  // 0 dB always on the axis
  for (const auto& d : diffs)
    for (double v : {d.psnr_db.lo(), d.psnr_db.hi(), d.psnr_db_seeds.lo(), d.psnr_db_seeds.hi(), d.psnr_db.mean})
      if (std::isfinite(v)) {
        lo = std::min(lo, v);
        hi = std::max(hi, v);
      }
  if (hi - lo < 1e-9) hi = lo + 1;
  const double pad = 0.05 * (hi - lo);
  lo -= pad;
  hi += pad;
  auto x_of = [&](double v) { return long(double(margin) + (double(width) - 2.0 * double(margin)) * (v - lo) / (hi - lo)); };
  auto put = [&](long x, long y, const unsigned char* c) {
    if (x < 0 || y < 0 || x >= long(width) || y >= long(height)) return;
    std::copy(c, c + 3, px.begin() + long((std::size_t(y) * width + std::size_t(x)) * 3));
  };
  const unsigned char grey[3] = {160, 160, 160}, blue[3] = {31, 119, 180}, red[3] = {214, 39, 40}, black[3] = {0, 0, 0};
  for (long y = long(margin / 2); y < long(height - margin / 2); ++y) put(x_of(0), y, grey);
  for (std::size_t k = 0; k < diffs.size(); ++k) {
    const auto& d = diffs[k];
    const long y = long(margin + row_px * k + row_px / 2);
    const unsigned char* c = d.psnr_db.lo() > 0 ? blue : d.psnr_db.hi() < 0 ? red : black;
    if (std::isfinite(d.psnr_db_seeds.half_width))
      for (long x = x_of(d.psnr_db_seeds.lo()); x <= x_of(d.psnr_db_seeds.hi()); ++x) put(x, y, grey);
    if (std::isfinite(d.psnr_db.half_width))
      for (long x = x_of(d.psnr_db.lo()); x <= x_of(d.psnr_db.hi()); ++x)
        for (long t = -2; t <= 2; ++t) put(x, y + t, c);
    const long xm = x_of(d.psnr_db.mean);
    for (long dy = -5; dy <= 5; ++dy)
      for (long dx = -5; dx <= 5; ++dx)
        if (dx * dx + dy * dy <= 25) put(xm + dx, y + dy, c);
  }
  write_png(path, width, height, 3, px);
}

}  // namespace qdo
