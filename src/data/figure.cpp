// Figures drawn with PLplot: each is rendered twice, with the "pngcairo" device to the PNG and
// with the "svg" device (text kept as <text>) to the SVG beside it, each into a temporary file
// that commit_output moves into place. See include/qdo/figure.hpp.
#include "qdo/figure.hpp"

#include <plplot.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cctype>
#include <cerrno>
#include <climits>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

#include "qdo/error.hpp"
#include "qdo/io.hpp"

namespace qdo {
namespace {
namespace fs = std::filesystem;

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Values drawn: finite and within +-1e300 (beyond, ranges and tick intervals overflow).
constexpr double kHuge = 1e300;
bool drawable(double v) { return std::isfinite(v) && std::fabs(v) <= kHuge; }

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
// PLplot session: one mutex, one fresh stream per file
// ---------------------------------------------------------------------------------------

std::mutex g_plplot_mutex;     // PLplot keeps global state: one figure at a time
bool g_plplot_exited = false;  // set when PLplot called its exit handler
std::string g_plplot_message;  // the first error PLplot reported in the current stream

// PLplot's fatal errors (plexit) end the process unless the handler does not return: it
// throws, and the stream left behind is abandoned, never ended.
int on_plplot_exit(const char* message) {
  g_plplot_exited = true;
  throw Error(std::string("figure: PLplot failed: ") + (message ? message : "unknown error"));
}

// PLplot's recoverable errors (plabort) are recorded and fail the figure once its stream ends.
void on_plplot_abort(const char* message) {
  if (g_plplot_message.empty()) g_plplot_message = message ? message : "unknown error";
}

PLINT pl_int(std::size_t n) {
  if (n > static_cast<std::size_t>(INT_MAX))
    throw Error("figure: too many values for PLplot (" + std::to_string(n) + ")");
  return static_cast<PLINT>(n);
}

void require_device(const char* device) {
  constexpr int kMaxDevices = 256;
  std::vector<const char*> menu(kMaxDevices + 1, nullptr), names(kMaxDevices + 1, nullptr);
  const char** menu_p = menu.data();
  const char** names_p = names.data();
  int n = kMaxDevices;
  try {
    plgDevs(&menu_p, &names_p, &n);
  } catch (const Error& e) {
    throw Error(std::string(e.what()) + " (Debian: install plplot-driver-cairo)");
  }
  for (int i = 0; i < n && i < kMaxDevices; ++i)
    if (names_p[i] && std::strcmp(names_p[i], device) == 0) return;
  throw Error(std::string("figure: PLplot has no '") + device +
              "' output device (Debian: install plplot-driver-cairo; PLplot looks in PLPLOT_DRV_DIR)");
}

// PLplot's exit and abort handlers, installed for a scope (a figure, under the mutex).
class Handlers {
 public:
  Handlers() {
    g_plplot_exited = false;
    g_plplot_message.clear();
    plsexit(&on_plplot_exit);
    plsabort(&on_plplot_abort);
  }
  Handlers(const Handlers&) = delete;
  Handlers& operator=(const Handlers&) = delete;
  ~Handlers() {
    plsexit(nullptr);
    plsabort(nullptr);
  }
};

// One PLplot stream; ended (plend1) and the previous stream made current again on scope exit.
class Stream {
 public:
  Stream() {
    plgstrm(&previous_);
    g_plplot_message.clear();
    plmkstrm(&id_);
    if (id_ < 0) throw Error("figure: PLplot has no free stream");
  }
  Stream(const Stream&) = delete;
  Stream& operator=(const Stream&) = delete;
  ~Stream() {
    if (!g_plplot_exited && !ended_) plend1();
    plsstrm(previous_);
  }
  // Ends the stream (its file is complete); throws when PLplot reported an error.
  void end() {
    plend1();
    ended_ = true;
    if (!g_plplot_message.empty()) throw Error("figure: PLplot reported an error: " + g_plplot_message);
  }

 private:
  PLINT previous_ = 0, id_ = -1;
  bool ended_ = false;
};

// Geometry: PLplot's cairo and svg devices map 72 px to 25.4 mm. Text has one height in every
// figure, whatever its size (PLplot's default grows with the page).
constexpr double kPxPerMm = 72.0 / 25.4;
constexpr double kCharMm = 4.6;  // character height: 13 px
constexpr double kCharPx = kCharMm * kPxPerMm;
constexpr double kDigitWidth = 0.9;  // width of a digit, in character heights

// The page after plinit: size in mm.
struct Page {
  double w_mm = 1, h_mm = 1;
  double fx(double chars) const { return chars * kCharMm / w_mm; }  // character heights -> page x
  double fy(double chars) const { return chars * kCharMm / h_mm; }  // character heights -> page y
};

// Colour map 0 entries.
constexpr PLINT kBackground = 0, kInk = 1, kGrid = 2, kReference = 3, kSeries0 = 4;
constexpr std::array<std::array<int, 3>, 10> kSeriesRgb = {{{31, 119, 180},
                                                            {255, 127, 14},
                                                            {44, 160, 44},
                                                            {214, 39, 40},
                                                            {148, 103, 189},
                                                            {140, 86, 75},
                                                            {227, 119, 194},
                                                            {127, 127, 127},
                                                            {188, 189, 34},
                                                            {23, 190, 207}}};
constexpr PLINT kBand0 = kSeries0 + static_cast<PLINT>(kSeriesRgb.size());
constexpr PLINT kColours = kBand0 + static_cast<PLINT>(kSeriesRgb.size());

// Viridis control points (matplotlib's map at 0, 1/8, ..., 1).
constexpr std::array<std::array<double, 3>, 9> kViridis = {{{68, 1, 84},
                                                            {71, 45, 123},
                                                            {59, 82, 139},
                                                            {44, 114, 142},
                                                            {33, 145, 140},
                                                            {40, 174, 128},
                                                            {94, 201, 98},
                                                            {173, 220, 48},
                                                            {253, 231, 37}}};

void set_colours() {
  plscmap0n(kColours);
  plscol0(kBackground, 255, 255, 255);
  plscol0(kInk, 0, 0, 0);
  plscol0(kGrid, 222, 222, 222);
  plscol0(kReference, 100, 100, 100);
  for (std::size_t i = 0; i < kSeriesRgb.size(); ++i) {
    const auto& c = kSeriesRgb[i];
    plscol0(kSeries0 + static_cast<PLINT>(i), c[0], c[1], c[2]);
    plscol0a(kBand0 + static_cast<PLINT>(i), c[0], c[1], c[2], 0.22);
  }
  std::array<double, kViridis.size()> pos{}, r{}, g{}, b{};
  for (std::size_t i = 0; i < kViridis.size(); ++i) {
    pos[i] = static_cast<double>(i) / static_cast<double>(kViridis.size() - 1);
    r[i] = kViridis[i][0] / 255;
    g[i] = kViridis[i][1] / 255;
    b[i] = kViridis[i][2] / 255;
  }
  plscmap1n(256);
  plscmap1l(1, static_cast<PLINT>(kViridis.size()), pos.data(), r.data(), g.data(), b.data(), nullptr);
}

// Starts a page of w x h px on the current stream (device and output already set).
Page begin_page(int w, int h) {
  plspage(0, 0, w, h, 0, 0);
  plscolbg(255, 255, 255);
  plinit();
  set_colours();
  plschr(kCharMm, 1.0);
  pladv(0);
  double x0 = 0, x1 = 0, y0 = 0, y1 = 0;
  plgspa(&x0, &x1, &y0, &y1);
  plcol0(kInk);
  return Page{x1 - x0, y1 - y0};
}

// Renders one page of w x h px with `draw` into `file` on `device`.
void render(const char* device, const std::string& file, int w, int h, const std::function<void(const Page&)>& draw) {
  Stream stream;
  plsdev(device);
  plsfnam(file.c_str());
  const Page page = begin_page(w, h);
  draw(page);
  stream.end();
}

// Renders `draw` on a throwaway page of w x h px, for measuring what PLplot draws: the two
// devices measure text differently (cairo from the font, svg from PLplot's own metrics).
void render_to_measure(bool svg, int w, int h, const std::function<void(const Page&)>& draw) {
  std::vector<unsigned char> pixels;
  Stream stream;
  if (svg) {
    plsdev("svg");
    plsfnam("/dev/null");
  } else {
    pixels.resize(static_cast<std::size_t>(w) * static_cast<std::size_t>(h) * 4);
    plsdev("memcairo");
    plsmema(w, h, pixels.data());
  }
  const Page page = begin_page(w, h);
  draw(page);
  stream.end();
}

// Temporary outputs "<name>.tmp-<pid>": removed on scope exit unless committed.
class TempOutputs {
 public:
  explicit TempOutputs(const std::string& png_path) : finals_{png_path, svg_path_for(png_path)} {
    const std::string suffix = ".tmp-" + std::to_string(static_cast<long>(::getpid()));
    for (std::size_t i = 0; i < 2; ++i) {
      temps_[i] = finals_[i] + suffix;
      // Created here, so that PLplot never meets a file it cannot open (it would prompt for one).
      std::ofstream probe(temps_[i], std::ios::binary | std::ios::trunc);
      if (!probe) {
        const std::string why = std::strerror(errno);
        if (i == 1) std::remove(temps_[0].c_str());
        throw InputError("file '" + finals_[i] + "': cannot be written (" + why + ")");
      }
    }
  }
  TempOutputs(const TempOutputs&) = delete;
  TempOutputs& operator=(const TempOutputs&) = delete;
  ~TempOutputs() {
    for (std::size_t i = 0; i < 2; ++i)
      if (!committed_[i]) std::remove(temps_[i].c_str());
  }
  const std::string& png() const { return temps_[0]; }
  const std::string& svg() const { return temps_[1]; }
  void commit() {
    for (std::size_t i = 0; i < 2; ++i) {
      commit_output(temps_[i], finals_[i]);
      committed_[i] = true;
    }
  }

 private:
  std::array<std::string, 2> finals_, temps_;
  std::array<bool, 2> committed_{{false, false}};
};

// Runs `measure` (PLplot measurements on throwaway pages), then draws the figure with
// `draw(page, svg)` to the PNG and to the SVG and moves both into place.
void write_figure(const std::string& png_path, const std::function<void()>& measure, int w, int h,
                  const std::function<void(const Page&, bool)>& draw) {
  wait_if_abandoned();
  const std::lock_guard<std::mutex> lock(g_plplot_mutex);
  const Handlers handlers;
  require_device("pngcairo");
  require_device("svg");
  require_device("memcairo");  // measurements
  measure();
  TempOutputs out(png_path);
  render("pngcairo", out.png(), w, h, [&](const Page& p) { draw(p, false); });
  render("svg", out.svg(), w, h, [&](const Page& p) { draw(p, true); });
  out.commit();
}

// ---------------------------------------------------------------------------------------
// Text, ranges and ticks
// ---------------------------------------------------------------------------------------

// PLplot text: '#' starts an escape sequence, "##" is a literal '#'.
std::string pl_text(const std::string& s) {
  std::string t;
  t.reserve(s.size());
  for (char c : s) {
    t += c;
    if (c == '#') t += '#';
  }
  return t;
}

// Text centred above the viewport, `disp` character heights out, at `scale` times the height.
void text_top(double disp, double scale, const std::string& s) {
  plschr(0, scale);
  plmtex("t", disp, 0.5, 0.5, pl_text(s).c_str());
  plschr(0, 1.0);
}

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
Range padded(Range r, bool log_axis) {
  if (r.empty()) return {0, 1};
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

// How the tick labels of a linear axis are written (by write_tick_label, PLplot's custom
// labels): fixed-point with the decimals the interval needs, or as mantissa x 10^exponent for
// very large or small values. Every label carries its own magnitude (no separate factor).
struct TickFormat {
  double step = 1;  // tick interval
  bool sci = false;
  int decimals = 0;  // fixed-point decimals
};

int decade(double v) { return static_cast<int>(std::floor(std::log10(v) + 1e-9)); }

TickFormat tick_format(const Range& w, double step) {
  TickFormat f;
  f.step = step;
  const double m = std::max(std::fabs(w.lo), std::fabs(w.hi));
  f.sci = m >= 1e6 || decade(step) < -4;
  f.decimals = std::max(0, -decade(step));
  return f;
}

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

// plbox with custom labels on the linear axes (option "o").
void draw_axes(const std::string& xopt, const TickFormat& x, bool log_x, const std::string& yopt, const TickFormat& y,
               bool log_y) {
  AxisLabels labels{x, y};
  plslabelfunc(&write_tick_label, &labels);
  plbox((xopt + (log_x ? "l" : "o")).c_str(), log_x ? 0 : x.step, 0, (yopt + (log_y ? "l" : "o")).c_str(),
        log_y ? 0 : y.step, 0);
  plslabelfunc(nullptr, nullptr);
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

// Distance, in character heights, of a y axis label from the axis: past the tick labels
// (tick_chars wide, in character heights at tick_scale).
double y_label_disp(double tick_chars, double tick_scale) { return 0.5 + tick_chars * tick_scale + 1.2; }

// ---------------------------------------------------------------------------------------
// Line plots
// ---------------------------------------------------------------------------------------

constexpr double kLegendScale = 0.9;       // legend text, relative to the character height
constexpr double kLegendPlotWidth = 0.07;  // legend line samples, in viewport widths
constexpr double kLegendGap = 0.02;        // between the axes and the legend, in viewport widths
constexpr double kTitleScale = 1.15;
constexpr const char* kMarkers[] = {"●", "■", "▲", "◆", "▼", "⬟"};
constexpr std::size_t kMarkerCount = sizeof(kMarkers) / sizeof(kMarkers[0]);

PLINT series_colour(std::size_t i) { return kSeries0 + static_cast<PLINT>(i % kSeriesRgb.size()); }
PLINT band_colour(std::size_t i) { return kBand0 + static_cast<PLINT>(i % kSeriesRgb.size()); }
PLINT series_style(std::size_t i) { return 1 + static_cast<PLINT>((i / kSeriesRgb.size()) % 8); }
const char* series_marker(std::size_t i) { return kMarkers[i % kMarkerCount]; }

// The plotted points of one series, log and finiteness applied.
struct Points {
  std::vector<double> x, y, lo, hi;
};

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

// What a line plot's layout depends on: its window, tick formats and y tick label width.
struct LineFrame {
  Range xw, yw;
  TickFormat x_ticks, y_ticks;  // linear axes
  double y_chars = 0;           // widest y tick label, in character heights
  bool nothing = false;         // no drawable point
};

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

// Left margin of a line plot, in character heights.
double line_left(const LineFrame& f) { return y_label_disp(f.y_chars, 1.0) + 1.5; }

constexpr int kLineW = 800, kLineH = 500;
constexpr int kPanelH = 330, kPanelsTitleH = 50;

// ---------------------------------------------------------------------------------------
// Images
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

// Cells a PNG draws for all its images together (beyond, block means).
constexpr std::size_t kPngImageCells = std::size_t{1} << 22;

// Colour scale: values as coloured (linear, or log10 clamped to the floor).
struct ColourScale {
  bool log = false;
  double floor = 0;        // log: smallest value coloured (max * 10^-decades)
  double lo = 0, hi = 1;   // colour range in coloured units
  bool valid = false;      // false: nothing to colour
  std::string empty_text;  // shown when not valid
};

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

double coloured(double v, const ColourScale& s) {
  if (!drawable(v)) return kNaN;
  if (!s.log) return v;
  return std::log10(std::max(v, s.floor));
}

// Draws a raster in the current viewport and window; non-finite cells stay blank.
void draw_raster(const Raster& r, const ColourScale& s) {
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

// Tick format of a linear colour bar: about 5 intervals.
TickFormat colour_bar_ticks(const ColourScale& s) { return tick_format({s.lo, s.hi}, nice_step(s.hi - s.lo, 5)); }

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

// An image's axes: world rectangle of the pixel grid and tick intervals.
struct ImageFrame {
  Axis x, y;
  Raster grid(std::size_t rows, std::size_t cols, std::vector<double> v) const {
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
  void window() const {
    if (y.pixel)
      plwind(x.lo, x.hi, y.hi, y.lo);
    else
      plwind(x.lo, x.hi, y.lo, y.hi);
  }
  // Height / width of the drawn image, kept within [1/4, 4].
  double aspect(std::size_t rows, std::size_t cols) const {
    const double a =
        (x.pixel || y.pixel) ? static_cast<double>(rows) / static_cast<double>(cols) : (y.hi - y.lo) / (x.hi - x.lo);
    return std::clamp(a, 0.25, 4.0);
  }
  // Tick formats for axes of w x h px with text at `scale`.
  TickFormat x_ticks(double w, double scale, double target) const {
    return fit_ticks({x.lo, x.hi}, w, scale, target, false);
  }
  TickFormat y_ticks(double h, double scale, double target) const {
    return fit_ticks({y.lo, y.hi}, h, scale, target, true);
  }
};

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
