// 16-bit grayscale PNG frames (raw captures): read and write the code values unchanged.
#include <png.h>

#include <cmath>
#include <cstring>
#include <filesystem>

#include "data/io_internal.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"

namespace qdo {
using namespace io_detail;

// The stored 16-bit codes (read_png_codes: no gamma transform, whatever gAMA, sRGB, cHRM or iCCP
// chunk the file carries). An 8-bit, colour, palette or alpha file is refused: a raw frame is
// 16-bit grayscale.
Map2D read_png16_gray(const std::string& path) {
  const PngCodes p = read_png_codes(path);
  if (p.bit_depth != 16 || p.channels != 1)
    fail(path, "", std::string("a raw frame must be a 16-bit grayscale PNG; this one is ") + (p.from_palette ? "a palette" : std::to_string(p.bit_depth) + "-bit") +
                       " " + (p.channels == 1 ? "grayscale" : "colour or with alpha") + " file");
  Map2D m(p.height, p.width);
  for (std::size_t i = 0; i < m.data.size(); ++i) m.data[i] = p.samples[i];
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

// A capture: 16-bit grayscale (1 plane) or RGB (3 planes), the stored codes (read_png_codes: no
// gamma transform). An 8-bit, palette or alpha file is refused, naming the file.
RealStack read_png16(const std::string& path) {
  const PngCodes p = read_png_codes(path);
  if (p.bit_depth != 16 || p.has_alpha || p.from_palette)
    fail(path, "", std::string("a capture must be a 16-bit grayscale (raw mosaic) or 16-bit RGB PNG without alpha; this one is ") +
                       (p.from_palette ? "a palette file" : std::to_string(p.bit_depth) + "-bit") + (p.has_alpha ? " with alpha" : ""));
  const std::size_t ch = p.channels, n = p.width * p.height;
  RealStack out(ch, p.height, p.width);
  for (std::size_t i = 0; i < n; ++i)
    for (std::size_t c = 0; c < ch; ++c) out.data[c * n + i] = p.samples[i * ch + c];
  return out;
}

void write_png16_rgb(const std::string& path, const RealStack& dn3) {
  if (dn3.planes != 3) reject("16-bit RGB PNG planes", dn3.planes, "3 (file '" + path + "')");
  write_png16_planes(path, dn3.data, 3, dn3.rows, dn3.cols);
}

}  // namespace qdo
