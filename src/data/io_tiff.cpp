// 16-bit TIFF captures (raw mosaics and RGB frames as lab cameras save them), read with libtiff:
// code values unchanged; and the extension dispatch of read_capture16 (io.hpp).
#include <tiffio.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdarg>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "data/io_internal.hpp"
#include "data/io_tiff_internal.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"
#include "qdo/data/io_raw.hpp"

namespace qdo {
using namespace io_detail;

namespace {

std::string lower_extension(const std::string& path) {
  std::string ext = std::filesystem::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  return ext;
}

}  // namespace

bool is_tiff_path(const std::string& path) {
  const std::string e = lower_extension(path);
  return e == ".tif" || e == ".tiff";
}

// One image (the first directory): 16 bits per sample, unsigned, 1 (grayscale or a mosaic) or 3
// (RGB) samples per pixel, chunky (interleaved) or separate planes, in strips or tiles, any libtiff
// compression. Refused, naming the file: not a TIFF, another bit depth, signed or float samples,
// alpha or other sample counts, a palette, a size beyond 2^28 pixels.
RealStack read_tiff16(const std::string& path) {
  require_file(path);
  TIFFSetErrorHandler(tiff_handler);
  TIFFSetWarningHandler(nullptr);
  tiff_message.clear();
  TiffPtr t(TIFFOpen(path.c_str(), "r"));
  if (!t) fail(path, "", "not a readable TIFF file (" + tiff_message + ")");
  std::uint32_t w = 0, h = 0;
  std::uint16_t bits = 0, spp = 1, fmt = SAMPLEFORMAT_UINT, planar = PLANARCONFIG_CONTIG, photometric = 0;
  TIFFGetField(t.get(), TIFFTAG_IMAGEWIDTH, &w);
  TIFFGetField(t.get(), TIFFTAG_IMAGELENGTH, &h);
  TIFFGetFieldDefaulted(t.get(), TIFFTAG_BITSPERSAMPLE, &bits);
  TIFFGetFieldDefaulted(t.get(), TIFFTAG_SAMPLESPERPIXEL, &spp);
  TIFFGetFieldDefaulted(t.get(), TIFFTAG_SAMPLEFORMAT, &fmt);
  TIFFGetFieldDefaulted(t.get(), TIFFTAG_PLANARCONFIG, &planar);
  TIFFGetField(t.get(), TIFFTAG_PHOTOMETRIC, &photometric);
  // A multi-page file (a stack of exposures, a thumbnail page) is refused, not read as page 1:
  // an average over exposures silently lost all but one.
  const tdir_t pages = TIFFNumberOfDirectories(t.get());
  if (pages != 1)
    fail(path, "", "holds " + std::to_string(pages) + " pages (image directories); qdo reads one frame per file: " +
                       "write each exposure to its own file (e.g. tiffsplit) and give them all, they are averaged");
  if (bits != 16 || fmt != SAMPLEFORMAT_UINT) {
    const std::string kind = fmt == SAMPLEFORMAT_IEEEFP ? "floating-point"
                             : fmt == SAMPLEFORMAT_INT  ? "signed"
                             : fmt == SAMPLEFORMAT_UINT ? "unsigned"
                                                        : "SampleFormat " + std::to_string(fmt) + " (untyped or complex)";
    fail(path, "", "a capture must be a 16-bit unsigned TIFF; this one has " + std::to_string(bits) + "-bit " + kind + " samples");
  }
  if (photometric == PHOTOMETRIC_PALETTE) fail(path, "", "a palette TIFF is not a capture (16-bit grayscale or RGB)");
  if (spp != 1 && spp != 3)
    fail(path, "", std::to_string(spp) + " samples per pixel; a capture has 1 (grayscale: a raw mosaic) or 3 (RGB, no alpha)");
  if (w == 0 || h == 0 || std::uint64_t(w) * h > (std::uint64_t{1} << 28))
    fail(path, "", "declares " + std::to_string(h) + " x " + std::to_string(w) + " pixels (at least 1 x 1, at most 2^28)");
  RealStack out(spp, h, w);
  const std::size_t plane = std::size_t(w) * h;
  if (TIFFIsTiled(t.get())) {
    std::uint32_t tw = 0, th = 0;
    TIFFGetField(t.get(), TIFFTAG_TILEWIDTH, &tw);
    TIFFGetField(t.get(), TIFFTAG_TILELENGTH, &th);
    if (tw == 0 || th == 0 || std::uint64_t(tw) * th > (std::uint64_t{1} << 26)) fail(path, "", "a tile size out of range");
    const tmsize_t tile_bytes = TIFFTileSize(t.get());
    std::vector<std::uint16_t> buf(std::size_t(tile_bytes) / 2 + 1);
    const std::uint16_t planes = planar == PLANARCONFIG_SEPARATE ? spp : 1;
    for (std::uint16_t s = 0; s < planes; ++s)
      for (std::uint32_t y0 = 0; y0 < h; y0 += th)
        for (std::uint32_t x0 = 0; x0 < w; x0 += tw) {
          if (TIFFReadTile(t.get(), buf.data(), x0, y0, 0, s) < 0) fail(path, "", "a tile cannot be read (" + tiff_message + ")");
          for (std::uint32_t y = y0; y < std::min(h, y0 + th); ++y)
            for (std::uint32_t x = x0; x < std::min(w, x0 + tw); ++x) {
              const std::size_t at = std::size_t(y - y0) * tw + (x - x0);
              if (planes == 1)
                for (std::uint16_t c = 0; c < spp; ++c) out.data[c * plane + std::size_t(y) * w + x] = buf[at * spp + c];
              else
                out.data[s * plane + std::size_t(y) * w + x] = buf[at];
            }
        }
    return out;
  }
  const tmsize_t line_bytes = TIFFScanlineSize(t.get());
  std::vector<std::uint16_t> line(std::size_t(line_bytes) / 2 + 1);
  const std::uint16_t planes = planar == PLANARCONFIG_SEPARATE ? spp : 1;
  for (std::uint16_t s = 0; s < planes; ++s)
    for (std::uint32_t y = 0; y < h; ++y) {
      if (TIFFReadScanline(t.get(), line.data(), y, s) < 0) fail(path, "", "row " + std::to_string(y) + " cannot be read (" + tiff_message + ")");
      for (std::uint32_t x = 0; x < w; ++x) {
        if (planes == 1)
          for (std::uint16_t c = 0; c < spp; ++c) out.data[c * plane + std::size_t(y) * w + x] = line[std::size_t(x) * spp + c];
        else
          out.data[s * plane + std::size_t(y) * w + x] = line[x];
      }
    }
  return out;
}

void write_tiff16(const std::string& path, const RealStack& dn) {
  if (dn.planes != 1 && dn.planes != 3) reject("16-bit TIFF planes", dn.planes, "1 (grayscale) or 3 (RGB) (file '" + path + "')");
  for (double v : dn.data)
    if (!(v >= 0 && v <= 65535 && v == std::floor(v))) reject("16-bit TIFF value", v, "integer code values in [0, 65535] (file '" + path + "')");
  AtomicFile out(path);
  TIFFSetErrorHandler(tiff_handler);
  tiff_message.clear();
  {
    TiffPtr t(TIFFOpen(out.tmp().c_str(), "w"));
    if (!t) fail(path, "", "TIFF write failed (" + tiff_message + ")");
    const std::uint32_t w = std::uint32_t(dn.cols), h = std::uint32_t(dn.rows);
    const std::uint16_t spp = std::uint16_t(dn.planes);
    TIFFSetField(t.get(), TIFFTAG_IMAGEWIDTH, w);
    TIFFSetField(t.get(), TIFFTAG_IMAGELENGTH, h);
    TIFFSetField(t.get(), TIFFTAG_BITSPERSAMPLE, 16);
    TIFFSetField(t.get(), TIFFTAG_SAMPLESPERPIXEL, spp);
    TIFFSetField(t.get(), TIFFTAG_SAMPLEFORMAT, SAMPLEFORMAT_UINT);
    TIFFSetField(t.get(), TIFFTAG_PLANARCONFIG, PLANARCONFIG_CONTIG);
    TIFFSetField(t.get(), TIFFTAG_PHOTOMETRIC, spp == 3 ? PHOTOMETRIC_RGB : PHOTOMETRIC_MINISBLACK);
    TIFFSetField(t.get(), TIFFTAG_COMPRESSION, COMPRESSION_NONE);
    TIFFSetField(t.get(), TIFFTAG_ROWSPERSTRIP, TIFFDefaultStripSize(t.get(), 0));
    std::vector<std::uint16_t> line(std::size_t(w) * spp);
    const std::size_t plane = std::size_t(w) * h;
    for (std::uint32_t y = 0; y < h; ++y) {
      for (std::uint32_t x = 0; x < w; ++x)
        for (std::uint16_t c = 0; c < spp; ++c) line[std::size_t(x) * spp + c] = std::uint16_t(dn.data[c * plane + std::size_t(y) * w + x]);
      if (TIFFWriteScanline(t.get(), line.data(), y, 0) < 0) fail(path, "", "TIFF write failed (" + tiff_message + ")");
    }
  }
  out.commit();
}

std::vector<std::string> capture_files(const std::string& dir, const std::string& argument) {
  std::error_code ec;
  if (!std::filesystem::is_directory(dir, ec)) reject(argument, dir, "a folder of 16-bit PNG or TIFF frames, or camera raw files");
  std::vector<std::string> out;
  for (const auto& e : std::filesystem::directory_iterator(dir)) {
    if (!e.is_regular_file(ec)) continue;
    const std::string p = e.path().string();
    if (lower_extension(p) == ".png" || is_tiff_path(p) || is_camera_raw_path(p)) out.push_back(p);
  }
  std::sort(out.begin(), out.end());
  if (out.empty()) reject(argument, dir, "a folder holding at least one .png, .tif or camera raw (.dng, ...) frame (it holds none)");
  return out;
}

RealStack read_capture16(const std::string& path, CaptureMeta* meta) {
  if (meta) *meta = CaptureMeta{};
  if (is_tiff_path(path)) return read_tiff16(path);
  if (lower_extension(path) == ".png") return read_png16(path);
  if (is_camera_raw_path(path)) {
    CameraRawInfo info;
    RealStack mosaic = read_camera_raw(path, &info);
    if (meta) {
      meta->camera_raw = true;
      meta->raw = info;
    }
    return mosaic;
  }
  fail(path, "", "a capture is a 16-bit PNG (.png) or TIFF (.tif, .tiff) file, or a camera raw file (.dng, .nef, .cr2, ...)");
}

void check_camera_raw(const CaptureMeta& meta, const std::string& config_cfa, double black_level_dn, double white_level_dn,
                      const std::string& path) {
  if (!meta.camera_raw) return;
  const CameraRawInfo& r = meta.raw;
  if (config_cfa == "none")
    fail(path, "", "a camera raw Bayer mosaic (" + r.cfa + " by its metadata), but the configuration's cfa is \"none\" (RGB or "
                   "monochrome frames): set \"cfa\": \"" + r.cfa + "\"");
  if (config_cfa != r.cfa)
    fail(path, "", "its metadata says the mosaic is " + r.cfa + ", but the configuration's cfa is \"" + config_cfa +
                       "\": set \"cfa\": \"" + r.cfa + "\" (or the file was cropped by one pixel)");
  if (std::fabs(r.black_level_dn - black_level_dn) > 0.5)
    fail(path, "", "its metadata gives the black level " + to_str(r.black_level_dn) + " DN, but the configuration's black_level_dn is " +
                       to_str(black_level_dn) + ": set \"black_level_dn\": " + to_str(r.black_level_dn));
  if (r.white_level_dn > white_level_dn)
    fail(path, "", "its metadata gives the white level " + to_str(r.white_level_dn) + " DN, above the configuration's " +
                       to_str(white_level_dn) + " DN (bit_depth): set bit_depth so that 2^bit_depth - 1 >= " + to_str(r.white_level_dn));
}

}  // namespace qdo
