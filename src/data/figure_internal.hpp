// Private to src/data: what the parts of the figure module share. figure_plplot.cpp runs PLplot
// (one stream per file, rendered once with "pngcairo" and once with "svg", each to a temporary
// file that commit_output moves into place); figure_axes.cpp lays out axes, ticks, legends,
// colour scales and images; figure.cpp checks the input and writes the public figures. Not
// installed; the public API is include/qdo/data/figure.hpp.
#pragma once

#include <plplot.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <functional>
#include <limits>
#include <string>
#include <vector>

#include "qdo/data/figure.hpp"

namespace qdo::figure_detail {

inline constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Values drawn: finite and within +-1e300 (beyond, ranges and tick intervals overflow).
inline constexpr double kHuge = 1e300;
inline bool drawable(double v) { return std::isfinite(v) && std::fabs(v) <= kHuge; }

// ---------------------------------------------------------------------------------------
// PLplot session and page (figure_plplot.cpp)
// ---------------------------------------------------------------------------------------

// A count as PLplot's int; throws Error beyond INT_MAX.
PLINT pl_int(std::size_t n);

// Geometry: PLplot's cairo and svg devices map 72 px to 25.4 mm. Text has one height in every
// figure, whatever its size (PLplot's default grows with the page).
inline constexpr double kPxPerMm = 72.0 / 25.4;
inline constexpr double kCharMm = 4.6;  // character height: 13 px
inline constexpr double kCharPx = kCharMm * kPxPerMm;
inline constexpr double kDigitWidth = 0.9;  // width of a digit, in character heights

// The page after plinit: size in mm.
struct Page {
  double w_mm = 1, h_mm = 1;
  double fx(double chars) const { return chars * kCharMm / w_mm; }  // character heights -> page x
  double fy(double chars) const { return chars * kCharMm / h_mm; }  // character heights -> page y
};

// Colour map 0 entries (set on every page): background, ink, grid, reference lines, then one
// opaque colour per series (kSeries0...) and the same colours translucent for bands (kBand0...).
inline constexpr PLINT kBackground = 0, kInk = 1, kGrid = 2, kReference = 3, kSeries0 = 4;
inline constexpr std::array<std::array<int, 3>, 10> kSeriesRgb = {{{31, 119, 180},
                                                                   {255, 127, 14},
                                                                   {44, 160, 44},
                                                                   {214, 39, 40},
                                                                   {148, 103, 189},
                                                                   {140, 86, 75},
                                                                   {227, 119, 194},
                                                                   {127, 127, 127},
                                                                   {188, 189, 34},
                                                                   {23, 190, 207}}};
inline constexpr PLINT kBand0 = kSeries0 + static_cast<PLINT>(kSeriesRgb.size());
inline constexpr PLINT kColours = kBand0 + static_cast<PLINT>(kSeriesRgb.size());

// Renders `draw` on a throwaway page of w x h px, for measuring what PLplot draws (svg device,
// or cairo in memory). Call only inside write_figure's `measure`.
void render_to_measure(bool svg, int w, int h, const std::function<void(const Page&)>& draw);

// Writes one figure of w x h px: under the PLplot mutex, runs `measure` (PLplot measurements on
// throwaway pages), then draws the figure with `draw(page, svg)` to the PNG at png_path and to
// the SVG beside it (svg_path_for) and moves both into place. Throws Error when a device is
// missing or PLplot fails, InputError when a file cannot be written.
void write_figure(const std::string& png_path, const std::function<void()>& measure, int w, int h,
                  const std::function<void(const Page&, bool)>& draw);

// PLplot text: '#' starts an escape sequence, "##" is a literal '#'. Returns s escaped.
std::string pl_text(const std::string& s);

// Text centred above the viewport, `disp` character heights out, at `scale` times the height.
void text_top(double disp, double scale, const std::string& s);

// ---------------------------------------------------------------------------------------
// Ranges, ticks and labels (figure_axes.cpp)
// ---------------------------------------------------------------------------------------

// The extent of the drawable values added; empty (NaN ends) when none.
struct Range {
  double lo = kNaN, hi = kNaN;
  void add(double v) {
    if (!drawable(v)) return;
    lo = std::isfinite(lo) ? std::min(lo, v) : v;
    hi = std::isfinite(hi) ? std::max(hi, v) : v;
  }
  bool empty() const { return !std::isfinite(lo); }
};

// An axis range with 5 % padding; a constant widened (half a decade on log axes), none [0, 1].
Range padded(Range r, bool log_axis);

// A value as plotted on an axis: log10 on a log axis (NaN for v <= 0), NaN when not drawable.
double axis_value(double v, bool log_axis);

// A tick interval of 1, 2 or 5 x 10^k giving about `target` intervals over `span`.
double nice_step(double span, double target);

// How the tick labels of a linear axis are written (by write_tick_label, PLplot's custom
// labels): fixed-point with the decimals the interval needs, or as mantissa x 10^exponent for
// very large or small values. Every label carries its own magnitude (no separate factor).
struct TickFormat {
  double step = 1;  // tick interval
  bool sci = false;
  int decimals = 0;  // fixed-point decimals
};

// The tick format for ticks `step` apart over the window w.
TickFormat tick_format(const Range& w, double step);

// plbox with custom labels on the linear axes (option "o"); log axes get PLplot's own.
void draw_axes(const std::string& xopt, const TickFormat& x, bool log_x, const std::string& yopt, const TickFormat& y,
               bool log_y);

// Width, in character heights, of the widest tick label of a linear axis (log axes: "10" and a
// small exponent).
double tick_label_chars(const Range& w, const TickFormat& f, bool log_axis);

// Tick format for a linear axis of axis_px pixels with text at `scale`: about `target`
// intervals, fewer while the labels would not fit side by side (x) or one above the other (y).
TickFormat fit_ticks(const Range& w, double axis_px, double scale, double target, bool vertical);

// Distance, in character heights, of a y axis label from the axis: past the tick labels
// (tick_chars wide, in character heights at tick_scale).
inline double y_label_disp(double tick_chars, double tick_scale) { return 0.5 + tick_chars * tick_scale + 1.2; }

// ---------------------------------------------------------------------------------------
// Line plots: series styles, window, legend (figure_axes.cpp)
// ---------------------------------------------------------------------------------------

inline constexpr double kLegendScale = 0.9;       // legend text, relative to the character height
inline constexpr double kLegendPlotWidth = 0.07;  // legend line samples, in viewport widths
inline constexpr double kLegendGap = 0.02;        // between the axes and the legend, in viewport widths
inline constexpr double kTitleScale = 1.15;
inline constexpr const char* kMarkers[] = {"●", "■", "▲", "◆", "▼", "⬟"};
inline constexpr std::size_t kMarkerCount = sizeof(kMarkers) / sizeof(kMarkers[0]);

// Series i's line colour, band colour, line style (the colours repeat every 10 series, then
// with the next dash pattern) and marker.
inline PLINT series_colour(std::size_t i) { return kSeries0 + static_cast<PLINT>(i % kSeriesRgb.size()); }
inline PLINT band_colour(std::size_t i) { return kBand0 + static_cast<PLINT>(i % kSeriesRgb.size()); }
inline PLINT series_style(std::size_t i) { return 1 + static_cast<PLINT>((i / kSeriesRgb.size()) % 8); }
inline const char* series_marker(std::size_t i) { return kMarkers[i % kMarkerCount]; }

// The plotted points of one series, log and finiteness applied: n values each (lo, hi empty
// when the series has no interval); NaN where a point is not drawn.
struct Points {
  std::vector<double> x, y, lo, hi;
};

Points plotted(const PlotSeries& s, bool log_x, bool log_y);

// What a line plot's layout depends on: its window, tick formats and y tick label width.
struct LineFrame {
  Range xw, yw;
  TickFormat x_ticks, y_ticks;  // linear axes
  double y_chars = 0;           // widest y tick label, in character heights
  bool nothing = false;         // no drawable point
};

LineFrame line_frame(const LinePlot& plot);

// Left margin of a line plot, in character heights.
inline double line_left(const LineFrame& f) { return y_label_disp(f.y_chars, 1.0) + 1.5; }

// The legend, its top left corner at (x, 1) in viewport coordinates; returns its width in
// viewport widths.
double draw_legend(const LinePlot& plot, double x, double plot_width);

// Width in mm of the part of a legend that does not scale with the viewport (text, margins),
// measured by drawing it on a throwaway page of the svg device or of cairo's.
double measure_legend_mm(const LinePlot& plot, bool svg);

// ---------------------------------------------------------------------------------------
// Images: rasters, block means, colour scale and bar (figure_axes.cpp)
// ---------------------------------------------------------------------------------------

// A row-major grid of values (rows x cols) covering the world rectangle [x0, x1] x [y0, y1],
// row 0 at the y1 side when top_is_y1, else at the y0 side.
struct Raster {
  std::size_t rows = 0, cols = 0;
  std::vector<double> v;
  double x0 = 0, x1 = 1, y0 = 0, y1 = 1;
  bool top_is_y1 = true;
};

// An image axis: the world coordinates of the outer pixel edges; pixel axes centre pixel i at i.
struct Axis {
  double lo, hi;
  bool pixel;
};
// The axis of n pixels with outer edges lo..hi, or pixel indices when both are 0.
Axis image_axis(double lo, double hi, std::size_t n);

// Block mean over f x f cells (drawable values only; NaN when a block has none). The result
// covers f times its size in cells, so its world extent grows past the data by under one
// block at the far edges (clipped by the window).
Raster block_mean(const Raster& r, std::size_t f);

// Block size that keeps `panels` rasters of rows x cols within `cells` cells in all.
std::size_t block_for(std::size_t rows, std::size_t cols, std::size_t panels, std::size_t cells);

// Cells a PNG draws for all its images together (beyond, block means).
inline constexpr std::size_t kPngImageCells = std::size_t{1} << 22;

// Colour scale: values as coloured (linear, or log10 clamped to the floor).
struct ColourScale {
  bool log = false;
  double floor = 0;        // log: smallest value coloured (max * 10^-decades)
  double lo = 0, hi = 1;   // colour range in coloured units
  bool valid = false;      // false: nothing to colour
  std::string empty_text;  // shown when not valid
};

// The colour scale over all values of `data` (log10, `decades` below the maximum, when log_scale).
ColourScale colour_scale(const std::vector<const std::vector<double>*>& data, bool log_scale, double decades);

// Draws a raster in the current viewport and window; non-finite cells stay blank.
void draw_raster(const Raster& r, const ColourScale& s);

// The PNG pass draws its rasters itself: PLplot's cairo device draws an image cell by cell (a
// filled polygon each, ~0.5 s for a 31-panel PSF montage), so draw_raster hands the PNG's rasters
// to a RasterSink instead, and write_figure paints them into the page's pixels after PLplot has
// drawn the rest (only over pixels PLplot left as background: the frame, ticks and text stay on
// top). Colours: the viridis map PLplot uses (figure_plplot.cpp), per cell, nearest-cell scaling.
struct PendingRaster {
  double px0 = 0, px1 = 0, py0 = 0, py1 = 0;  // the raster's outer edges in page pixels (py0 at the top)
  std::size_t rows = 0, cols = 0;             // cells, row 0 at the top
  std::vector<std::array<unsigned char, 4>> rgba;  // per cell; alpha 0: not drawn (non-finite)
};
struct RasterSink {
  int page_w = 0, page_h = 0;  // px
  std::vector<PendingRaster> rasters;
};
// The sink of the pass being drawn (the PNG pass), or nullptr (the SVG pass draws with PLplot).
RasterSink*& raster_sink();
// A value in coloured units (log10, clamped to the floor, on a log scale); NaN when not drawable.
inline double coloured(double v, const ColourScale& s) {
  if (!drawable(v)) return kNaN;
  if (!s.log) return v;
  return std::log10(std::max(v, s.floor));
}
// The raster's cells as colours and its edges in page pixels (the current viewport and window).
PendingRaster pending_raster(const Raster& r, const ColourScale& s, const RasterSink& sink);
// The viridis colour at t in [0, 1] (PLplot's colour map 1 as set_colours sets it).
std::array<unsigned char, 3> viridis(double t);

// A colour bar right of the current viewport (offset and width in viewport widths).
void draw_colour_bar(const ColourScale& s, const std::string& label, double offset, double width);

// Width in character heights of a colour bar's widest tick label.
double colour_bar_chars(const ColourScale& s);

// An image's axes: world rectangle of the pixel grid and tick intervals.
struct ImageFrame {
  Axis x, y;
  // The values v (rows x cols, row-major) as a raster over this frame.
  Raster grid(std::size_t rows, std::size_t cols, std::vector<double> v) const;
  // Sets the PLplot window (pixel rows: inverted, row 0 on top).
  void window() const;
  // Height / width of the drawn image, kept within [1/4, 4].
  double aspect(std::size_t rows, std::size_t cols) const;
  // Tick formats for axes of w x h px with text at `scale`.
  TickFormat x_ticks(double w, double scale, double target) const;
  TickFormat y_ticks(double h, double scale, double target) const;
};

// `text` in the middle of an image's window (when there is nothing to colour).
void no_values_text(const ImageFrame& f, const std::string& text);

// The planes a montage shows: all when planes <= max, else max of them evenly spaced, first and
// last included (indices in increasing order).
std::vector<std::size_t> shown_planes(std::size_t planes, std::size_t max);

}  // namespace qdo::figure_detail
