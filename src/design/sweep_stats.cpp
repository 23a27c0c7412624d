#include "qdo/sweep_stats.hpp"

#include <algorithm>
#include <cstdio>
#include <string>
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

namespace {
std::string xml_escape(const std::string& t) {
  std::string o;
  for (char c : t) {
    if (c == '&') o += "&amp;";
    else if (c == '<') o += "&lt;";
    else if (c == '>') o += "&gt;";
    else if (c == '"') o += "&quot;";
    else o += c;
  }
  return o;
}
std::string num(double v, int digits) {
  char b[32];
  std::snprintf(b, sizeof b, "%.*f", digits, v);
  return b;
}
}  // namespace

void write_difference_plot_svg(const std::string& path, const std::vector<PairedDifference>& diffs) {
  // Row labels: "L4  qdo+a − do  @spec  (9 pairs, 3 seeds)", a decoder spec both sides share written once.
  std::vector<std::string> labels;
  std::size_t longest = 0;
  for (const auto& d : diffs) {
    const auto at_a = d.a.find('@'), at_b = d.b.find('@');
    const std::string spec_a = at_a == std::string::npos ? "" : d.a.substr(at_a), spec_b = at_b == std::string::npos ? "" : d.b.substr(at_b);
    const bool shared = spec_a == spec_b;
    const std::string a = shared ? d.a.substr(0, at_a) : d.a, b = shared ? d.b.substr(0, at_b) : d.b;
    labels.push_back((d.levels == 0 ? std::string("full") : "L" + std::to_string(d.levels)) + "  " + a + " − " + b + "  " +
                     (shared && !spec_a.empty() ? spec_a + "  " : "") + "(" + std::to_string(d.psnr_db.n) + " pairs, " +
                     std::to_string(d.seeds) + " seeds)");
    longest = std::max(longest, labels.back().size());
  }
  const double label_w = std::max(160.0, 6.8 * double(longest) + 16), plot_w = 420, row_h = 26, top = 30, bottom = 50;
  const double width = label_w + plot_w + 30, height = top + bottom + row_h * double(std::max<std::size_t>(diffs.size(), 1));
  double lo = 0, hi = 0;
  for (const auto& d : diffs)
    for (double v : {d.psnr_db.lo(), d.psnr_db.hi(), d.psnr_db_seeds.lo(), d.psnr_db_seeds.hi(), d.psnr_db.mean})
      if (std::isfinite(v)) {
        lo = std::min(lo, v);
        hi = std::max(hi, v);
      }
  // Ticks every 1, 2, 5 x 10^k dB, about 6 of them.
  double span = std::max(hi - lo, 1e-6), step = std::pow(10.0, std::floor(std::log10(span / 6)));
  for (double m : {1.0, 2.0, 5.0, 10.0})
    if (span / (step * m) <= 7) {
      step *= m;
      break;
    }
  lo = std::floor(lo / step) * step;
  hi = std::ceil(hi / step) * step;
  if (hi - lo < step) hi = lo + step;
  auto x_of = [&](double v) { return label_w + plot_w * (v - lo) / (hi - lo); };
  std::string svg = "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" + num(width, 0) + "\" height=\"" + num(height, 0) +
                    "\" font-family=\"sans-serif\" font-size=\"12\">\n<rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n";
  svg += "<text x=\"6\" y=\"18\">ΔPSNR paired by seed and test scene. Dot: mean; thick: 95 % interval over the pairs; thin: over seeds</text>\n";
  const double y_axis = top + row_h * double(diffs.size()) + 6;
  svg += "<line x1=\"" + num(label_w, 1) + "\" y1=\"" + num(y_axis, 1) + "\" x2=\"" + num(label_w + plot_w, 1) + "\" y2=\"" + num(y_axis, 1) +
         "\" stroke=\"black\"/>\n";
  const int digits = step >= 1 ? 0 : step >= 0.1 ? 1 : 2;
  for (double t = lo; t <= hi + step * 1e-9; t += step) {
    const double x = x_of(t);
    svg += "<line x1=\"" + num(x, 1) + "\" y1=\"" + num(top - 4, 1) + "\" x2=\"" + num(x, 1) + "\" y2=\"" + num(y_axis + 4, 1) + "\" stroke=\"" +
           (std::fabs(t) < step * 1e-6 ? "#666" : "#ddd") + "\"/>\n";
    svg += "<text x=\"" + num(x, 1) + "\" y=\"" + num(y_axis + 18, 1) + "\" text-anchor=\"middle\">" + num(std::fabs(t) < step * 1e-6 ? 0.0 : t, digits) +
           "</text>\n";
  }
  svg += "<text x=\"" + num(label_w + plot_w / 2, 1) + "\" y=\"" + num(y_axis + 36, 1) + "\" text-anchor=\"middle\">ΔPSNR [dB]</text>\n";
  for (std::size_t k = 0; k < diffs.size(); ++k) {
    const auto& d = diffs[k];
    const double y = top + row_h * double(k) + row_h / 2;
    const std::string color = d.psnr_db.lo() > 0 ? "#1f77b4" : d.psnr_db.hi() < 0 ? "#d62728" : "black";
    svg += "<text x=\"6\" y=\"" + num(y + 4, 1) + "\">" + xml_escape(labels[k]) + "</text>\n";
    if (std::isfinite(d.psnr_db_seeds.half_width))
      svg += "<line x1=\"" + num(x_of(d.psnr_db_seeds.lo()), 1) + "\" y1=\"" + num(y, 1) + "\" x2=\"" + num(x_of(d.psnr_db_seeds.hi()), 1) +
             "\" y2=\"" + num(y, 1) + "\" stroke=\"#999\" stroke-width=\"1.5\"/>\n";
    if (std::isfinite(d.psnr_db.half_width))
      svg += "<line x1=\"" + num(x_of(d.psnr_db.lo()), 1) + "\" y1=\"" + num(y, 1) + "\" x2=\"" + num(x_of(d.psnr_db.hi()), 1) + "\" y2=\"" +
             num(y, 1) + "\" stroke=\"" + color + "\" stroke-width=\"5\"/>\n";
    svg += "<circle cx=\"" + num(x_of(d.psnr_db.mean), 1) + "\" cy=\"" + num(y, 1) + "\" r=\"5\" fill=\"" + color + "\"/>\n";
    svg += "<text x=\"" + num(label_w + plot_w + 4, 1) + "\" y=\"" + num(y + 4, 1) + "\" font-size=\"10\">" + num(d.psnr_db.mean, 2) + "</text>\n";
  }
  svg += "</svg>\n";
  write_text_atomic(path, svg);
}

}  // namespace qdo
