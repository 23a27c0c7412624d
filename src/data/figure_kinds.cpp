// Figures of the kinds qdo writes (figure.hpp, second part): PSF stacks, height maps and curves
// against an index, each a thin layer over the general writers.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "qdo/runtime/error.hpp"
#include "qdo/data/figure.hpp"

namespace qdo {

namespace {

std::string nm_title(double nm) {
  char b[32];
  std::snprintf(b, sizeof b, "%g nm", nm);
  return b;
}

}  // namespace

void write_psf_panels(const std::string& png_path, const std::string& title, const RealStack& stack,
                      const std::vector<std::string>& panel_titles, double pitch_m, std::size_t crop, const std::string& origin) {
  if (panel_titles.size() != stack.planes)
    reject("panel_titles", to_str(panel_titles.size()) + " titles", "one per plane (" + to_str(stack.planes) + ")");
  if (!(pitch_m > 0)) reject("pitch_m", pitch_m, "> 0");
  const std::size_t h = crop ? std::min(crop, stack.rows) : stack.rows, w = crop ? std::min(crop, stack.cols) : stack.cols;
  const std::size_t y0 = (stack.rows - h) / 2, x0 = (stack.cols - w) / 2;
  MontagePlot m;
  m.title = title;
  m.x_label = origin.empty() ? "x (µm)" : "x from " + origin + " (µm)";
  m.y_label = origin.empty() ? "y (µm)" : "y from " + origin + " (µm)";
  m.value_label = "PSF / panel maximum";
  m.stack = RealStack(stack.planes, h, w);
  for (std::size_t p = 0; p < stack.planes; ++p)
    for (std::size_t y = 0; y < h; ++y)
      for (std::size_t x = 0; x < w; ++x) m.stack(p, y, x) = stack(p, y0 + y, x0 + x);
  m.panel_titles = panel_titles;
  centred_extent(w, pitch_m * 1e6, m.x_min, m.x_max);
  centred_extent(h, pitch_m * 1e6, m.y_min, m.y_max);
  write_montage_plot(png_path, m);
}

void write_psf_figure(const std::string& png_path, const std::string& title, const RealStack& stack,
                      const std::vector<double>& wavelengths_nm, double pitch_m, std::size_t crop) {
  if (!wavelengths_nm.empty() && wavelengths_nm.size() != stack.planes)
    reject("wavelengths_nm", to_str(wavelengths_nm.size()) + " values", "one per plane (" + to_str(stack.planes) + ") or none");
  std::vector<std::string> titles;
  for (std::size_t p = 0; p < stack.planes; ++p) titles.push_back(wavelengths_nm.empty() ? "plane " + to_str(p) : nm_title(wavelengths_nm[p]));
  write_psf_panels(png_path, title, stack, titles, pitch_m, crop);
}

void write_height_figure(const std::string& png_path, const std::string& title, const Map2D& height_m, double pitch_m,
                         const std::string& value_label) {
  if (!(pitch_m > 0)) reject("pitch_m", pitch_m, "> 0");
  ImagePlot im;
  im.title = title;
  im.x_label = "x (mm)";
  im.y_label = "y (mm)";
  im.value_label = value_label;
  im.values = height_m;
  for (double& v : im.values.data) v *= 1e9;
  centred_extent(height_m.cols, pitch_m * 1e3, im.x_min, im.x_max);
  centred_extent(height_m.rows, pitch_m * 1e3, im.y_min, im.y_max);
  write_image_plot(png_path, im);
}

void write_index_plot(const std::string& png_path, const std::string& title, const std::string& x_label, const std::string& y_label,
                      const std::vector<std::vector<double>>& series, const std::vector<std::string>& labels) {
  if (labels.size() != series.size()) reject("labels", to_str(labels.size()) + " labels", "one per series (" + to_str(series.size()) + ")");
  LinePlot lp;
  lp.title = title;
  lp.x_label = x_label;
  lp.y_label = y_label;
  bool positive = true, any = false;
  for (std::size_t k = 0; k < series.size(); ++k) {
    PlotSeries s;
    s.label = labels[k];
    for (std::size_t i = 0; i < series[k].size(); ++i) {
      s.x.push_back(double(i));
      s.y.push_back(series[k][i]);
      if (std::isfinite(series[k][i])) {
        any = true;
        positive = positive && series[k][i] > 0;
      }
    }
    s.points_only = series[k].size() == 1;
    lp.series.push_back(s);
  }
  lp.log_y = any && positive;
  write_line_plot(png_path, lp);
}

}  // namespace qdo
