// 16-bit grayscale PNG frames (raw captures): read and write the code values unchanged.
#include <png.h>

#include <cmath>
#include <cstring>
#include <filesystem>

#include "data/io_internal.hpp"
#include "qdo/error.hpp"
#include "qdo/io.hpp"

namespace qdo {
using namespace io_detail;

// libpng's simplified API: a 16-bit file without a gAMA chunk (or with gamma 1) is linear and
// decoded to PNG_FORMAT_LINEAR_Y unchanged; an 8-bit file is widened (v * 257) by libpng, so it is
// refused here (a raw frame is 16-bit).
Map2D read_png16_gray(const std::string& path) {
  require_file(path);
  png_image img;
  std::memset(&img, 0, sizeof img);
  img.version = PNG_IMAGE_VERSION;
  if (!png_image_begin_read_from_file(&img, path.c_str())) {
    const std::string msg = img.message;
    png_image_free(&img);
    fail(path, "", "not a readable PNG file (" + msg + ")");
  }
  const bool sixteen = (img.format & PNG_FORMAT_FLAG_LINEAR) != 0;
  const bool colour = (img.format & (PNG_FORMAT_FLAG_COLOR | PNG_FORMAT_FLAG_ALPHA)) != 0;
  const std::size_t w = img.width, h = img.height;
  if (!sixteen || colour) {
    png_image_free(&img);
    fail(path, "", std::string("a raw frame must be a 16-bit grayscale PNG; this one is ") + (sixteen ? "16" : "8") +
                       "-bit " + (colour ? "colour or with alpha" : "grayscale"));
  }
  std::error_code ec;
  const std::uintmax_t bytes = std::filesystem::file_size(path, ec);
  if (w == 0 || h == 0 || w * h > (std::uintmax_t{1} << 28) || ec || h * (1 + 2 * w) > bytes * kMaxExpansion + kSlackBytes) {
    png_image_free(&img);
    fail(path, "", "header declares " + std::to_string(h) + " x " + std::to_string(w) +
                       " pixels: empty, larger than 2^28 pixels, or more than the file can hold (truncated or corrupt)");
  }
  img.format = PNG_FORMAT_LINEAR_Y;
  std::vector<png_uint_16> buf(w * h);
  if (!png_image_finish_read(&img, nullptr, buf.data(), 0, nullptr)) {
    const std::string msg = img.message;
    png_image_free(&img);
    fail(path, "", "cannot decode the PNG data, truncated or corrupt file (" + msg + ")");
  }
  png_image_free(&img);
  Map2D m(h, w);
  for (std::size_t i = 0; i < w * h; ++i) m.data[i] = buf[i];
  return m;
}

namespace {

// planes (1 or 3) x rows x cols integer code values -> a 16-bit PNG (grayscale or RGB), written then
// renamed; a value that is not an integer in [0, 65535] is refused naming the file.
void write_png16_planes(const std::string& path, const std::vector<double>& data, std::size_t planes, std::size_t rows,
                        std::size_t cols) {
  for (double v : data)
    if (!(v >= 0 && v <= 65535 && v == std::floor(v)))
      reject("16-bit PNG value", v, "integer code values in [0, 65535] (file '" + path + "')");
  const std::size_t n = rows * cols;
  std::vector<png_uint_16> buf(n * planes);
  for (std::size_t i = 0; i < n; ++i)
    for (std::size_t c = 0; c < planes; ++c) buf[i * planes + c] = static_cast<png_uint_16>(data[c * n + i]);
  AtomicFile out(path);
  png_image img;
  std::memset(&img, 0, sizeof img);
  img.version = PNG_IMAGE_VERSION;
  img.width = static_cast<png_uint_32>(cols);
  img.height = static_cast<png_uint_32>(rows);
  img.format = planes == 3 ? PNG_FORMAT_LINEAR_RGB : PNG_FORMAT_LINEAR_Y;
  const int ok = png_image_write_to_file(&img, out.tmp().c_str(), 0, buf.data(), 0, nullptr);
  const std::string msg = img.message;
  png_image_free(&img);
  if (!ok) fail(path, "", "PNG write failed: " + msg);
  out.commit();
}

}  // namespace

void write_png16_gray(const std::string& path, const Map2D& dn) { write_png16_planes(path, dn.data, 1, dn.rows, dn.cols); }

// A capture: 16-bit grayscale (1 plane) or RGB (3 planes), code values unchanged. libpng's
// simplified API gives a 16-bit file (without gAMA, or gamma 1) as linear values; an 8-bit file
// (widened by libpng) and one with alpha are refused, naming the file.
RealStack read_png16(const std::string& path) {
  require_file(path);
  png_image img;
  std::memset(&img, 0, sizeof img);
  img.version = PNG_IMAGE_VERSION;
  if (!png_image_begin_read_from_file(&img, path.c_str())) {
    const std::string msg = img.message;
    png_image_free(&img);
    fail(path, "", "not a readable PNG file (" + msg + ")");
  }
  const bool sixteen = (img.format & PNG_FORMAT_FLAG_LINEAR) != 0;
  const bool colour = (img.format & PNG_FORMAT_FLAG_COLOR) != 0, alpha = (img.format & PNG_FORMAT_FLAG_ALPHA) != 0;
  const std::size_t w = img.width, h = img.height, ch = colour ? 3 : 1;
  if (!sixteen || alpha) {
    png_image_free(&img);
    fail(path, "", std::string("a capture must be a 16-bit grayscale (raw mosaic) or 16-bit RGB PNG without alpha; this one is ") +
                       (sixteen ? "16" : "8") + "-bit" + (alpha ? " with alpha" : ""));
  }
  std::error_code ec;
  const std::uintmax_t bytes = std::filesystem::file_size(path, ec);
  if (w == 0 || h == 0 || w * h > (std::uintmax_t{1} << 28) || ec || h * (1 + 2 * ch * w) > bytes * kMaxExpansion + kSlackBytes) {
    png_image_free(&img);
    fail(path, "", "header declares " + std::to_string(h) + " x " + std::to_string(w) +
                       " pixels: empty, larger than 2^28 pixels, or more than the file can hold (truncated or corrupt)");
  }
  img.format = colour ? PNG_FORMAT_LINEAR_RGB : PNG_FORMAT_LINEAR_Y;
  std::vector<png_uint_16> buf(w * h * ch);
  if (!png_image_finish_read(&img, nullptr, buf.data(), 0, nullptr)) {
    const std::string msg = img.message;
    png_image_free(&img);
    fail(path, "", "cannot decode the PNG data, truncated or corrupt file (" + msg + ")");
  }
  png_image_free(&img);
  RealStack out(ch, h, w);
  for (std::size_t i = 0; i < w * h; ++i)
    for (std::size_t c = 0; c < ch; ++c) out.data[c * w * h + i] = buf[i * ch + c];
  return out;
}

void write_png16_rgb(const std::string& path, const RealStack& dn3) {
  if (dn3.planes != 3) reject("16-bit RGB PNG planes", dn3.planes, "3 (file '" + path + "')");
  write_png16_planes(path, dn3.data, 3, dn3.rows, dn3.cols);
}

}  // namespace qdo
