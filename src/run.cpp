#include "qdo/run.hpp"

#include <algorithm>
#include <cmath>

#include "qdo/error.hpp"
#include "qdo/io.hpp"

namespace qdo {

void save_checkpoint(const std::string& path, const DesignState& s) {
  auto vec = [](const std::string& name, const std::vector<double>& v) {
    return H5Dataset{name, {v.size()}, v.empty() ? std::vector<double>{} : v, {}, {}};
  };
  std::vector<H5Dataset> ds = {vec("/w", s.w), vec("/offsets", s.offsets), vec("/adam_w_m", s.adam_w.m),
                               vec("/adam_w_v", s.adam_w.v), vec("/adam_a_m", s.adam_a.m), vec("/adam_a_v", s.adam_a.v)};
  ds.push_back({"/counters", {3}, {double(s.step), double(s.adam_w.t), double(s.adam_a.t)}, {}, {{"names", "step, adam_w.t, adam_a.t"}}});
  h5_write(path, ds, {{"format", "qdo checkpoint 1"}});
}

DesignState load_checkpoint(const std::string& path, std::size_t expected_w, std::size_t expected_levels) {
  auto read = [&](const std::string& name, std::size_t expected, bool allow_empty) {
    const H5Dataset d = h5_read(path, name, 1u << 28);
    const std::size_t n = d.data.size();
    if (!(n == expected || (allow_empty && n == 0)))
      throw InputError("file '" + path + "': dataset '" + name + "' has " + to_str(n) + " values, expected " + to_str(expected) +
                       " (is this checkpoint from another configuration?)");
    for (double v : d.data)
      if (!std::isfinite(v)) throw InputError("file '" + path + "': dataset '" + name + "' holds non-finite values");
    return d.data;
  };
  DesignState s;
  s.w = read("/w", expected_w, false);
  s.offsets = read("/offsets", expected_levels, false);
  s.adam_w.m = read("/adam_w_m", expected_w, true);
  s.adam_w.v = read("/adam_w_v", expected_w, true);
  s.adam_a.m = read("/adam_a_m", expected_levels, true);
  s.adam_a.v = read("/adam_a_v", expected_levels, true);
  const auto c = read("/counters", 3, false);
  for (double v : c)
    if (v < 0 || v != std::floor(v)) throw InputError("file '" + path + "': dataset '/counters' holds " + to_str(v) + ", not a count");
  s.step = long(c[0]);
  s.adam_w.t = long(c[1]);
  s.adam_a.t = long(c[2]);
  for (double w : s.w)
    if (w < -1 || w > 1) throw InputError("file '" + path + "': dataset '/w' holds " + to_str(w) + " outside [-1, 1]");
  return s;
}

void write_line_plot_png(const std::string& path, const std::vector<std::vector<double>>& series, std::size_t width,
                         std::size_t height) {
  std::vector<unsigned char> px(width * height * 3, 255);
  double lo = INFINITY, hi = -INFINITY;
  std::size_t len = 1;
  bool positive = true;
  for (const auto& s : series)
    for (double v : s) {
      if (!std::isfinite(v)) continue;
      lo = std::min(lo, v);
      hi = std::max(hi, v);
      positive = positive && v > 0;
    }
  for (const auto& s : series) len = std::max(len, s.size());
  if (!(hi >= lo)) {
    lo = 0;
    hi = 1;
  }
  auto ty = [&](double v) { return positive ? std::log10(v) : v; };
  double a = ty(lo), b = ty(hi);
  if (b - a < 1e-12) {
    a -= 0.5;
    b += 0.5;
  }
  const std::size_t m = 30;  // margin
  auto put = [&](long x, long y, const unsigned char* c) {
    if (x < 0 || y < 0 || x >= long(width) || y >= long(height)) return;
    std::copy(c, c + 3, px.begin() + long((std::size_t(y) * width + std::size_t(x)) * 3));
  };
  const unsigned char axis[3] = {0, 0, 0};
  for (std::size_t x = m; x < width - m / 2; ++x) put(long(x), long(height - m), axis);
  for (std::size_t y = m / 2; y <= height - m; ++y) put(long(m), long(y), axis);
  // Series colours in order: blue, red, green, orange, purple, brown (matplotlib's tab10).
  const unsigned char colors[6][3] = {{31, 119, 180}, {214, 39, 40}, {44, 160, 44}, {255, 127, 14}, {148, 103, 189}, {140, 86, 75}};
  for (std::size_t k = 0; k < series.size(); ++k) {
    long px_prev = -1, py_prev = -1;
    for (std::size_t i = 0; i < series[k].size(); ++i) {
      const double v = series[k][i];
      if (!std::isfinite(v) || (positive && v <= 0)) continue;
      const double fm = double(m), fw = double(width), fh = double(height);
      const long x = long(fm + (fw - 1.5 * fm) * (len > 1 ? double(i) / double(len - 1) : 0.5));
      const long y = long(fh - fm - (fh - 1.5 * fm) * (ty(v) - a) / (b - a));
      if (px_prev >= 0) {
        const long steps = std::max(std::labs(x - px_prev), std::labs(y - py_prev)) + 1;
        for (long t = 0; t <= steps; ++t)
          put(px_prev + (x - px_prev) * t / steps, py_prev + (y - py_prev) * t / steps, colors[k % 6]);
      }
      px_prev = x;
      py_prev = y;
    }
  }
  write_png(path, width, height, 3, px);
}

}  // namespace qdo
