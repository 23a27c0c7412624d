// Figures for reading results: line plots, stacked line panels, value images with a colour bar
// and image montages (e.g. a PSF stack, one panel per wavelength), drawn with PLplot.
//
// Every figure is written twice: as a PNG at the given path (which must end in ".png", any
// case) and as an SVG beside it with the same stem (svg_path_for). Both go through temporary
// files "<name>.tmp-<pid>" and commit_output (qdo/data/io.hpp), so a failure leaves neither file
// half-written and an OutputStage stages both. The SVG keeps every text as a <text> element;
// images in it are PNG <image> elements with the same cells as the PNG's (block-averaged, the
// mean of the finite values of each block, only beyond 4 Mi cells in all).
//
// Array arguments, all dense and row-major (C order):
//   PlotSeries::x, y       n values each (n >= 1, same n); point i is (x[i], y[i]).
//   PlotSeries::y_low/high either both empty or both n values: the interval [y_low[i], y_high[i]]
//                          at x[i] (error bars for points_only series, a shaded band for lines).
//   ImagePlot::values      Map2D, rows x cols, element (y, x) at data[y * cols + x]. Row 0 is drawn
//                          at the top, column 0 at the left.
//   MontagePlot::stack     RealStack, planes x rows x cols, element (p, y, x) at
//                          data[(p * rows + y) * cols + x]; one panel per plane, each drawn as
//                          ImagePlot draws a Map2D. panel_titles holds one title per plane.
//
// Extents (ImagePlot, MontagePlot): x_min..x_max and y_min..y_max are the outer pixel edges in
// physical units; the y axis then increases upwards, so row 0 lies at the y_max side. An axis
// whose min and max are both 0 shows pixel indices instead (pixel centres at 0, 1, ...; the
// y axis then increases downwards, row 0 at the top).
//
// Values: non-finite points (and any beyond +-1e300) are left out of lines, bands and error
// bars; a log axis leaves out values <= 0. A plot with nothing left to draw shows its axes and
// "no finite values". In images such pixels stay blank (white); on a log colour scale values
// below max * 10^-log_decades (zero and negative ones included) take the lowest colour. Tick
// labels carry their own magnitude (e.g. "2.5×10^-6"), never a separate axis factor.
//
// Text is UTF-8 and drawn literally (PLplot's escape character '#' is escaped). Units belong in
// the labels, e.g. "object distance (m)", "PSNR (dB)".
//
// Errors: bad input throws InputError naming the argument and the value (empty series, x/y size
// mismatch, a missing title or label, a path not ending in .png, a folder that does not exist)
// before anything is drawn or written. A PLplot installation without the "svg" device or the
// cairo ones ("pngcairo", "memcairo"; Debian: plplot-driver-cairo) throws Error, as does a
// failure inside PLplot. Calls are serialised (PLplot keeps global state); any thread may call.
#pragma once
#include <cstddef>
#include <string>
#include <vector>

#include "qdo/runtime/types.hpp"

namespace qdo {

// One curve (or set of points) of a line plot, named in the legend by label.
struct PlotSeries {
  std::string label;                  // legend entry; required
  std::vector<double> x, y;           // n points each
  std::vector<double> y_low, y_high;  // optional interval: both empty or both n values
  bool points_only = false;           // markers (and error bars) instead of a line (and a band)
};

// One panel: axes, curves and a legend.
struct LinePlot {
  std::string title, x_label, y_label;  // all required; units in the axis labels
  std::vector<PlotSeries> series;       // at least one
  bool log_x = false, log_y = false;    // base-10 axes
  std::vector<double> hlines;           // dashed gray reference lines at these y values (e.g. 0 dB)
};

// A value image with a colour bar (viridis colour map).
struct ImagePlot {
  std::string title, x_label, y_label, value_label;   // all required; value_label names the colour bar
  Map2D values;                                       // rows x cols, row 0 at the top
  double x_min = 0, x_max = 0, y_min = 0, y_max = 0;  // outer pixel edges; (0, 0) = pixel index
  bool log_scale = false;                             // colours by log10(value)
  double log_decades = 4;                             // log colour range [max * 10^-decades, max]
};

// A grid of image panels sharing one colour scale and one colour bar.
struct MontagePlot {
  std::string title, x_label, y_label, value_label;   // all required
  RealStack stack;                                    // planes x rows x cols, one panel per plane
  std::vector<std::string> panel_titles;              // one per plane (e.g. "450 nm")
  double x_min = 0, x_max = 0, y_min = 0, y_max = 0;  // as ImagePlot, for every panel
  bool log_scale = true;
  double log_decades = 4;
  bool per_panel_max = true;    // each panel divided by its own maximum (PSFs); else one scale
  std::size_t max_panels = 36;  // more planes: this many, evenly spaced, first and last included
};

// Colour cells an SVG holds for all its images together (embedded as PNG <image> elements).
inline constexpr std::size_t kSvgImageCells = std::size_t{1} << 22;

// The SVG written beside png_path: the same stem with extension ".svg" (InputError when
// png_path does not end in .png).
std::string svg_path_for(const std::string& png_path);

// One panel: 800 x 500 px.
void write_line_plot(const std::string& png_path, const LinePlot& plot);
// Panels stacked vertically, each with its own title, axes and legend, under an overall title.
void write_line_panels(const std::string& png_path, const std::string& title, const std::vector<LinePlot>& panels);
// One image with a colour bar labelled value_label.
void write_image_plot(const std::string& png_path, const ImagePlot& plot);
// Up to max_panels panels in a near-square grid with one colour bar labelled value_label.
void write_montage_plot(const std::string& png_path, const MontagePlot& plot);

}  // namespace qdo

// ---------- Figures of the kinds qdo writes, built on the writers above ----------
namespace qdo {

// The outer edges [lo, hi] of n samples at `pitch` whose sample n / 2 sits at 0 (qdo's centre
// convention for PSF windows, crops and height maps), for the extents above.
inline void centred_extent(std::size_t n, double pitch, double& lo, double& hi) {
  lo = -(double(n / 2) + 0.5) * pitch;
  hi = lo + double(n) * pitch;
}

// A PSF stack (planes x rows x cols at pitch_m): the central crop x crop of each plane (0 = whole),
// one panel per plane titled by its wavelength (wavelengths_nm: one per plane, or empty: "plane k"),
// log colour scale of 4 decades, each panel divided by its own maximum, axes in µm from the centre.
void write_psf_figure(const std::string& png_path, const std::string& title, const RealStack& stack,
                      const std::vector<double>& wavelengths_nm, double pitch_m, std::size_t crop = 0);
// The same with a title per panel (panel_titles: one per plane, e.g. an object point); the axes are
// "x (µm)" and "y (µm)", or "x from ORIGIN (µm)" when `origin` names where 0 lies.
void write_psf_panels(const std::string& png_path, const std::string& title, const RealStack& stack,
                      const std::vector<std::string>& panel_titles, double pitch_m, std::size_t crop = 0,
                      const std::string& origin = "");
// A height map (rows x cols, metres, at pitch_m): colours in nm, axes in mm from the centre.
// value_label names the colour bar ("height (nm)", "height error (nm)", ...).
void write_height_figure(const std::string& png_path, const std::string& title, const Map2D& height_m, double pitch_m,
                         const std::string& value_label = "height (nm)");
// One curve per series against 0, 1, 2, ... (x_label names what the index counts), each named
// in the legend by labels[k]; log y when every finite value is positive.
void write_index_plot(const std::string& png_path, const std::string& title, const std::string& x_label, const std::string& y_label,
                      const std::vector<std::vector<double>>& series, const std::vector<std::string>& labels);

}  // namespace qdo
