// PNG files read as their stored code values through libpng's low-level (png_read_*) API. The
// simplified API (png_image_*) converts 16-bit samples to linear light when a file carries a
// gAMA, sRGB, cHRM or iCCP chunk (ImageMagick writes gAMA by default), which would turn a raw
// capture's 12-bit codes into gamma-decoded values; this reader applies no colour or gamma
// transform at all: what the file stores is what the caller gets.
#include <png.h>

#include <csetjmp>
#include <cstdio>
#include <cstring>
#include <filesystem>

#include "data/io_internal.hpp"
#include "qdo/runtime/error.hpp"

namespace qdo::io_detail {
namespace {

struct ErrorText {
  char text[512] = {0};
  bool refused = false;  // the header check refused the file (text is the whole problem)
};

void on_error(png_structp png, png_const_charp msg) {
  auto* e = static_cast<ErrorText*>(png_get_error_ptr(png));
  std::snprintf(e->text, sizeof e->text, "%s", msg ? msg : "libpng error");
  png_longjmp(png, 1);
}
void on_warning(png_structp, png_const_charp) {}

// What the header declares, after the expansions below.
struct Header {
  png_uint_32 width = 0, height = 0;
  int bit_depth = 0, channels = 0, colour_type = 0, interlace = 0;
  bool palette = false, trns = false;
};

// The one function that holds a setjmp: only trivially destructible locals live here, and every
// C++ object it fills (the pixel and row vectors) belongs to the caller, so a longjmp from libpng
// skips no destructor. Returns false with e.text set on a libpng error; `check` runs on the
// header (before any pixel buffer is allocated) and refuses by writing e.text.
bool decode(std::FILE* fp, ErrorText& e, Header& h, std::vector<std::uint16_t>& samples, std::vector<png_bytep>& rows,
            std::vector<unsigned char>& bytes, bool (*check)(const Header&, const void*, ErrorText&), const void* ctx) {
  png_structp png = png_create_read_struct(PNG_LIBPNG_VER_STRING, &e, on_error, on_warning);
  if (!png) {
    std::snprintf(e.text, sizeof e.text, "out of memory");
    return false;
  }
  png_infop info = png_create_info_struct(png);
  if (!info) {
    png_destroy_read_struct(&png, nullptr, nullptr);
    std::snprintf(e.text, sizeof e.text, "out of memory");
    return false;
  }
  if (setjmp(png_jmpbuf(png))) {
    png_destroy_read_struct(&png, &info, nullptr);
    return false;
  }
  png_init_io(png, fp);
  png_set_user_limits(png, 1u << 20, 1u << 20);
  png_read_info(png, info);
  h.colour_type = png_get_color_type(png, info);
  h.bit_depth = png_get_bit_depth(png, info);
  h.interlace = png_get_interlace_type(png, info);
  h.palette = h.colour_type == PNG_COLOR_TYPE_PALETTE;
  h.trns = png_get_valid(png, info, PNG_INFO_tRNS) != 0;
  // Expansions that keep the stored codes: a palette to its RGB entries, 1/2/4-bit gray to 8-bit
  // codes (scaled to 0..255 by libpng's bit replication), tRNS to an alpha channel; 16-bit
  // samples to host byte order. No gamma, no colour conversion.
  if (h.palette) png_set_palette_to_rgb(png);
  if (h.colour_type == PNG_COLOR_TYPE_GRAY && h.bit_depth < 8) png_set_expand_gray_1_2_4_to_8(png);
  if (h.trns) png_set_tRNS_to_alpha(png);
  if (h.bit_depth == 16) png_set_swap(png);
  png_set_interlace_handling(png);
  png_read_update_info(png, info);
  h.width = png_get_image_width(png, info);
  h.height = png_get_image_height(png, info);
  h.channels = png_get_channels(png, info);
  h.bit_depth = png_get_bit_depth(png, info);
  if (!check(h, ctx, e)) {
    e.refused = true;
    png_destroy_read_struct(&png, &info, nullptr);
    return false;
  }
  const std::size_t row_bytes = png_get_rowbytes(png, info);
  rows.resize(h.height);
  if (h.bit_depth == 16) {
    samples.resize(std::size_t(h.height) * h.width * std::size_t(h.channels));
    for (png_uint_32 y = 0; y < h.height; ++y)
      rows[y] = reinterpret_cast<png_bytep>(samples.data() + std::size_t(y) * h.width * std::size_t(h.channels));
  } else {
    bytes.resize(std::size_t(h.height) * row_bytes);
    for (png_uint_32 y = 0; y < h.height; ++y) rows[y] = bytes.data() + std::size_t(y) * row_bytes;
  }
  png_read_image(png, rows.data());
  png_read_end(png, nullptr);
  png_destroy_read_struct(&png, &info, nullptr);
  return true;
}

struct CheckCtx {
  std::uintmax_t file_bytes;
};

bool check_header(const Header& h, const void* ctx, ErrorText& e) {
  const auto& c = *static_cast<const CheckCtx*>(ctx);
  const std::uintmax_t w = h.width, rows = h.height;
  if (w == 0 || rows == 0 || w * rows > (std::uintmax_t{1} << 28)) {
    std::snprintf(e.text, sizeof e.text, "header declares %ju x %ju pixels (rows x columns); at most 2^28 are accepted", rows, w);
    return false;
  }
  // Each row holds a filter byte and at least 1 bit per pixel, deflated at most ~1032:1.
  if (rows * (1 + (w + 7) / 8) > c.file_bytes * kMaxExpansion + kSlackBytes) {
    std::snprintf(e.text, sizeof e.text, "header declares %ju x %ju pixels but the file has only %ju bytes: truncated or corrupt",
                  rows, w, c.file_bytes);
    return false;
  }
  return true;
}

struct FileCloser {
  void operator()(std::FILE* f) const { std::fclose(f); }
};

}  // namespace

PngCodes read_png_codes(const std::string& path) {
  require_file(path);
  std::error_code ec;
  const std::uintmax_t size = std::filesystem::file_size(path, ec);
  std::unique_ptr<std::FILE, FileCloser> fp(std::fopen(path.c_str(), "rb"));
  if (!fp || ec) fail(path, "", "cannot be opened for reading");
  unsigned char sig[8] = {0};
  if (std::fread(sig, 1, 8, fp.get()) != 8 || png_sig_cmp(sig, 0, 8) != 0) fail(path, "", "not a readable PNG file (no PNG signature)");
  std::rewind(fp.get());
  ErrorText e;
  Header h;
  std::vector<std::uint16_t> samples;
  std::vector<png_bytep> rows;
  std::vector<unsigned char> bytes;
  const CheckCtx ctx{size};
  if (!decode(fp.get(), e, h, samples, rows, bytes, check_header, &ctx)) {
    if (e.refused) fail(path, "", e.text);
    fail(path, "", std::string("not a readable PNG file, or truncated or corrupt (") + e.text + ")");
  }
  PngCodes out;
  out.width = h.width;
  out.height = h.height;
  out.channels = std::size_t(h.channels);
  out.bit_depth = h.bit_depth;
  out.has_alpha = h.channels == 2 || h.channels == 4;
  out.from_palette = h.palette;
  if (h.bit_depth == 16) {
    out.samples = std::move(samples);
  } else {
    out.samples.resize(out.width * out.height * out.channels);
    const std::size_t rb = out.width * out.channels;  // 8-bit samples after the expansions: rows are unpadded
    for (std::size_t y = 0; y < out.height; ++y)
      for (std::size_t i = 0; i < rb; ++i) out.samples[y * rb + i] = rows[y][i];
  }
  return out;
}

}  // namespace qdo::io_detail
