// Figures drawn with PLplot: each is rendered twice, with the "pngcairo" device to the PNG and
// with the "svg" device (text kept as <text>) to the SVG beside it, each into a temporary file
// that commit_output moves into place. See include/qdo/data/figure.hpp. This file checks the input
// and lays out the four kinds of figure; the PLplot session is in figure_plplot.cpp, axes,
// legends and colour scales in figure_axes.cpp (shared through data/figure_internal.hpp).
#include "qdo/data/figure.hpp"

#include <plplot.h>

#include <algorithm>
#include <array>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "data/figure_internal.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {
using namespace figure_detail;  // the figure module's shared parts

namespace {
namespace fs = std::filesystem;

// ---------------------------------------------------------------------------------------
// Input checks (before anything is drawn)
// ---------------------------------------------------------------------------------------

std::string quoted(const std::string& s) { return "\"" + s + "\""; }

void check_text(const std::string& name, const std::string& value) {
  if (value.empty()) reject(name, quoted(value), "a non-empty text (figures name what they show)");
}

bool ends_with_png(const std::string& p) {
  if (p.size() < 4) return false;
  std::string ext = p.substr(p.size() - 4);
  for (char& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return ext == ".png";
}

void check_png_path(const std::string& p) {
  if (!ends_with_png(p)) reject("png_path", quoted(p), "a file name ending in .png (the SVG is written beside it)");
  const fs::path file(p);
  if (file.filename().string().size() == 4) reject("png_path", quoted(p), "a file name with a stem before .png");
  const fs::path dir = file.parent_path().empty() ? fs::path(".") : file.parent_path();
  std::error_code ec;
  if (!fs::is_directory(dir, ec))
    reject("png_path", quoted(p), "a file in an existing folder ('" + dir.string() + "' is not one)");
  if (fs::is_directory(file, ec)) reject("png_path", quoted(p), "a file name, not a folder");
  if (fs::is_directory(svg_path_for(p), ec))
    reject("png_path", quoted(p), "a name whose SVG '" + svg_path_for(p) + "' is not a folder");
}

void check_decades(const std::string& name, double decades) {
  if (!(std::isfinite(decades) && decades > 0 && decades <= 300))
    reject(name, decades, "a number of decades in (0, 300]");
}

void check_line_plot(const std::string& name, const LinePlot& plot) {
  check_text(name + ".title", plot.title);
  check_text(name + ".x_label", plot.x_label);
  check_text(name + ".y_label", plot.y_label);
  if (plot.series.empty()) reject(name + ".series", "[] (empty)", "at least one series");
  for (std::size_t i = 0; i < plot.series.size(); ++i) {
    const PlotSeries& s = plot.series[i];
    const std::string sn = name + ".series[" + std::to_string(i) + "]";
    check_text(sn + ".label", s.label);
    const std::string which = " (series '" + s.label + "')";
    const std::string n = std::to_string(s.x.size());
    if (s.x.empty()) reject(sn + ".x", "[] (empty)", "at least one point" + which);
    if (s.y.size() != s.x.size())
      reject(sn + ".y", "size " + std::to_string(s.y.size()), "as many values as x (" + n + ")" + which);
    if (s.y_low.empty() != s.y_high.empty())
      reject(sn + (s.y_low.empty() ? ".y_low" : ".y_high"), "[] (empty)",
             "y_low and y_high both empty or both with " + n + " values" + which);
    if (!s.y_low.empty() && s.y_low.size() != s.x.size())
      reject(sn + ".y_low", "size " + std::to_string(s.y_low.size()), "as many values as x (" + n + ")" + which);
    if (!s.y_high.empty() && s.y_high.size() != s.x.size())
      reject(sn + ".y_high", "size " + std::to_string(s.y_high.size()), "as many values as x (" + n + ")" + which);
  }
}

// An axis extent: both 0 (pixel index) or finite with min < max.
void check_extent(const std::string& name, const std::string& axis, double lo, double hi) {
  if (lo == 0 && hi == 0) return;
  if (!drawable(lo)) reject(name + "." + axis + "_min", lo, "a finite value within +-1e300");
  if (!drawable(hi)) reject(name + "." + axis + "_max", hi, "a finite value within +-1e300");
  if (!(lo < hi))
    reject(name + "." + axis + "_min", lo,
           "less than " + axis + "_max (" + to_str(hi) + "), or both 0 for pixel indices");
}

void check_image_texts(const std::string& name, const std::string& title, const std::string& x_label,
                       const std::string& y_label, const std::string& value_label) {
  check_text(name + ".title", title);
  check_text(name + ".x_label", x_label);
  check_text(name + ".y_label", y_label);
  check_text(name + ".value_label", value_label);
}

// ---------------------------------------------------------------------------------------
// Line plots
// ---------------------------------------------------------------------------------------

// Runs of consecutive indices where ok(i) holds: [begin, end) pairs.
std::vector<std::pair<std::size_t, std::size_t>> runs(std::size_t n, const std::function<bool(std::size_t)>& ok) {
  std::vector<std::pair<std::size_t, std::size_t>> r;
  std::size_t i = 0;
  while (i < n) {
    while (i < n && !ok(i)) ++i;
    const std::size_t b = i;
    while (i < n && ok(i)) ++i;
    if (i > b) r.emplace_back(b, i);
  }
  return r;
}

void draw_markers(const std::vector<double>& x, const std::vector<double>& y, const char* marker) {
  std::vector<double> mx, my;
  for (std::size_t i = 0; i < x.size(); ++i)
    if (std::isfinite(x[i]) && std::isfinite(y[i])) {
      mx.push_back(x[i]);
      my.push_back(y[i]);
    }
  if (mx.empty()) return;
  plschr(0, 0.75);
  plstring(pl_int(mx.size()), mx.data(), my.data(), marker);
  plschr(0, 1.0);
}

void draw_series(const PlotSeries& s, std::size_t index, bool log_x, bool log_y) {
  const Points p = plotted(s, log_x, log_y);
  const std::size_t n = p.x.size();
  auto point_ok = [&](std::size_t i) { return std::isfinite(p.x[i]) && std::isfinite(p.y[i]); };
  auto interval_ok = [&](std::size_t i) {
    return !p.lo.empty() && std::isfinite(p.x[i]) && std::isfinite(p.lo[i]) && std::isfinite(p.hi[i]);
  };
  if (!p.lo.empty() && s.points_only) {  // error bars
    std::vector<double> ex, elo, ehi;
    for (std::size_t i = 0; i < n; ++i)
      if (interval_ok(i)) {
        ex.push_back(p.x[i]);
        elo.push_back(p.lo[i]);
        ehi.push_back(p.hi[i]);
      }
    if (!ex.empty()) {
      plcol0(series_colour(index));
      plwidth(1.5);
      plerry(pl_int(ex.size()), ex.data(), elo.data(), ehi.data());
    }
  } else if (!p.lo.empty()) {  // a translucent band
    plcol0(band_colour(index));
    for (const auto& [b, e] : runs(n, interval_ok)) {
      if (e - b < 2) continue;
      std::vector<double> bx, by;
      for (std::size_t i = b; i < e; ++i) {
        bx.push_back(p.x[i]);
        by.push_back(p.hi[i]);
      }
      for (std::size_t i = e; i-- > b;) {
        bx.push_back(p.x[i]);
        by.push_back(p.lo[i]);
      }
      plfill(pl_int(bx.size()), bx.data(), by.data());
    }
  }
  plcol0(series_colour(index));
  if (s.points_only) {
    draw_markers(p.x, p.y, series_marker(index));
  } else {
    plwidth(2.0);
    pllsty(series_style(index));
    std::vector<double> lone_x, lone_y;  // points with no finite neighbour: drawn as markers
    for (const auto& [b, e] : runs(n, point_ok)) {
      if (e - b == 1) {
        lone_x.push_back(p.x[b]);
        lone_y.push_back(p.y[b]);
      } else {
        plline(pl_int(e - b), p.x.data() + b, p.y.data() + b);
      }
    }
    pllsty(1);
    draw_markers(lone_x, lone_y, series_marker(index));
  }
  plwidth(1.0);
}

// One line plot in the page region [x0, x1] x [y0, y1] (normalised page coordinates): the
// axes `left` character heights from x0, the legend (legend_mm) to their right.
void draw_line_plot(const LinePlot& plot, const LineFrame& f, const Page& page, double x0, double x1, double y0,
                    double y1, double left, double legend_mm, double title_scale) {
  legend_mm = std::min(legend_mm, 0.45 * page.w_mm);  // longer labels run off the page, the axes stay
  const double usable = (x1 - x0) - page.fx(left) - (legend_mm + 0.5 * kCharMm) / page.w_mm;
  const double vp_w = usable / (1 + kLegendGap + kLegendPlotWidth);
  const double vx0 = x0 + page.fx(left), vx1 = vx0 + vp_w;
  const double vy0 = y0 + page.fy(4.9), vy1 = y1 - page.fy(2.8 * title_scale);
  plvpor(vx0, vx1, vy0, vy1);
  plwind(f.xw.lo, f.xw.hi, f.yw.lo, f.yw.hi);

  const char* xgrid = plot.log_x ? "gl" : "g";
  const char* ygrid = plot.log_y ? "gl" : "g";
  plcol0(kGrid);
  plwidth(0.8);
  plbox(xgrid, plot.log_x ? 0 : f.x_ticks.step, 0, ygrid, plot.log_y ? 0 : f.y_ticks.step, 0);
  plwidth(1.0);

  if (f.nothing) {
    plcol0(kInk);
    plptex(0.5 * (f.xw.lo + f.xw.hi), 0.5 * (f.yw.lo + f.yw.hi), 1, 0, 0.5, "no finite values");
  } else {
    for (double v : plot.hlines) {
      const double y = axis_value(v, plot.log_y);
      if (!std::isfinite(y)) continue;
      const std::array<double, 2> hx{f.xw.lo, f.xw.hi}, hy{y, y};
      plcol0(kReference);
      plwidth(1.5);
      pllsty(2);
      plline(2, hx.data(), hy.data());
      pllsty(1);
      plwidth(1.0);
    }
    for (std::size_t i = 0; i < plot.series.size(); ++i) draw_series(plot.series[i], i, plot.log_x, plot.log_y);
  }

  plcol0(kInk);
  draw_axes("bcnst", f.x_ticks, plot.log_x, "bcnstv", f.y_ticks, plot.log_y);
  plmtex("b", 3.5, 0.5, 0.5, pl_text(plot.x_label).c_str());
  plmtex("l", y_label_disp(f.y_chars, 1.0), 0.5, 0.5, pl_text(plot.y_label).c_str());
  text_top(1.0, title_scale, plot.title);
  draw_legend(plot, 1 + kLegendGap, kLegendPlotWidth);
}

constexpr int kLineW = 800, kLineH = 500;
constexpr int kPanelH = 330, kPanelsTitleH = 50;

// A length in pixels, rounded to a whole number of them.
int px(double v) { return static_cast<int>(std::lround(v)); }

}  // namespace

std::string svg_path_for(const std::string& png_path) {
  if (!ends_with_png(png_path)) reject("png_path", quoted(png_path), "a file name ending in .png");
  return png_path.substr(0, png_path.size() - 4) + ".svg";
}

void write_line_plot(const std::string& png_path, const LinePlot& plot) {
  check_png_path(png_path);
  check_line_plot("plot", plot);
  const LineFrame frame = line_frame(plot);
  std::array<double, 2> legend_mm{};  // cairo, svg
  write_figure(
      png_path,
      [&] {
        for (bool svg : {false, true}) legend_mm[svg] = measure_legend_mm(plot, svg);
      },
      kLineW, kLineH,
      [&](const Page& page, bool svg) {
        draw_line_plot(plot, frame, page, 0, 1, 0, 1, line_left(frame), legend_mm[svg], kTitleScale);
      });
}

void write_line_panels(const std::string& png_path, const std::string& title, const std::vector<LinePlot>& panels) {
  check_png_path(png_path);
  check_text("title", title);
  if (panels.empty()) reject("panels", "[] (empty)", "at least one panel");
  for (std::size_t i = 0; i < panels.size(); ++i) check_line_plot("panels[" + std::to_string(i) + "]", panels[i]);
  std::vector<LineFrame> frames;
  double left = 0;  // one left margin and one legend width for all panels: the axes line up
  for (const auto& p : panels) {
    frames.push_back(line_frame(p));
    left = std::max(left, line_left(frames.back()));
  }
  std::array<double, 2> legend_mm{};  // cairo, svg
  const int h = kPanelsTitleH + pl_int(panels.size()) * kPanelH;
  write_figure(
      png_path,
      [&] {
        for (bool svg : {false, true})
          for (const auto& p : panels) legend_mm[svg] = std::max(legend_mm[svg], measure_legend_mm(p, svg));
      },
      kLineW, h,
      [&](const Page& page, bool svg) {
        const double title_frac = static_cast<double>(kPanelsTitleH) / static_cast<double>(h);
        const double panel_frac = static_cast<double>(kPanelH) / static_cast<double>(h);
        for (std::size_t i = 0; i < panels.size(); ++i) {
          const double top = 1 - title_frac - panel_frac * static_cast<double>(i);
          draw_line_plot(panels[i], frames[i], page, 0, 1, top - panel_frac, top, left, legend_mm[svg], 1.0);
        }
        plvpor(0, 1, 1 - title_frac, 1);
        plwind(0, 1, 0, 1);
        plcol0(kInk);
        plschr(0, 1.3);
        plptex(0.5, 0.4, 1, 0, 0.5, pl_text(title).c_str());
        plschr(0, 1.0);
      });
}

void write_image_plot(const std::string& png_path, const ImagePlot& plot) {
  check_png_path(png_path);
  check_image_texts("plot", plot.title, plot.x_label, plot.y_label, plot.value_label);
  const Map2D& m = plot.values;
  if (m.rows == 0 || m.cols == 0)
    reject("plot.values", shape(1, m.rows, m.cols), "a map with at least one row and one column");
  if (m.data.size() != m.rows * m.cols)
    reject("plot.values.data", "size " + std::to_string(m.data.size()),
           "rows x cols = " + std::to_string(m.rows * m.cols) + " values");
  check_extent("plot", "x", plot.x_min, plot.x_max);
  check_extent("plot", "y", plot.y_min, plot.y_max);
  if (plot.log_scale) check_decades("plot.log_decades", plot.log_decades);

  const ImageFrame frame{image_axis(plot.x_min, plot.x_max, m.cols), image_axis(plot.y_min, plot.y_max, m.rows)};
  const ColourScale scale = colour_scale({&m.data}, plot.log_scale, plot.log_decades);
  const Raster full = frame.grid(m.rows, m.cols, m.data);

  // Page: the image fits a 540 x 540 px box at its aspect, margins around it in character heights.
  constexpr double kBox = 540;
  const double aspect = frame.aspect(m.rows, m.cols);
  const double img_w = aspect <= 1 ? kBox : kBox / aspect, img_h = aspect <= 1 ? kBox * aspect : kBox;
  const TickFormat x_ticks = frame.x_ticks(img_w, 1.0, 6), y_ticks = frame.y_ticks(img_h, 1.0, 5);
  const double y_disp = y_label_disp(tick_label_chars({frame.y.lo, frame.y.hi}, y_ticks, false), 1.0);
  const double left = (y_disp + 1.5) * kCharPx, bottom = 4.9 * kCharPx, top = 3.2 * kCharPx;
  const double bar_offset = 1.0 * kCharPx, bar_w = 1.6 * kCharPx;
  const double right = bar_offset + bar_w + (1.0 + colour_bar_chars(scale) + 3.0) * kCharPx;
  const int w = px(left + img_w + right), h = px(bottom + img_h + top);

  write_figure(
      png_path, [] {}, w, h,
      [&](const Page&, bool svg) {
        const double W = w, H = h;
        plvpor(left / W, (left + img_w) / W, bottom / H, (bottom + img_h) / H);
        frame.window();
        if (scale.valid) {
          const std::size_t f = block_for(m.rows, m.cols, 1, svg ? kSvgImageCells : kPngImageCells);
          draw_raster(block_mean(full, f), scale);
        } else {
          no_values_text(frame, scale.empty_text);
        }
        plcol0(kInk);
        draw_axes("bcnst", x_ticks, false, "bcnstv", y_ticks, false);
        plmtex("b", 3.5, 0.5, 0.5, pl_text(plot.x_label).c_str());
        plmtex("l", y_disp, 0.5, 0.5, pl_text(plot.y_label).c_str());
        text_top(1.2, kTitleScale, plot.title);
        if (scale.valid) draw_colour_bar(scale, plot.value_label, bar_offset / img_w, bar_w / img_w);
      });
}

void write_montage_plot(const std::string& png_path, const MontagePlot& plot) {
  check_png_path(png_path);
  check_image_texts("plot", plot.title, plot.x_label, plot.y_label, plot.value_label);
  const RealStack& st = plot.stack;
  if (st.planes == 0 || st.rows == 0 || st.cols == 0)
    reject("plot.stack", shape(st), "a stack with at least one plane, row and column");
  if (st.data.size() != st.planes * st.rows * st.cols)
    reject("plot.stack.data", "size " + std::to_string(st.data.size()),
           "planes x rows x cols = " + std::to_string(st.planes * st.rows * st.cols) + " values");
  if (plot.panel_titles.size() != st.planes)
    reject("plot.panel_titles", "size " + std::to_string(plot.panel_titles.size()),
           "one title per plane (" + std::to_string(st.planes) + ")");
  for (std::size_t p = 0; p < st.planes; ++p)
    check_text("plot.panel_titles[" + std::to_string(p) + "]", plot.panel_titles[p]);
  if (plot.max_panels == 0) reject("plot.max_panels", plot.max_panels, "at least 1");
  check_extent("plot", "x", plot.x_min, plot.x_max);
  check_extent("plot", "y", plot.y_min, plot.y_max);
  if (plot.log_scale) check_decades("plot.log_decades", plot.log_decades);

  const std::vector<std::size_t> shown = shown_planes(st.planes, plot.max_panels);
  const std::size_t n = shown.size();
  const ImageFrame frame{image_axis(plot.x_min, plot.x_max, st.cols), image_axis(plot.y_min, plot.y_max, st.rows)};

  // Panel values, each divided by its own maximum when per_panel_max.
  std::vector<std::vector<double>> values(n);
  std::vector<const std::vector<double>*> value_ptrs(n);
  for (std::size_t k = 0; k < n; ++k) {
    const double* src = st.plane(shown[k]);
    values[k].assign(src, src + st.plane_size());
    if (plot.per_panel_max) {
      Range r;
      for (double v : values[k]) r.add(v);
      if (!r.empty() && r.hi > 0)
        for (double& v : values[k]) v /= r.hi;
    }
    value_ptrs[k] = &values[k];
  }
  const ColourScale scale = colour_scale(value_ptrs, plot.log_scale, plot.log_decades);

  // Grid: near-square, panels sized so that the figure stays within ~1300 px across; tick
  // labels on the left column and under the lowest panel of each column only, the columns
  // spaced by the widest x tick label.
  constexpr double kTickScale = 0.8, kPanelTitleScale = 0.9;
  const std::size_t ncols = static_cast<std::size_t>(std::ceil(std::sqrt(static_cast<double>(n))));
  const std::size_t nrows = (n + ncols - 1) / ncols;
  const double aspect = frame.aspect(st.rows, st.cols);
  const double side = std::clamp(1000.0 / static_cast<double>(ncols), 160.0, 320.0);
  const double panel_w = aspect > 1 ? side / aspect : side, panel_h = aspect > 1 ? side : side * aspect;
  const TickFormat x_ticks = frame.x_ticks(panel_w, kTickScale, 3), y_ticks = frame.y_ticks(panel_h, kTickScale, 3);
  const double y_disp = y_label_disp(tick_label_chars({frame.y.lo, frame.y.hi}, y_ticks, false), kTickScale);
  const double x_chars = tick_label_chars({frame.x.lo, frame.x.hi}, x_ticks, false);
  const double left = (y_disp + 1.5) * kCharPx, top = 3.0 * kCharPx, bottom = 4.9 * kCharPx;
  const double title_h = 2.2 * kCharPx, gap = (x_chars * kTickScale + 0.8) * kCharPx;
  const double bar_offset = 1.2 * kCharPx, bar_w = 1.6 * kCharPx;
  const double right = bar_offset + bar_w + (1.0 + colour_bar_chars(scale) + 3.0) * kCharPx;
  const double grid_w = static_cast<double>(ncols) * panel_w + static_cast<double>(ncols - 1) * gap;
  const double grid_h = static_cast<double>(nrows) * (panel_h + title_h);
  const int w = px(left + grid_w + right), h = px(top + grid_h + bottom);
  std::string title = plot.title;
  if (n < st.planes) title += " (" + std::to_string(n) + " of " + std::to_string(st.planes) + " planes)";

  write_figure(
      png_path, [] {}, w, h,
      [&](const Page&, bool svg) {
        const double W = w, H = h;
        const std::size_t f = block_for(st.rows, st.cols, n, svg ? kSvgImageCells : kPngImageCells);
        for (std::size_t k = 0; k < n; ++k) {
          const std::size_t row = k / ncols, col = k % ncols;
          const double x0 = left + static_cast<double>(col) * (panel_w + gap);
          const double y1 = H - top - static_cast<double>(row) * (panel_h + title_h) - title_h;
          plvpor(x0 / W, (x0 + panel_w) / W, (y1 - panel_h) / H, y1 / H);
          frame.window();
          if (scale.valid)
            draw_raster(block_mean(frame.grid(st.rows, st.cols, values[k]), f), scale);
          else
            no_values_text(frame, scale.empty_text);
          const bool left_edge = col == 0, bottom_edge = k + ncols >= n;
          plcol0(kInk);
          plschr(0, kTickScale);
          draw_axes(bottom_edge ? "bcnt" : "bct", x_ticks, false, left_edge ? "bcntv" : "bctv", y_ticks, false);
          plschr(0, 1.0);
          text_top(0.9, kPanelTitleScale, plot.panel_titles[shown[k]]);
        }
        // Labels and the colour bar, relative to the whole grid of panels.
        plvpor(left / W, (left + grid_w) / W, bottom / H, (bottom + grid_h - title_h) / H);
        plwind(0, 1, 0, 1);
        plcol0(kInk);
        plmtex("b", 3.5, 0.5, 0.5, pl_text(plot.x_label).c_str());
        plmtex("l", y_disp, 0.5, 0.5, pl_text(plot.y_label).c_str());
        if (scale.valid) draw_colour_bar(scale, plot.value_label, bar_offset / grid_w, bar_w / grid_w);
        plvpor(0, 1, 1 - top / H, 1);
        plwind(0, 1, 0, 1);
        plschr(0, 1.25);
        plptex(0.5, 0.4, 1, 0, 0.5, pl_text(title).c_str());
        plschr(0, 1.0);
      });
}

}  // namespace qdo
