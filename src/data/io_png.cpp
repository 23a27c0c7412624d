// PNG writing (libpng, through AtomicFile) and the figures: montage, RGB, height map.
#include <png.h>

#include <algorithm>
#include <cmath>
#include <cstring>

#include "data/io_internal.hpp"
#include "qdo/error.hpp"
#include "qdo/io.hpp"

namespace qdo {
using namespace io_detail;
namespace {

struct Rgb {
  double r, g, b;
};

// Approximate colour of a visible wavelength (piecewise linear, after D. Bruton), with the
// intensity fading towards the ends of 380..780 nm; outside that range a neutral gray.
Rgb wavelength_rgb(double nm) {
  if (!(nm >= 380 && nm <= 780)) return {0.7, 0.7, 0.7};
  Rgb c{0, 0, 0};
  if (nm < 440) c = {(440 - nm) / 60, 0, 1};
  else if (nm < 490) c = {0, (nm - 440) / 50, 1};
  else if (nm < 510) c = {0, 1, (510 - nm) / 20};
  else if (nm < 580) c = {(nm - 510) / 70, 1, 0};
  else if (nm < 645) c = {1, (645 - nm) / 65, 0};
  else c = {1, 0, 0};
  double f = 1;
  if (nm < 420) f = 0.3 + 0.7 * (nm - 380) / 40;
  else if (nm > 700) f = 0.3 + 0.7 * (780 - nm) / 80;
  return {c.r * f, c.g * f, c.b * f};
}

unsigned char to_byte(double v01) {
  const double v = std::clamp(v01, 0.0, 1.0);
  return static_cast<unsigned char>(std::lround(v * 255.0));
}

double srgb_encode(double v) { return v <= 0.0031308 ? 12.92 * v : 1.055 * std::pow(v, 1 / 2.4) - 0.055; }

// An output about to be written: NaN or Inf is a NumericalError (nothing is written).
void require_finite_output(const std::string& path, const std::string& what, const std::vector<double>& v) {
  const std::size_t bad = count_nonfinite(v);
  if (bad)
    throw NumericalError("file '" + path + "': " + what + ": " + std::to_string(bad) + " of " + std::to_string(v.size()) +
                         " values are NaN or Inf; not written");
}

// One tile of a montage: plane p of stack cropped to (y0, x0, h, w), box-averaged by factor f.
// Returns a (ceil(h/f) x ceil(w/f)) row-major image.
std::vector<double> tile_of(const RealStack& s, std::size_t p, std::size_t y0, std::size_t x0, std::size_t h,
                            std::size_t w, std::size_t f, std::size_t th, std::size_t tw) {
  std::vector<double> t(th * tw, 0.0);
  for (std::size_t ty = 0; ty < th; ++ty)
    for (std::size_t tx = 0; tx < tw; ++tx) {
      double sum = 0;
      std::size_t cnt = 0;
      for (std::size_t y = ty * f; y < std::min(h, ty * f + f); ++y)
        for (std::size_t x = tx * f; x < std::min(w, tx * f + f); ++x, ++cnt) sum += s(p, y0 + y, x0 + x);
      t[ty * tw + tx] = cnt ? sum / static_cast<double>(cnt) : 0.0;
    }
  return t;
}

}  // namespace

// =========================================================================================
// PNG
// =========================================================================================

// pixels: height rows of width * channels bytes, interleaved (RGBRGB... or gray).
void write_png(const std::string& path, std::size_t width, std::size_t height, int channels,
               const std::vector<unsigned char>& pixels) {
  if (channels != 1 && channels != 3) reject("channels", channels, "1 (gray) or 3 (RGB)");
  const std::size_t max_dim = 0x7fffffffu;
  if (width == 0 || height == 0 || width > max_dim || height > max_dim)
    reject("png size", std::to_string(width) + " x " + std::to_string(height), "1 .. 2^31-1 pixels per side");
  const std::size_t ch = static_cast<std::size_t>(channels);
  if (pixels.size() != width * height * ch)
    reject("pixels", pixels.size(), "width * height * channels = " + std::to_string(width * height * ch) + " bytes");
  AtomicFile out(path);
  png_image img;
  std::memset(&img, 0, sizeof img);
  img.version = PNG_IMAGE_VERSION;
  img.width = static_cast<png_uint_32>(width);
  img.height = static_cast<png_uint_32>(height);
  img.format = channels == 1 ? PNG_FORMAT_GRAY : PNG_FORMAT_RGB;
  img.flags = PNG_IMAGE_FLAG_FAST;  // faster zlib settings: figures write ~3x faster, files ~20 % larger
  const int ok = png_image_write_to_file(&img, out.tmp().c_str(), 0, pixels.data(),
                                         static_cast<png_int_32>(width * ch), nullptr);
  const std::string msg = img.message;
  png_image_free(&img);
  if (!ok) fail(path, "", "PNG write failed: " + msg);
  out.commit();
}

// stack: planes x rows x cols; one tile per plane.
void write_montage_png(const std::string& path, const RealStack& stack, const std::vector<double>& wavelengths_nm,
                       double gamma, std::size_t crop) {
  const std::size_t P = stack.planes;
  if (P == 0 || stack.rows == 0 || stack.cols == 0 || stack.data.size() != P * stack.rows * stack.cols)
    reject("stack", std::to_string(P) + " x " + std::to_string(stack.rows) + " x " + std::to_string(stack.cols),
           "a non-empty stack whose data matches its shape");
  if (!wavelengths_nm.empty() && wavelengths_nm.size() != P)
    reject("wavelengths_nm", wavelengths_nm.size(), "empty or one per plane (" + std::to_string(P) + ")");
  if (!(gamma > 0) || !std::isfinite(gamma)) reject("gamma", gamma, "a finite value > 0");
  require_finite_output(path, "montage data", stack.data);
  const std::size_t h = crop ? std::min(crop, stack.rows) : stack.rows;
  const std::size_t w = crop ? std::min(crop, stack.cols) : stack.cols;
  const std::size_t y0 = (stack.rows - h) / 2, x0 = (stack.cols - w) / 2;
  const std::size_t grid_cols = static_cast<std::size_t>(std::ceil(std::sqrt(static_cast<double>(P))));
  const std::size_t grid_rows = (P + grid_cols - 1) / grid_cols;
  const std::size_t max_tile = std::max<std::size_t>(16, std::min<std::size_t>(256, 4096 / grid_cols));
  const std::size_t f = (std::max(h, w) + max_tile - 1) / max_tile;  // box-average factor
  const std::size_t th = (h + f - 1) / f, tw = (w + f - 1) / f, gap = 2;
  const std::size_t W = grid_cols * tw + (grid_cols - 1) * gap, H = grid_rows * th + (grid_rows - 1) * gap;
  std::vector<unsigned char> px(W * H * 3, 0);
  for (std::size_t p = 0; p < P; ++p) {
    const std::vector<double> t = tile_of(stack, p, y0, x0, h, w, f, th, tw);
    const double mx = *std::max_element(t.begin(), t.end());
    const Rgb tint = wavelengths_nm.empty() ? Rgb{1, 1, 1} : wavelength_rgb(wavelengths_nm[p]);
    const std::size_t oy = (p / grid_cols) * (th + gap), ox = (p % grid_cols) * (tw + gap);
    for (std::size_t y = 0; y < th; ++y)
      for (std::size_t x = 0; x < tw; ++x) {
        const double v = mx > 0 ? std::pow(std::max(t[y * tw + x], 0.0) / mx, gamma) : 0.0;
        unsigned char* q = &px[((oy + y) * W + ox + x) * 3];
        q[0] = to_byte(v * tint.r);
        q[1] = to_byte(v * tint.g);
        q[2] = to_byte(v * tint.b);
      }
  }
  write_png(path, W, H, 3, px);
}

// rgb3: 3 x H x W (planes R, G, B), linear values.
void write_rgb_png(const std::string& path, const RealStack& rgb3) {
  if (rgb3.planes != 3 || rgb3.rows == 0 || rgb3.cols == 0 || rgb3.data.size() != 3 * rgb3.rows * rgb3.cols)
    reject("rgb stack", std::to_string(rgb3.planes) + " x " + std::to_string(rgb3.rows) + " x " + std::to_string(rgb3.cols),
           "a non-empty 3 x H x W stack");
  require_finite_output(path, "rgb data", rgb3.data);
  std::vector<double> sorted = rgb3.data;
  const std::size_t k = std::min(sorted.size() - 1, static_cast<std::size_t>(0.999 * static_cast<double>(sorted.size())));
  std::nth_element(sorted.begin(), sorted.begin() + static_cast<std::ptrdiff_t>(k), sorted.end());
  double ref = sorted[k];
  if (!(ref > 0)) ref = *std::max_element(rgb3.data.begin(), rgb3.data.end());
  if (!(ref > 0)) ref = 1;
  const std::size_t n = rgb3.plane_size();
  std::vector<unsigned char> px(n * 3);
  for (std::size_t i = 0; i < n; ++i)
    for (std::size_t c = 0; c < 3; ++c) px[i * 3 + c] = to_byte(srgb_encode(std::clamp(rgb3.data[c * n + i] / ref, 0.0, 1.0)));
  write_png(path, rgb3.cols, rgb3.rows, 3, px);
}

// m: rows x cols, row-major.
void write_map_png(const std::string& path, const Map2D& m) {
  if (m.rows == 0 || m.cols == 0 || m.data.size() != m.rows * m.cols)
    reject("map", std::to_string(m.rows) + " x " + std::to_string(m.cols), "a non-empty map whose data matches its shape");
  require_finite_output(path, "map data", m.data);
  static const Rgb viridis[] = {{68, 1, 84},    {71, 45, 123},  {59, 82, 139},  {44, 114, 142}, {33, 145, 140},
                                {40, 174, 128}, {94, 201, 98},  {173, 220, 48}, {253, 231, 37}};
  const std::size_t na = sizeof(viridis) / sizeof(viridis[0]);
  const auto [lo_it, hi_it] = std::minmax_element(m.data.begin(), m.data.end());
  const double lo = *lo_it, span = *hi_it - *lo_it;
  std::vector<unsigned char> px(m.data.size() * 3);
  for (std::size_t i = 0; i < m.data.size(); ++i) {
    const double t = span > 0 ? (m.data[i] - lo) / span : 0.5;
    const double pos = t * static_cast<double>(na - 1);
    const std::size_t a = std::min(na - 2, static_cast<std::size_t>(pos));
    const double u = pos - static_cast<double>(a);
    const Rgb& c0 = viridis[a];
    const Rgb& c1 = viridis[a + 1];
    px[i * 3 + 0] = to_byte((c0.r + u * (c1.r - c0.r)) / 255);
    px[i * 3 + 1] = to_byte((c0.g + u * (c1.g - c0.g)) / 255);
    px[i * 3 + 2] = to_byte((c0.b + u * (c1.b - c0.b)) / 255);
  }
  write_png(path, m.cols, m.rows, 3, px);
}

}  // namespace qdo
