// Layout of the figure module's figures: axis ranges, tick spacing and labels, the line plots'
// window and legend, and for images the block means, colour scale and colour bar.
#include <plplot.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <utility>
#include <vector>

#include "data/figure_internal.hpp"
#include "qdo/data/figure.hpp"

namespace qdo::figure_detail {

// ---------------------------------------------------------------------------------------
// Ranges, ticks and labels
// ---------------------------------------------------------------------------------------

namespace {

// The decade of v > 0: floor(log10 v), robust to log10 landing just below an integer.
int decade(double v) { return static_cast<int>(std::floor(std::log10(v) + 1e-9)); }

// The label of the tick at v, as PLplot text (an exponent as "#u...#d").
std::string tick_label(double v, const TickFormat& f) {
  if (!std::isfinite(v) || std::fabs(v) < 1e-6 * f.step) return "0";
  std::array<char, 64> buf{};
  if (!f.sci) {
    std::snprintf(buf.data(), buf.size(), "%.*f", f.decimals, v);
    return buf.data();
  }
  int e = decade(std::fabs(v));
  int decimals = std::clamp(e - decade(f.step), 0, 4);
  std::snprintf(buf.data(), buf.size(), "%.*f", decimals, v / std::pow(10.0, e));
  if (std::fabs(std::strtod(buf.data(), nullptr)) >= 10) {  // rounded up to the next decade
    ++e;
    decimals = std::max(0, decimals - 1);
    std::snprintf(buf.data(), buf.size(), "%.*f", decimals, v / std::pow(10.0, e));
  }
  return std::string(buf.data()) + "×10#u" + std::to_string(e) + "#d";
}

// PLplot's custom label function: data points to the AxisLabels of the axes being drawn.
struct AxisLabels {
  TickFormat x, y;
};
void write_tick_label(PLINT axis, PLFLT value, char* label, PLINT length, PLPointer data) {
  const auto* labels = static_cast<const AxisLabels*>(data);
  const std::string text = tick_label(value, axis == PL_X_AXIS ? labels->x : labels->y);
  if (length > 0) std::snprintf(label, static_cast<std::size_t>(length), "%s", text.c_str());
}

// The ticks of a linear axis: the multiples of step within w.
std::vector<double> ticks(const Range& w, double step) {
  std::vector<double> t;
  const double first = std::ceil(w.lo / step - 1e-9), last = std::floor(w.hi / step + 1e-9);
  for (double k = first; k <= last && t.size() < 1000; k += 1) t.push_back(k * step);
  return t;
}

// Width of a tick label in digit widths ('.' and '-' narrower, the sign '×' wider, exponents
// smaller).
double label_width(const std::string& label) {
  double w = 0, size = 1;
  for (std::size_t i = 0; i < label.size(); ++i) {
    const unsigned char c = static_cast<unsigned char>(label[i]);
    if (c == '#' && i + 1 < label.size()) {
      size = label[i + 1] == 'u' ? 0.8 : 1.0;
      ++i;
    } else if ((c & 0xC0) == 0xC0) {
      w += size * 1.3;  // '×', the only non-ASCII glyph in tick labels
    } else if ((c & 0xC0) != 0x80) {
      w += size * (c == '.' ? 0.5 : c == '-' ? 0.6 : 1.0);
    }
  }
  return w;
}

}  // namespace

// An axis range with 5 % padding; a constant widened (half a decade on log axes), none [0, 1].
// A log axis spans whole decades (PLplot labels a log axis at its decades only, so a range inside
// one decade would carry no value at all).
Range padded(Range r, bool log_axis) {
  if (r.empty()) return {0, 1};
  if (log_axis) {
    const double lo = std::floor(r.lo + 1e-9), hi = std::ceil(r.hi - 1e-9);
    return {lo, hi > lo ? hi : lo + 1};
  }
  const double span = r.hi - r.lo;
  const double scale = std::max(std::fabs(r.lo), std::fabs(r.hi));
  if (span <= 1e-12 * scale || span == 0) {
    const double d = log_axis ? 0.5 : (scale > 0 ? 0.1 * scale : 1.0);
    return {r.lo - d, r.hi + d};
  }
  return {r.lo - 0.05 * span, r.hi + 0.05 * span};
}

// A value as plotted on an axis: log10 on a log axis (NaN for v <= 0), NaN when not drawable.
double axis_value(double v, bool log_axis) {
  if (!drawable(v)) return kNaN;
  if (log_axis) return v > 0 ? std::log10(v) : kNaN;
  return v;
}

// A tick interval of 1, 2 or 5 x 10^k giving about `target` intervals over `span`.
double nice_step(double span, double target) {
  if (!(span > 0) || !std::isfinite(span)) return 1;
  const double raw = span / target;
  const double mag = std::pow(10.0, std::floor(std::log10(raw)));
  const double r = raw / mag;
  return (r < 1.5 ? 1 : r < 3.5 ? 2 : r < 7.5 ? 5 : 10) * mag;
}

TickFormat tick_format(const Range& w, double step) {
  TickFormat f;
  f.step = step;
  const double m = std::max(std::fabs(w.lo), std::fabs(w.hi));
  f.sci = m >= 1e6 || decade(step) < -4;
  f.decimals = std::max(0, -decade(step));
  return f;
}

// plbox with custom labels on the linear axes (option "o").
void draw_axes(const std::string& xopt, const TickFormat& x, bool log_x, const std::string& yopt, const TickFormat& y,
               bool log_y) {
  AxisLabels labels{x, y};
  plslabelfunc(&write_tick_label, &labels);
  plbox((xopt + (log_x ? "l" : "o")).c_str(), log_x ? 0 : x.step, 0, (yopt + (log_y ? "l" : "o")).c_str(),
        log_y ? 0 : y.step, 0);
  plslabelfunc(nullptr, nullptr);
}

// Width, in character heights, of the widest tick label of a linear axis (log axes: "10" and a
// small exponent).
double tick_label_chars(const Range& w, const TickFormat& f, bool log_axis) {
  if (log_axis) return 3.5 * kDigitWidth;
  double widest = 1;
  for (double t : ticks(w, f.step)) widest = std::max(widest, label_width(tick_label(t, f)));
  return widest * kDigitWidth;
}

// Tick format for a linear axis of axis_px pixels with text at `scale`: about `target`
// intervals, fewer while the labels would not fit side by side (x) or one above the other (y).
TickFormat fit_ticks(const Range& w, double axis_px, double scale, double target, bool vertical) {
  TickFormat f;
  for (double t = target; t >= 1; t -= 1) {
    f = tick_format(w, nice_step(w.hi - w.lo, t));
    const double n = static_cast<double>(ticks(w, f.step).size());
    const double each = vertical ? 1.8 : tick_label_chars(w, f, false) + 1.5;
    if (n * each * scale * kCharPx <= axis_px) break;
  }
  return f;
}

// ---------------------------------------------------------------------------------------
// Line plots: window and legend
// ---------------------------------------------------------------------------------------

Points plotted(const PlotSeries& s, bool log_x, bool log_y) {
  Points p;
  const std::size_t n = s.x.size();
  p.x.resize(n);
  p.y.resize(n);
  for (std::size_t i = 0; i < n; ++i) {
    p.x[i] = axis_value(s.x[i], log_x);
    p.y[i] = axis_value(s.y[i], log_y);
  }
  if (!s.y_low.empty()) {
    p.lo.resize(n);
    p.hi.resize(n);
    for (std::size_t i = 0; i < n; ++i) {
      p.lo[i] = axis_value(s.y_low[i], log_y);
      p.hi[i] = axis_value(s.y_high[i], log_y);
    }
  }
  return p;
}

LineFrame line_frame(const LinePlot& plot) {
  Range xr, yr;
  for (const auto& s : plot.series) {
    const Points p = plotted(s, plot.log_x, plot.log_y);
    for (std::size_t i = 0; i < p.x.size(); ++i) {
      if (!std::isfinite(p.x[i])) continue;
      if (std::isfinite(p.y[i])) {
        xr.add(p.x[i]);
        yr.add(p.y[i]);
      }
      if (!p.lo.empty() && std::isfinite(p.lo[i]) && std::isfinite(p.hi[i])) {
        xr.add(p.x[i]);
        yr.add(p.lo[i]);
        yr.add(p.hi[i]);
      }
    }
  }
  LineFrame f;
  f.nothing = xr.empty();
  if (!f.nothing)
    for (double v : plot.hlines) yr.add(axis_value(v, plot.log_y));
  f.xw = padded(xr, plot.log_x);
  f.yw = padded(yr, plot.log_y);
  f.x_ticks = fit_ticks(f.xw, 450, 1.0, 6, false);
  f.y_ticks = fit_ticks(f.yw, 300, 1.0, 5, true);
  f.y_chars = tick_label_chars(f.yw, f.y_ticks, plot.log_y);
  return f;
}

// The legend, its top left corner at (x, 1) in viewport coordinates; returns its width in
// viewport widths.
double draw_legend(const LinePlot& plot, double x, double plot_width) {
  const std::size_t n = plot.series.size();
  std::vector<PLINT> opts(n), text_colours(n, kInk), colours(n), styles(n), box_colours(n, kInk), patterns(n, 0),
      symbol_numbers(n, 1);
  std::vector<double> widths(n, 2.0), box_scales(n, 1.0), box_widths(n, 1.0), symbol_scales(n, 0.75);
  std::vector<std::string> texts(n);
  std::vector<const char*> text_ptrs(n), symbols(n);
  for (std::size_t i = 0; i < n; ++i) {
    const PlotSeries& s = plot.series[i];
    opts[i] = s.points_only ? PL_LEGEND_SYMBOL : PL_LEGEND_LINE;
    colours[i] = series_colour(i);
    styles[i] = series_style(i);
    texts[i] = pl_text(s.label);
    text_ptrs[i] = texts[i].c_str();
    symbols[i] = series_marker(i);
  }
  double w = 0, h = 0;
  plcol0(kInk);
  pllegend(&w, &h, PL_LEGEND_BACKGROUND | PL_LEGEND_BOUNDING_BOX,
           PL_POSITION_LEFT | PL_POSITION_TOP | PL_POSITION_INSIDE | PL_POSITION_VIEWPORT, x, 0, plot_width,
           kBackground, kInk, 1, 0, 0, pl_int(n), opts.data(), 1.0, kLegendScale, 2.0, 0.0, text_colours.data(),
           text_ptrs.data(), box_colours.data(), patterns.data(), box_scales.data(), box_widths.data(), colours.data(),
           styles.data(), widths.data(), colours.data(), symbol_scales.data(), symbol_numbers.data(), symbols.data());
  plcol0(kInk);
  return w;
}

// Width in mm of the part of a legend that does not scale with the viewport (text, margins),
// measured by drawing it on a throwaway page of the svg device or of cairo's.
double measure_legend_mm(const LinePlot& plot, bool svg) {
  double mm = 0;
  render_to_measure(svg, 800, 500, [&](const Page& page) {
    plvpor(0.1, 0.6, 0.1, 0.9);
    plwind(0, 1, 0, 1);
    mm = draw_legend(plot, 0, 0) * 0.5 * page.w_mm;
  });
  return mm;
}

// ---------------------------------------------------------------------------------------
// Images
// ---------------------------------------------------------------------------------------

namespace {

// Tick format of a linear colour bar: about 5 intervals.
TickFormat colour_bar_ticks(const ColourScale& s) { return tick_format({s.lo, s.hi}, nice_step(s.hi - s.lo, 5)); }

}  // namespace

Axis image_axis(double lo, double hi, std::size_t n) {
  if (lo == 0 && hi == 0) return {-0.5, static_cast<double>(n) - 0.5, true};
  return {lo, hi, false};
}

// Block mean over f x f cells (drawable values only; NaN when a block has none). The result
// covers f times its size in cells, so its world extent grows past the data by under one
// block at the far edges (clipped by the window).
Raster block_mean(const Raster& r, std::size_t f) {
  if (f <= 1) return r;
  Raster d = r;
  d.rows = (r.rows + f - 1) / f;
  d.cols = (r.cols + f - 1) / f;
  d.v.assign(d.rows * d.cols, kNaN);
  for (std::size_t by = 0; by < d.rows; ++by)
    for (std::size_t bx = 0; bx < d.cols; ++bx) {
      double sum = 0;
      std::size_t count = 0;
      for (std::size_t y = by * f; y < std::min(r.rows, (by + 1) * f); ++y)
        for (std::size_t x = bx * f; x < std::min(r.cols, (bx + 1) * f); ++x) {
          const double v = r.v[y * r.cols + x];
          if (drawable(v)) {
            sum += v;
            ++count;
          }
        }
      if (count) d.v[by * d.cols + bx] = sum / static_cast<double>(count);
    }
  const double cell_w = (r.x1 - r.x0) / static_cast<double>(r.cols);
  const double cell_h = (r.y1 - r.y0) / static_cast<double>(r.rows);
  d.x1 = r.x0 + cell_w * static_cast<double>(d.cols * f);
  if (r.top_is_y1)
    d.y0 = r.y1 - cell_h * static_cast<double>(d.rows * f);
  else
    d.y1 = r.y0 + cell_h * static_cast<double>(d.rows * f);
  return d;
}

// Block size that keeps `panels` rasters of rows x cols within `cells` cells in all.
std::size_t block_for(std::size_t rows, std::size_t cols, std::size_t panels, std::size_t cells) {
  auto total = [&](std::size_t f) {
    return static_cast<double>((rows + f - 1) / f) * static_cast<double>((cols + f - 1) / f) *
           static_cast<double>(panels);
  };
  if (total(1) <= static_cast<double>(cells)) return 1;
  std::size_t f = static_cast<std::size_t>(std::floor(std::sqrt(total(1) / static_cast<double>(cells))));
  f = std::max<std::size_t>(f, 2);
  while (total(f) > static_cast<double>(cells)) ++f;
  return f;
}

ColourScale colour_scale(const std::vector<const std::vector<double>*>& data, bool log_scale, double decades) {
  ColourScale s;
  s.log = log_scale;
  Range r;
  for (const auto* d : data)
    for (double v : *d) r.add(v);
  if (r.empty()) {
    s.empty_text = "no finite values";
    return s;
  }
  if (log_scale) {
    if (!(r.hi > 0)) {
      s.empty_text = "no positive values";
      return s;
    }
    s.floor = r.hi * std::pow(10.0, -decades);
    s.lo = std::log10(s.floor);
    s.hi = std::log10(r.hi);
  } else {
    s.lo = r.lo;
    s.hi = r.hi;
    if (!(s.hi > s.lo)) {
      const double d = s.lo != 0 ? 0.05 * std::fabs(s.lo) : 1.0;
      s.lo -= d;
      s.hi += d;
    }
  }
  s.valid = std::isfinite(s.lo) && std::isfinite(s.hi) && s.hi > s.lo;
  if (!s.valid) s.empty_text = "no finite values";
  return s;
}

// Draws a raster in the current viewport and window; non-finite cells stay blank. In the PNG
// pass the raster goes to the sink (RasterSink) instead.
void draw_raster(const Raster& r, const ColourScale& s) {
  if (RasterSink* sink = raster_sink()) {
    sink->rasters.push_back(pending_raster(r, s, *sink));
    return;
  }
  const double below = s.lo - 1 - std::fabs(s.lo);  // outside [lo, hi]: not drawn
  std::vector<double> t(r.rows * r.cols);
  std::vector<const double*> columns(r.cols);
  for (std::size_t x = 0; x < r.cols; ++x) {
    columns[x] = t.data() + x * r.rows;
    for (std::size_t iy = 0; iy < r.rows; ++iy) {  // iy = 0 at the y0 side
      const std::size_t row = r.top_is_y1 ? r.rows - 1 - iy : iy;
      const double c = coloured(r.v[row * r.cols + x], s);
      t[x * r.rows + iy] = std::isfinite(c) ? std::clamp(c, s.lo, s.hi) : below;
    }
  }
  plimagefr(columns.data(), pl_int(r.cols), pl_int(r.rows), r.x0, r.x1, r.y0, r.y1, s.lo, s.hi, s.lo, s.hi, nullptr,
            nullptr);
}

// A colour bar right of the current viewport (offset and width in viewport widths).
void draw_colour_bar(const ColourScale& s, const std::string& label, double offset, double width) {
  constexpr std::size_t kSteps = 128;
  std::vector<double> values(kSteps);
  for (std::size_t i = 0; i < kSteps; ++i)
    values[i] = s.lo + (s.hi - s.lo) * static_cast<double>(i) / static_cast<double>(kSteps - 1);
  const double* value_rows[] = {values.data()};
  const std::string text = pl_text(label);
  const char* labels[] = {text.c_str()};
  const PLINT label_opts[] = {PL_COLORBAR_LABEL_RIGHT};
  const char* axis_opts[] = {s.log ? "bcvtml" : "bcvtmo"};
  const TickFormat f = colour_bar_ticks(s);
  const double steps[] = {s.log ? 0 : f.step};
  const PLINT sub_ticks[] = {0};
  const PLINT n_values[] = {pl_int(kSteps)};
  double w = 0, h = 0;
  plcol0(kInk);
  AxisLabels tick_labels{f, f};
  plslabelfunc(&write_tick_label, &tick_labels);
  plcolorbar(&w, &h, PL_COLORBAR_IMAGE | PL_COLORBAR_LABEL_RIGHT,
             PL_POSITION_RIGHT | PL_POSITION_OUTSIDE | PL_POSITION_VIEWPORT, offset, 0, width, 1.0, kBackground, kInk,
             1, 0, 0, kInk, 1, 1, label_opts, labels, 1, axis_opts, steps, sub_ticks, n_values, value_rows);
  plslabelfunc(nullptr, nullptr);
}

// Width in character heights of a colour bar's widest tick label.
double colour_bar_chars(const ColourScale& s) {
  if (!s.valid) return 0;
  return tick_label_chars({s.lo, s.hi}, colour_bar_ticks(s), s.log);
}

Raster ImageFrame::grid(std::size_t rows, std::size_t cols, std::vector<double> v) const {
  Raster r;
  r.rows = rows;
  r.cols = cols;
  r.v = std::move(v);
  r.x0 = x.lo;
  r.x1 = x.hi;
  r.y0 = y.lo;
  r.y1 = y.hi;
  r.top_is_y1 = !y.pixel;  // pixel rows: the window is inverted, row 0 (at y0) on top
  return r;
}

void ImageFrame::window() const {
  if (y.pixel)
    plwind(x.lo, x.hi, y.hi, y.lo);
  else
    plwind(x.lo, x.hi, y.lo, y.hi);
}

double ImageFrame::aspect(std::size_t rows, std::size_t cols) const {
  const double a =
      (x.pixel || y.pixel) ? static_cast<double>(rows) / static_cast<double>(cols) : (y.hi - y.lo) / (x.hi - x.lo);
  return std::clamp(a, 0.25, 4.0);
}

TickFormat ImageFrame::x_ticks(double w, double scale, double target) const {
  return fit_ticks({x.lo, x.hi}, w, scale, target, false);
}

TickFormat ImageFrame::y_ticks(double h, double scale, double target) const {
  return fit_ticks({y.lo, y.hi}, h, scale, target, true);
}

void no_values_text(const ImageFrame& f, const std::string& text) {
  plcol0(kInk);
  plptex(0.5 * (f.x.lo + f.x.hi), 0.5 * (f.y.lo + f.y.hi), 1, 0, 0.5, text.c_str());
}

// Evenly spaced plane indices: all when planes <= max, else max of them, first and last included.
std::vector<std::size_t> shown_planes(std::size_t planes, std::size_t max) {
  std::vector<std::size_t> idx;
  if (planes <= max) {
    for (std::size_t p = 0; p < planes; ++p) idx.push_back(p);
    return idx;
  }
  if (max == 1) return {0};
  for (std::size_t k = 0; k < max; ++k)
    idx.push_back(static_cast<std::size_t>(
        std::llround(static_cast<double>(k) * static_cast<double>(planes - 1) / static_cast<double>(max - 1))));
  return idx;
}

}  // namespace qdo::figure_detail
