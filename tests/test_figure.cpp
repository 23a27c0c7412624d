// Tests of the figures (src/data/figure.cpp): every kind is written as a valid PNG and an SVG
// beside it whose text elements hold the title, the axis labels, the legend entries and the
// colour bar label; bad input is refused before anything is written; no temporary file stays.
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "svg_text.hpp"
#include "io_common.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/figure.hpp"

namespace fs = std::filesystem;
using namespace qdo;
using qdo::test::io_suite::TmpDir;

using namespace qdo::test;

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

std::string read_all(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

template <typename F>
std::string input_error(F&& f) {
  try {
    f();
  } catch (const InputError& e) {
    return e.what();
  }
  return "<no InputError thrown>";
}

bool has(const std::string& s, const std::string& part) { return s.find(part) != std::string::npos; }

// Width and height from the IHDR chunk of a PNG file; zero when the signature is wrong.
struct PngSize {
  std::uint32_t width = 0, height = 0;
};
PngSize png_size(const std::string& path) {
  const std::string b = read_all(path);
  static const unsigned char sig[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  PngSize s;
  if (b.size() < 33 || !std::equal(sig, sig + 8, reinterpret_cast<const unsigned char*>(b.data())) ||
      b.compare(12, 4, "IHDR") != 0)
    return s;
  auto be32 = [&](std::size_t o) {
    std::uint32_t v = 0;
    for (std::size_t i = 0; i < 4; ++i) v = (v << 8) | static_cast<unsigned char>(b[o + i]);
    return v;
  };
  s.width = be32(16);
  s.height = be32(20);
  return s;
}

bool has_text(const std::vector<std::string>& texts, const std::string& t) {
  return std::find(texts.begin(), texts.end(), t) != texts.end();
}

// The PNG is valid and has the given size (0: any), the SVG exists beside it and holds each of
// `texts` as a whole <text> element, and the folder holds no temporary file.
void check_figure(const std::string& png, const std::vector<std::string>& texts, std::uint32_t width = 0,
                  std::uint32_t height = 0) {
  CAPTURE(png);
  const PngSize s = png_size(png);
  CHECK(s.width > 0);
  if (width) CHECK(s.width == width);
  if (height) CHECK(s.height == height);
  const std::string svg = svg_path_for(png);
  REQUIRE(fs::is_regular_file(svg));
  CHECK(has(read_all(svg), "<svg"));
  const std::vector<std::string> found = svg_texts(svg);
  for (const std::string& t : texts) {
    CAPTURE(t);
    CHECK(has_text(found, t));
  }
  for (const auto& e : fs::directory_iterator(fs::path(png).parent_path()))
    CHECK_MESSAGE(!has(e.path().filename().string(), ".tmp-"), e.path().string());
}

std::vector<double> linspace(double a, double b, std::size_t n) {
  std::vector<double> v(n);
  for (std::size_t i = 0; i < n; ++i) v[i] = a + (b - a) * static_cast<double>(i) / static_cast<double>(n - 1);
  return v;
}

LinePlot two_series_plot() {
  LinePlot p;
  p.title = "PSNR against object distance";
  p.x_label = "object distance (m)";
  p.y_label = "PSNR (dB)";
  PlotSeries a, b;
  a.label = "design #b (µ-lens)";  // "#b" is a PLplot escape unless escaped
  b.label = "baseline";
  a.x = b.x = linspace(0.5, 5, 20);
  for (double x : a.x) {
    a.y.push_back(30 - 2 * std::log(x));
    b.y.push_back(25 - std::log(x));
  }
  p.series = {a, b};
  return p;
}

// A Gaussian spot of width sigma (pixels) centred at (cy, cx), rows x cols.
std::vector<double> spot(std::size_t rows, std::size_t cols, double cy, double cx, double sigma) {
  std::vector<double> v(rows * cols);
  for (std::size_t y = 0; y < rows; ++y)
    for (std::size_t x = 0; x < cols; ++x) {
      const double dy = static_cast<double>(y) - cy, dx = static_cast<double>(x) - cx;
      v[y * cols + x] = std::exp(-(dx * dx + dy * dy) / (2 * sigma * sigma));
    }
  return v;
}

}  // namespace

TEST_SUITE("figure") {
  TEST_CASE("the SVG is the PNG's stem with .svg") {
    CHECK(svg_path_for("out/fig.png") == "out/fig.svg");
    CHECK(svg_path_for("FIG.PNG") == "FIG.svg");
    CHECK(svg_path_for("a.b/c.d.png") == "a.b/c.d.svg");
    CHECK(has(input_error([] { svg_path_for("fig.jpg"); }), "png_path"));
  }

  TEST_CASE("a line plot names its title, axes and every series") {
    TmpDir tmp;
    const std::string png = tmp / "psnr.png";
    const LinePlot p = two_series_plot();
    write_line_plot(png, p);
    check_figure(png, {p.title, p.x_label, p.y_label, "design #b (µ-lens)", "baseline"}, 800, 500);
    CHECK(tmp.entries() == 2);
    write_line_plot(png, p);  // written again: replaced, still two files
    CHECK(tmp.entries() == 2);
  }

  TEST_CASE("log axes, intervals, reference lines and invalid values") {
    TmpDir tmp;
    LinePlot p;
    p.title = "MTF";
    p.x_label = "spatial frequency (cycles/mm)";
    p.y_label = "contrast";
    p.log_x = true;
    p.log_y = true;
    p.hlines = {0.1, -1.0};  // the negative one is left out on a log axis
    PlotSeries band, bars;
    band.label = "mean over seeds";
    bars.label = "measured";
    bars.points_only = true;
    band.x = bars.x = linspace(1, 100, 15);
    for (double f : band.x) {
      band.y.push_back(std::exp(-f / 40));
      band.y_low.push_back(0.8 * std::exp(-f / 40));
      band.y_high.push_back(1.2 * std::exp(-f / 40));
    }
    bars.y = band.y;
    bars.y_low = band.y_low;
    bars.y_high = band.y_high;
    band.y[3] = kNaN;  // a gap in the line
    band.y[7] = -1;    // not drawable on a log axis
    bars.x[0] = 0;     // idem
    bars.y_high[4] = std::numeric_limits<double>::infinity();
    p.series = {band, bars};
    const std::string png = tmp / "mtf.png";
    write_line_plot(png, p);
    check_figure(png, {"MTF", "spatial frequency (cycles/mm)", "contrast", "mean over seeds", "measured"});
  }

  TEST_CASE("a plot with nothing drawable shows its axes and says so") {
    TmpDir tmp;
    LinePlot p;
    p.title = "empty";
    p.x_label = "x (m)";
    p.y_label = "y (m)";
    p.log_y = true;
    PlotSeries s;
    s.label = "nothing";
    s.x = {1, 2, kNaN, 4};
    s.y = {0, -1, 3, 1e308};  // beyond +-1e300: left out like a non-finite value
    p.series = {s};
    const std::string png = tmp / "empty.png";
    write_line_plot(png, p);
    check_figure(png, {"empty", "x (m)", "y (m)", "nothing", "no finite values"});

    PlotSeries h;  // values up to +-1e300 span 2e300 and still get ticks
    h.label = "huge";
    h.x = {-1e300, 1e300};
    h.y = {1e300, -1e300};
    p.series = {h};
    p.log_y = false;
    write_line_plot(png, p);
    check_figure(png, {"huge"});

    PlotSeries c;  // a constant series: a widened range, no division by zero
    c.label = "constant";
    c.x = {2, 2, 2};
    c.y = {5, 5, 5};
    p.series = {c};
    p.log_y = false;
    write_line_plot(png, p);
    check_figure(png, {"constant"});
  }

  TEST_CASE("stacked panels keep every panel's title, labels and legend") {
    TmpDir tmp;
    std::vector<LinePlot> panels(3, two_series_plot());
    panels[0].title = "red channel";
    panels[1].title = "green channel";
    panels[2].title = "blue channel";
    panels[2].y_label = "SSIM";
    panels[2].hlines = {28};
    const std::string png = tmp / "panels.png";
    write_line_panels(png, "Sweep over object distance", panels);
    check_figure(png,
                 {"Sweep over object distance", "red channel", "green channel", "blue channel", "SSIM", "PSNR (dB)",
                  "object distance (m)", "baseline"},
                 800, 50 + 3 * 330);
    CHECK(tmp.entries() == 2);
  }

  TEST_CASE("an image has a colour bar labelled with the value and its units") {
    TmpDir tmp;
    ImagePlot p;
    p.title = "DOE height map";
    p.x_label = "x (mm)";
    p.y_label = "y (mm)";
    p.value_label = "height (µm)";
    p.values = Map2D(40, 60);
    for (std::size_t y = 0; y < 40; ++y)
      for (std::size_t x = 0; x < 60; ++x) p.values(y, x) = 0.6 * std::sin(0.2 * double(x)) * std::cos(0.1 * double(y));
    p.values(3, 4) = kNaN;  // left blank
    p.x_min = -1.5;
    p.x_max = 1.5;
    p.y_min = -1;
    p.y_max = 1;
    const std::string png = tmp / "height.png";
    write_image_plot(png, p);
    check_figure(png, {"DOE height map", "x (mm)", "y (mm)", "height (µm)"});

    // Pixel indices and a log colour scale.
    ImagePlot q = p;
    q.x_min = q.x_max = q.y_min = q.y_max = 0;
    q.log_scale = true;
    q.log_decades = 3;
    q.title = "PSF (log)";
    q.x_label = "column (px)";
    q.y_label = "row (px)";
    q.value_label = "intensity (a.u.)";
    q.values.data = spot(40, 60, 12, 20, 3);
    const std::string png2 = tmp / "psf.png";
    write_image_plot(png2, q);
    check_figure(png2, {"PSF (log)", "column (px)", "row (px)", "intensity (a.u.)"});

    q.values.data.assign(q.values.data.size(), -1.0);  // nothing positive on a log scale
    write_image_plot(png2, q);
    check_figure(png2, {"no positive values"});
    CHECK(tmp.entries() == 4);
  }

  TEST_CASE("an image is embedded in the SVG as one PNG with every cell, not drawn cell by cell") {
    TmpDir tmp;
    ImagePlot p;
    p.title = "large";
    p.x_label = "x (px)";
    p.y_label = "y (px)";
    p.value_label = "value (1)";
    p.values = Map2D(300, 280);
    p.values.data = spot(300, 280, 150, 140, 40);
    const std::string png = tmp / "large.png";
    write_image_plot(png, p);
    check_figure(png, {"large"});
    const std::string svg = read_all(svg_path_for(png));
    std::size_t shapes = 0;
    for (std::size_t pos = 0; (pos = svg.find("<polyline", pos)) != std::string::npos; ++pos) ++shapes;
    CHECK(shapes < 600);  // the frame, ticks and colour bar only
    const std::string tag = "xlink:href=\"data:image/png;base64,";
    const std::size_t at = svg.find(tag);
    REQUIRE(at != std::string::npos);
    CHECK(svg.find(tag, at + 1) == std::string::npos);  // one image
    CHECK(svg.find("<image") < svg.find("<g"));          // under everything PLplot draws
    // The embedded PNG's size: its cells, rows x cols of the map.
    const std::string b64 = svg.substr(at + tag.size(), 64);
    auto val = [](char c) -> unsigned {
      if (c >= 'A' && c <= 'Z') return unsigned(c - 'A');
      if (c >= 'a' && c <= 'z') return unsigned(c - 'a' + 26);
      if (c >= '0' && c <= '9') return unsigned(c - '0' + 52);
      return c == '+' ? 62u : 63u;
    };
    std::vector<unsigned char> head;
    for (std::size_t i = 0; i + 3 < b64.size(); i += 4) {
      const unsigned v = (val(b64[i]) << 18) | (val(b64[i + 1]) << 12) | (val(b64[i + 2]) << 6) | val(b64[i + 3]);
      head.push_back(static_cast<unsigned char>(v >> 16));
      head.push_back(static_cast<unsigned char>(v >> 8));
      head.push_back(static_cast<unsigned char>(v));
    }
    REQUIRE(head.size() >= 24);
    auto be32 = [&](std::size_t o) { return (unsigned(head[o]) << 24) | (unsigned(head[o + 1]) << 16) | (unsigned(head[o + 2]) << 8) | head[o + 3]; };
    CHECK(head[1] == 'P');
    CHECK(be32(16) == 280u);  // width: columns
    CHECK(be32(20) == 300u);  // height: rows
  }

  TEST_CASE("a montage names every panel and shares one colour bar") {
    TmpDir tmp;
    MontagePlot p;
    p.title = "PSF stack";
    p.x_label = "x (µm)";
    p.y_label = "y (µm)";
    p.value_label = "intensity / panel max";
    p.stack = RealStack(5, 32, 32);
    for (std::size_t k = 0; k < 5; ++k) {
      const std::vector<double> s = spot(32, 32, 16, 16, 1.5 + double(k));
      for (std::size_t i = 0; i < s.size(); ++i) p.stack.data[k * 1024 + i] = (1 + double(k)) * s[i];
      p.panel_titles.push_back(std::to_string(450 + 50 * k) + " nm");
    }
    p.x_min = p.y_min = -40;
    p.x_max = p.y_max = 40;
    const std::string png = tmp / "montage.png";
    write_montage_plot(png, p);
    check_figure(png, {"PSF stack", "x (µm)", "y (µm)", "intensity / panel max", "450 nm", "550 nm", "650 nm"});

    // More planes than panels: evenly spaced, first and last, and the title says so.
    MontagePlot q = p;
    q.stack = RealStack(10, 8, 12, 1.0);
    q.panel_titles.clear();
    for (int k = 0; k < 10; ++k) q.panel_titles.push_back("band " + std::to_string(k));
    q.max_panels = 4;
    q.log_scale = false;
    q.per_panel_max = false;
    q.x_min = q.x_max = q.y_min = q.y_max = 0;
    write_montage_plot(png, q);
    check_figure(png, {"PSF stack (4 of 10 planes)", "band 0", "band 9"});
    const std::vector<std::string> texts = svg_texts(svg_path_for(png));
    CHECK_FALSE(has_text(texts, "band 1"));
    CHECK(tmp.entries() == 2);
  }

  TEST_CASE("bad input is refused naming the argument, and nothing is written") {
    TmpDir tmp;
    const std::string png = tmp / "bad.png";
    LinePlot p = two_series_plot();
    p.series[1].x.pop_back();
    std::string e = input_error([&] { write_line_plot(png, p); });
    CHECK(has(e, "plot.series[1].y"));
    CHECK(has(e, "'baseline'"));
    CHECK(has(e, "as many values as x (19)"));

    p = two_series_plot();
    p.series.clear();
    CHECK(has(input_error([&] { write_line_plot(png, p); }), "plot.series"));
    p = two_series_plot();
    p.series[0].x.clear();
    p.series[0].y.clear();
    CHECK(has(input_error([&] { write_line_plot(png, p); }), "plot.series[0].x"));
    p = two_series_plot();
    p.series[0].label.clear();
    CHECK(has(input_error([&] { write_line_plot(png, p); }), "plot.series[0].label"));
    p = two_series_plot();
    p.series[0].y_low = p.series[0].y;
    CHECK(has(input_error([&] { write_line_plot(png, p); }), "y_high"));
    p = two_series_plot();
    p.y_label.clear();
    CHECK(has(input_error([&] { write_line_plot(png, p); }), "plot.y_label"));

    p = two_series_plot();
    e = input_error([&] { write_line_plot(tmp / "bad.jpg", p); });
    CHECK(has(e, "png_path"));
    CHECK(has(e, "bad.jpg"));
    CHECK(has(input_error([&] { write_line_plot(tmp / "missing/fig.png", p); }), "png_path"));
    CHECK(has(input_error([&] { write_line_plot("", p); }), "png_path"));
    CHECK(has(input_error([&] { write_line_panels(png, "t", {}); }), "panels"));
    std::vector<LinePlot> panels{p, p};
    panels[1].title.clear();
    CHECK(has(input_error([&] { write_line_panels(png, "t", panels); }), "panels[1].title"));

    ImagePlot im;
    im.title = "t";
    im.x_label = "x (px)";
    im.y_label = "y (px)";
    im.value_label = "v (1)";
    im.values = Map2D(4, 5);
    im.values.data.pop_back();
    CHECK(has(input_error([&] { write_image_plot(png, im); }), "plot.values.data"));
    im.values = Map2D(4, 5);
    im.x_min = 2;
    im.x_max = 1;
    CHECK(has(input_error([&] { write_image_plot(png, im); }), "plot.x_min"));
    im.x_min = im.x_max = 0;
    im.log_scale = true;
    im.log_decades = 0;
    CHECK(has(input_error([&] { write_image_plot(png, im); }), "plot.log_decades"));
    im.log_scale = false;
    im.value_label.clear();
    CHECK(has(input_error([&] { write_image_plot(png, im); }), "plot.value_label"));

    MontagePlot m;
    m.title = "t";
    m.x_label = "x (px)";
    m.y_label = "y (px)";
    m.value_label = "v (1)";
    m.stack = RealStack(3, 4, 4, 1.0);
    m.panel_titles = {"a", "b"};
    CHECK(has(input_error([&] { write_montage_plot(png, m); }), "plot.panel_titles"));
    m.panel_titles = {"a", "b", "c"};
    m.max_panels = 0;
    CHECK(has(input_error([&] { write_montage_plot(png, m); }), "plot.max_panels"));
    m.max_panels = 4;
    m.stack = RealStack();
    CHECK(has(input_error([&] { write_montage_plot(png, m); }), "plot.stack"));

    CHECK(tmp.entries() == 0);  // no figure, no temporary file
  }

  TEST_CASE("figures may be written from several threads") {
    TmpDir tmp;
    const LinePlot p = two_series_plot();
    std::vector<std::thread> threads;
    for (int t = 0; t < 4; ++t)
      threads.emplace_back([&, t] { write_line_plot(tmp / ("t" + std::to_string(t) + ".png"), p); });
    for (auto& th : threads) th.join();
    for (int t = 0; t < 4; ++t) check_figure(tmp / ("t" + std::to_string(t) + ".png"), {p.title}, 800, 500);
    CHECK(tmp.entries() == 8);
  }
}
