// The PLplot side of the figure module: one figure at a time under a mutex, PLplot's exit and
// abort handlers turned into exceptions, one fresh stream per file, and each figure rendered
// twice (the "pngcairo" device to the PNG, the "svg" device, text kept as <text>, to the SVG
// beside it), each into a temporary file that commit_output moves into place.
#include <plplot.h>
#include <png.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <cmath>
#include <climits>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <functional>
#include <mutex>
#include <sstream>
#include <string>
#include <vector>

#include "data/figure_internal.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/figure.hpp"
#include "qdo/data/io.hpp"

namespace qdo::figure_detail {
namespace {

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

// Throws Error unless PLplot has the output device `device` (a driver it found).
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

}  // namespace

RasterSink*& raster_sink() {
  static RasterSink* sink = nullptr;  // guarded by the module's PLplot mutex, as every figure
  return sink;
}

// The raster's cells as colours, and its edges in page pixels (the current viewport and window).
PendingRaster pending_raster(const Raster& r, const ColourScale& s, const RasterSink& sink) {
  double vx0 = 0, vx1 = 0, vy0 = 0, vy1 = 0, wx0 = 0, wx1 = 0, wy0 = 0, wy1 = 0;
  plgvpd(&vx0, &vx1, &vy0, &vy1);
  plgvpw(&wx0, &wx1, &wy0, &wy1);
  auto px = [&](double x) { return (vx0 + (x - wx0) / (wx1 - wx0) * (vx1 - vx0)) * sink.page_w; };
  auto py = [&](double y) { return (1 - (vy0 + (y - wy0) / (wy1 - wy0) * (vy1 - vy0))) * sink.page_h; };
  PendingRaster p;
  p.px0 = px(r.x0);
  p.px1 = px(r.x1);
  // Row 0 of r.v lies at the y1 side when top_is_y1, else at the y0 side; py0 is the top edge.
  p.py0 = std::min(py(r.y0), py(r.y1));
  p.py1 = std::max(py(r.y0), py(r.y1));
  const bool row0_top = r.top_is_y1 == (py(r.y1) < py(r.y0));
  p.rows = r.rows;
  p.cols = r.cols;
  p.rgba.resize(r.rows * r.cols);
  for (std::size_t y = 0; y < r.rows; ++y)
    for (std::size_t x = 0; x < r.cols; ++x) {
      const double c = coloured(r.v[y * r.cols + x], s);
      auto& out = p.rgba[(row0_top ? y : r.rows - 1 - y) * r.cols + x];
      if (!std::isfinite(c)) {
        out = {0, 0, 0, 0};
        continue;
      }
      const auto rgb = viridis((std::clamp(c, s.lo, s.hi) - s.lo) / (s.hi - s.lo));
      out = {rgb[0], rgb[1], rgb[2], 255};
    }
  return p;
}

std::array<unsigned char, 3> viridis(double t) {
  if (!(t >= 0)) t = 0;
  if (t > 1) t = 1;
  const double at = t * static_cast<double>(kViridis.size() - 1);
  const std::size_t i = std::min(kViridis.size() - 2, static_cast<std::size_t>(at));
  const double f = at - static_cast<double>(i);
  std::array<unsigned char, 3> c{};
  for (std::size_t k = 0; k < 3; ++k)
    c[k] = static_cast<unsigned char>(std::lround(kViridis[i][k] + f * (kViridis[i + 1][k] - kViridis[i][k])));
  return c;
}

namespace {

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

// Sets raster_sink() to `sink` for one pass, and back to none on leaving it (also on an error).
struct SinkScope {
  explicit SinkScope(RasterSink& sink) { raster_sink() = &sink; }
  ~SinkScope() { raster_sink() = nullptr; }
  SinkScope(const SinkScope&) = delete;
  SinkScope& operator=(const SinkScope&) = delete;
};

// The PNG pass: PLplot draws into an RGBA page in memory ("memcairo"), the sink's rasters are
// painted over the pixels PLplot left as background, and the page is written as an RGB PNG.
void render_png(const std::string& file, int w, int h, const std::function<void(const Page&)>& draw) {
  const std::size_t W = static_cast<std::size_t>(w), H = static_cast<std::size_t>(h);
  std::vector<unsigned char> rgba(W * H * 4, 255);
  RasterSink sink;
  sink.page_w = w;
  sink.page_h = h;
  {
    Stream stream;
    plsdev("memcairo");
    plsmema(w, h, rgba.data());
    const Page page = begin_page(w, h);
    const SinkScope scope(sink);
    draw(page);
    stream.end();
  }
  for (const PendingRaster& r : sink.rasters) {
    const long x0 = std::max(0L, std::lround(r.px0)), x1 = std::min(long(W), std::lround(r.px1));
    const long y0 = std::max(0L, std::lround(r.py0)), y1 = std::min(long(H), std::lround(r.py1));
    for (long y = y0; y < y1; ++y)
      for (long x = x0; x < x1; ++x) {
        unsigned char* px = &rgba[(std::size_t(y) * W + std::size_t(x)) * 4];
        if (px[0] != 255 || px[1] != 255 || px[2] != 255) continue;  // PLplot drew here: frame, tick, text
        const std::size_t cy = std::min(r.rows - 1, std::size_t((double(y) + 0.5 - r.py0) / (r.py1 - r.py0) * double(r.rows)));
        const std::size_t cx = std::min(r.cols - 1, std::size_t((double(x) + 0.5 - r.px0) / (r.px1 - r.px0) * double(r.cols)));
        const auto& c = r.rgba[cy * r.cols + cx];
        if (c[3] == 0) continue;
        px[0] = c[0];
        px[1] = c[1];
        px[2] = c[2];
      }
  }
  std::vector<unsigned char> rgb(W * H * 3);
  for (std::size_t i = 0; i < W * H; ++i)
    for (std::size_t c = 0; c < 3; ++c) rgb[i * 3 + c] = rgba[i * 4 + c];
  write_png(file, W, H, 3, rgb);
}

// A raster's cells as an RGBA PNG in memory (libpng's simplified API).
std::vector<unsigned char> png_bytes(const PendingRaster& r) {
  std::vector<unsigned char> pixels(r.rows * r.cols * 4);
  for (std::size_t i = 0; i < r.rgba.size(); ++i) std::copy(r.rgba[i].begin(), r.rgba[i].end(), pixels.begin() + long(i * 4));
  png_image img;
  std::memset(&img, 0, sizeof img);
  img.version = PNG_IMAGE_VERSION;
  img.width = static_cast<png_uint_32>(r.cols);
  img.height = static_cast<png_uint_32>(r.rows);
  img.format = PNG_FORMAT_RGBA;
  img.flags = PNG_IMAGE_FLAG_FAST;  // faster zlib settings, as write_png
  png_alloc_size_t size = 0;
  if (!png_image_write_to_memory(&img, nullptr, &size, 0, pixels.data(), 0, nullptr)) throw Error("figure: PNG encoding failed");
  std::vector<unsigned char> out(size);
  if (!png_image_write_to_memory(&img, out.data(), &size, 0, pixels.data(), 0, nullptr)) throw Error("figure: PNG encoding failed");
  out.resize(size);
  png_image_free(&img);
  return out;
}

std::string base64(const std::vector<unsigned char>& in) {
  static const char* const k = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  out.reserve((in.size() + 2) / 3 * 4);
  for (std::size_t i = 0; i < in.size(); i += 3) {
    const unsigned v = (unsigned(in[i]) << 16) | (i + 1 < in.size() ? unsigned(in[i + 1]) << 8 : 0u) | (i + 2 < in.size() ? unsigned(in[i + 2]) : 0u);
    out += k[(v >> 18) & 63];
    out += k[(v >> 12) & 63];
    out += i + 1 < in.size() ? k[(v >> 6) & 63] : '=';
    out += i + 2 < in.size() ? k[v & 63] : '=';
  }
  return out;
}

// The SVG pass: PLplot writes everything but the rasters, which go into the file as <image>
// elements (each raster's cells as an embedded PNG, drawn without smoothing) right after the
// page's background, so the frame, ticks and text lie on top of them.
void render_svg(const std::string& file, int w, int h, const std::function<void(const Page&)>& draw) {
  RasterSink sink;
  sink.page_w = w;
  sink.page_h = h;
  {
    Stream stream;
    plsdev("svg");
    plsfnam(file.c_str());
    const Page page = begin_page(w, h);
    const SinkScope scope(sink);
    draw(page);
    stream.end();
  }
  if (sink.rasters.empty()) return;
  std::string svg;
  {
    std::ifstream in(file, std::ios::binary);
    std::ostringstream ss;
    ss << in.rdbuf();
    svg = ss.str();
  }
  const std::size_t rect = svg.find("<rect");
  const std::size_t at = rect == std::string::npos ? std::string::npos : svg.find("/>", rect);
  if (at == std::string::npos) throw Error("figure: the SVG device wrote no page background to place the images after");
  std::string images;
  for (const PendingRaster& r : sink.rasters) {
    char box[160];
    std::snprintf(box, sizeof box, "  <image x=\"%.2f\" y=\"%.2f\" width=\"%.2f\" height=\"%.2f\" preserveAspectRatio=\"none\" ",
                  r.px0, r.py0, r.px1 - r.px0, r.py1 - r.py0);
    images += std::string("\n") + box + "style=\"image-rendering:pixelated\" xlink:href=\"data:image/png;base64," +
              base64(png_bytes(r)) + "\"/>";
  }
  svg.insert(at + 2, images);
  std::ofstream out(file, std::ios::binary | std::ios::trunc);
  out << svg;
  if (!out) throw Error("figure: cannot write '" + file + "'");
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

}  // namespace

PLINT pl_int(std::size_t n) {
  if (n > static_cast<std::size_t>(INT_MAX))
    throw Error("figure: too many values for PLplot (" + std::to_string(n) + ")");
  return static_cast<PLINT>(n);
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

// Runs `measure` (PLplot measurements on throwaway pages), then draws the figure with
// `draw(page, svg)` to the PNG and to the SVG and moves both into place.
void write_figure(const std::string& png_path, const std::function<void()>& measure, int w, int h,
                  const std::function<void(const Page&, bool)>& draw) {
  wait_if_abandoned();
  const std::lock_guard<std::mutex> lock(g_plplot_mutex);
  const Handlers handlers;
  require_device("svg");
  require_device("memcairo");  // the PNG page and the measurements
  measure();
  TempOutputs out(png_path);
  render_png(out.png(), w, h, [&](const Page& p) { draw(p, false); });
  render_svg(out.svg(), w, h, [&](const Page& p) { draw(p, true); });
  out.commit();
}

// ---------------------------------------------------------------------------------------
// Text
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

}  // namespace qdo::figure_detail
