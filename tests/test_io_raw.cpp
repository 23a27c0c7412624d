// Tests of camera raw reading through LibRaw (src/data/io_raw.cpp): DNG mosaics written by
// write_dng_mosaic, and variants written here with libtiff (per-position black levels, a masked
// border, linear and monochrome data), read back code for code with their CFA pattern, black and
// white levels; files that hold no raw Bayer mosaic are refused, naming the file.
#include <doctest/doctest.h>
#include <tiffio.h>

#include <algorithm>
#include <array>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "common.hpp"
#include "io_common.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"
#include "qdo/data/io_raw.hpp"

namespace fs = std::filesystem;
using namespace qdo;
using namespace qdo::test::io_suite;
using qdo::test::input_error_of;

namespace {

// rows x cols code values in [0, 4095] from a fixed seed, row-major.
Map2D known_mosaic(std::size_t rows, std::size_t cols, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> code(0, 4095);
  Map2D m(rows, cols);
  for (double& v : m.data) v = code(rng);
  return m;
}

// A DNG written with libtiff directly, for what write_dng_mosaic does not write.
struct DngVariant {
  std::size_t rows = 0, cols = 0;
  std::uint16_t samples = 1;                     // 1: one sample per pixel, 3: RGB
  std::uint16_t photometric = PHOTOMETRIC_CFA;   // or 34892 (LinearRaw)
  std::array<std::uint8_t, 4> cfa{0, 1, 1, 2};   // CFAPattern (0 R, 1 G, 2 B), row-major 2 x 2
  std::vector<float> black{64};                  // one level, or 4 with BlackLevelRepeatDim 2 x 2
  std::array<std::uint32_t, 4> active{};         // ActiveArea top, left, bottom, right; all 0: none
  bool preview = false;                          // as cameras write: an RGB preview in IFD0, the raw in a SubIFD
  std::vector<std::uint16_t> codes;              // rows x cols x samples, interleaved
};

void write_dng_variant(const std::string& path, const DngVariant& v) {
  const std::unique_ptr<TIFF, void (*)(TIFF*)> file(TIFFOpen(path.c_str(), "w"), [](TIFF* f) {
    if (f) TIFFClose(f);
  });
  TIFF* t = file.get();
  REQUIRE(t != nullptr);
  const std::uint8_t version[4] = {1, 4, 0, 0};
  const std::uint16_t two_by_two[2] = {2, 2};
  const std::uint32_t white[1] = {4095};
  const float matrix[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1}, neutral[3] = {1, 1, 1};
  if (v.preview) {
    std::uint64_t sub_offsets[1] = {0};  // libtiff fills it in when it writes the next directory
    TIFFSetField(t, TIFFTAG_SUBFILETYPE, std::uint32_t{FILETYPE_REDUCEDIMAGE});
    TIFFSetField(t, TIFFTAG_IMAGEWIDTH, std::uint32_t{16});
    TIFFSetField(t, TIFFTAG_IMAGELENGTH, std::uint32_t{12});
    TIFFSetField(t, TIFFTAG_BITSPERSAMPLE, 8);
    TIFFSetField(t, TIFFTAG_SAMPLESPERPIXEL, 3);
    TIFFSetField(t, TIFFTAG_PLANARCONFIG, PLANARCONFIG_CONTIG);
    TIFFSetField(t, TIFFTAG_PHOTOMETRIC, PHOTOMETRIC_RGB);
    TIFFSetField(t, TIFFTAG_MAKE, "qdo");
    TIFFSetField(t, TIFFTAG_MODEL, "variant");
    TIFFSetField(t, TIFFTAG_UNIQUECAMERAMODEL, "qdo variant");
    TIFFSetField(t, TIFFTAG_DNGVERSION, version);
    TIFFSetField(t, TIFFTAG_COLORMATRIX1, std::uint16_t{9}, matrix);
    TIFFSetField(t, TIFFTAG_ASSHOTNEUTRAL, std::uint16_t{3}, neutral);
    TIFFSetField(t, TIFFTAG_CALIBRATIONILLUMINANT1, std::uint16_t{21});
    TIFFSetField(t, TIFFTAG_SUBIFD, std::uint16_t{1}, sub_offsets);
    std::vector<std::uint8_t> rgb(16 * 3, 128);
    for (std::uint32_t y = 0; y < 12; ++y) REQUIRE(TIFFWriteScanline(t, rgb.data(), y, 0) >= 0);
    REQUIRE(TIFFWriteDirectory(t));
  }
  TIFFSetField(t, TIFFTAG_SUBFILETYPE, std::uint32_t{0});
  TIFFSetField(t, TIFFTAG_IMAGEWIDTH, std::uint32_t(v.cols));
  TIFFSetField(t, TIFFTAG_IMAGELENGTH, std::uint32_t(v.rows));
  TIFFSetField(t, TIFFTAG_BITSPERSAMPLE, 16);
  TIFFSetField(t, TIFFTAG_SAMPLESPERPIXEL, v.samples);
  TIFFSetField(t, TIFFTAG_PLANARCONFIG, PLANARCONFIG_CONTIG);
  TIFFSetField(t, TIFFTAG_PHOTOMETRIC, v.photometric);
  TIFFSetField(t, TIFFTAG_COMPRESSION, COMPRESSION_NONE);
  TIFFSetField(t, TIFFTAG_ROWSPERSTRIP, std::uint32_t(v.rows));
  TIFFSetField(t, TIFFTAG_MAKE, "qdo");
  TIFFSetField(t, TIFFTAG_MODEL, "variant");
  TIFFSetField(t, TIFFTAG_UNIQUECAMERAMODEL, "qdo variant");
  TIFFSetField(t, TIFFTAG_DNGVERSION, version);
  if (v.photometric == PHOTOMETRIC_CFA) {
    TIFFSetField(t, TIFFTAG_CFAREPEATPATTERNDIM, two_by_two);
    TIFFSetField(t, TIFFTAG_CFAPATTERN, std::uint16_t{4}, v.cfa.data());
  }
  if (v.black.size() == 4) TIFFSetField(t, TIFFTAG_BLACKLEVELREPEATDIM, two_by_two);
  TIFFSetField(t, TIFFTAG_BLACKLEVEL, std::uint16_t(v.black.size()), v.black.data());
  TIFFSetField(t, TIFFTAG_WHITELEVEL, std::uint16_t{1}, white);
  if (v.active[2] > 0) TIFFSetField(t, TIFFTAG_ACTIVEAREA, v.active.data());
  TIFFSetField(t, TIFFTAG_COLORMATRIX1, std::uint16_t{9}, matrix);
  TIFFSetField(t, TIFFTAG_ASSHOTNEUTRAL, std::uint16_t{3}, neutral);
  TIFFSetField(t, TIFFTAG_CALIBRATIONILLUMINANT1, std::uint16_t{21});
  std::vector<std::uint16_t> line(v.cols * v.samples);
  for (std::size_t y = 0; y < v.rows; ++y) {
    std::copy_n(v.codes.begin() + std::ptrdiff_t(y * line.size()), line.size(), line.begin());
    REQUIRE(TIFFWriteScanline(t, line.data(), std::uint32_t(y), 0) >= 0);
  }
}

std::vector<std::uint16_t> codes_of(const Map2D& m) {
  std::vector<std::uint16_t> c(m.data.size());
  std::transform(m.data.begin(), m.data.end(), c.begin(), [](double v) { return std::uint16_t(v); });
  return c;
}

// Sets the single SHORT or LONG value of entry `tag` in the first IFD of a little-endian classic
// TIFF (libtiff writes the host's byte order; qdo's hosts are little-endian).
void patch_tag(const std::string& path, std::uint16_t tag, std::uint32_t value) {
  std::string b = qdo::test::slurp(path);
  REQUIRE(b.compare(0, 2, "II") == 0);
  auto byte = [&](std::size_t o) { return std::uint32_t(static_cast<unsigned char>(b[o])); };
  auto u16 = [&](std::size_t o) { return byte(o) | byte(o + 1) << 8; };
  auto u32 = [&](std::size_t o) { return u16(o) | u16(o + 2) << 16; };
  const std::size_t ifd = u32(4), entries = u16(ifd);
  bool found = false;
  for (std::size_t i = 0; i < entries; ++i) {
    const std::size_t e = ifd + 2 + 12 * i;
    if (u16(e) != tag) continue;
    REQUIRE(u32(e + 4) == 1);
    const std::size_t bytes = u16(e + 2) == TIFF_SHORT ? 2 : 4;
    for (std::size_t k = 0; k < bytes; ++k) b[e + 8 + k] = static_cast<char>((value >> (8 * k)) & 0xffu);
    found = true;
  }
  REQUIRE(found);
  std::ofstream(path, std::ios::binary | std::ios::trunc) << b;
}

// The 2 x 2 cell (row-major letters) seen from dy rows and dx columns further down and right.
std::string shifted_cell(const std::string& cell, std::size_t dy, std::size_t dx) {
  std::string out(4, '?');
  for (std::size_t i = 0; i < 4; ++i) out[i] = cell[((i / 2 + dy) % 2) * 2 + (i % 2 + dx) % 2];
  return out;
}

}  // namespace

TEST_SUITE("io_raw") {
  TEST_CASE("camera raw extensions are recognised in any case") {
    for (const char* p : {"a.dng", "b.NEF", "c.Cr2", "d.cr3", "e.ARW", "f.raf", "g.orf", "h.RW2", "i.pef", "j.srw", "k.RAW"})
      CHECK(is_camera_raw_path(p));
    for (const char* p : {"a.tif", "b.png", "c.dngx", "dng", "d.jpg"}) CHECK_FALSE(is_camera_raw_path(p));
  }

  TEST_CASE("a DNG from write_dng_mosaic reads back code for code, with its pattern and levels") {
    TmpDir tmp;
    const Map2D m = known_mosaic(48, 64, 7);
    for (const char* cfa : {"rggb", "bggr", "grbg", "gbrg"}) {
      CAPTURE(cfa);
      const std::string path = tmp / (std::string(cfa) + ".dng");
      write_dng_mosaic(path, m, cfa, 64, 4095);
      CameraRawInfo info;
      const RealStack s = read_camera_raw(path, &info);
      REQUIRE(s.planes == 1);
      REQUIRE(s.rows == 48);
      REQUIRE(s.cols == 64);
      CHECK(s.data == m.data);
      CHECK(info.cfa == cfa);
      CHECK(info.make == "qdo");
      CHECK(info.model == "synthetic");
      CHECK(info.black_level_dn == 64);
      for (double b : info.channel_black_dn) CHECK(b == 64);
      CHECK(info.white_level_dn == 4095);
      CHECK(info.linear_max_dn == 0);
      CHECK(info.rows == 48);
      CHECK(info.cols == 64);
      CHECK(info.bits == 16);
    }
    // No temporary file is left beside the outputs.
    CHECK(tmp.entries() == 4);
    // The upper-case pattern name is the same pattern; make and model are the caller's.
    write_dng_mosaic(tmp / "upper.DNG", m, "GBRG", 0, 65535, "Lab", "bench camera 2");
    CameraRawInfo info;
    CHECK(read_camera_raw(tmp / "upper.DNG", &info).data == m.data);
    CHECK(info.cfa == "gbrg");
    CHECK(info.make == "Lab");
    CHECK(info.model == "bench camera 2");
    CHECK(info.black_level_dn == 0);
    CHECK(info.white_level_dn == 65535);
  }

  TEST_CASE("a DNG mosaic reads as the 16-bit TIFF of the same codes does") {
    TmpDir tmp;
    const Map2D m = known_mosaic(48, 64, 11);
    write_dng_mosaic(tmp / "frame.dng", m, "rggb", 64, 4095);
    RealStack dn(1, m.rows, m.cols);
    dn.data = m.data;
    write_tiff16(tmp / "frame.tif", dn);
    const RealStack from_raw = read_camera_raw(tmp / "frame.dng");
    const RealStack from_tiff = read_tiff16(tmp / "frame.tif");
    CHECK(from_raw.planes == from_tiff.planes);
    CHECK(from_raw.rows == from_tiff.rows);
    CHECK(from_raw.cols == from_tiff.cols);
    CHECK(from_raw.data == from_tiff.data);
  }

  TEST_CASE("odd sizes, a masked border and per-position black levels") {
    TmpDir tmp;
    SUBCASE("odd sizes read whole") {
      for (const auto& size : {std::pair<std::size_t, std::size_t>{47, 63}, {63, 47}, {22, 22}, {23, 91}}) {
        const std::size_t rows = size.first, cols = size.second;
        CAPTURE(rows);
        CAPTURE(cols);
        const Map2D m = known_mosaic(rows, cols, unsigned(rows * 1000 + cols));
        write_dng_mosaic(tmp / "odd.dng", m, "grbg", 64, 4095);
        CameraRawInfo info;
        const RealStack s = read_camera_raw(tmp / "odd.dng", &info);
        CHECK(s.rows == rows);
        CHECK(s.cols == cols);
        CHECK(s.data == m.data);
        CHECK(info.cfa == "grbg");
      }
    }
    SUBCASE("LibRaw reads no DNG below 22 x 22 pixels: refused, naming the file") {
      write_dng_mosaic(tmp / "small.dng", known_mosaic(21, 40, 3), "rggb", 64, 4095);
      const std::string e = input_error_of([&] { read_camera_raw(tmp / "small.dng"); });
      CHECK(contains(e, tmp / "small.dng"));
      CHECK(contains(e, "not a camera raw file"));
    }
    SUBCASE("an ActiveArea at an odd offset: the visible area only, its pattern from its origin") {
      // 41 x 57 stored, active rows 3..40 and columns 5..54. The DNG CFAPattern starts at the
      // active area's corner; LibRaw may move the corner to even coordinates (0.20 does: 4, 6)
      // and then names the pattern at the corner it chose.
      DngVariant v;
      v.rows = 41;
      v.cols = 57;
      v.cfa = {1, 2, 0, 1};  // gbrg
      v.active = {3, 5, 41, 55};
      const Map2D full = known_mosaic(v.rows, v.cols, 5);
      v.codes = codes_of(full);
      write_dng_variant(tmp / "active.dng", v);
      CameraRawInfo info;
      const RealStack s = read_camera_raw(tmp / "active.dng", &info);
      REQUIRE((info.top == 3 || info.top == 4));
      REQUIRE((info.left == 5 || info.left == 6));
      CHECK(s.rows == 41 - info.top);
      CHECK(s.cols == 55 - info.left);
      CHECK(info.rows == s.rows);
      CHECK(info.cols == s.cols);
      CHECK(info.cfa == shifted_cell("gbrg", info.top - 3, info.left - 5));
      std::size_t mismatches = 0;
      for (std::size_t y = 0; y < s.rows; ++y)
        for (std::size_t x = 0; x < s.cols; ++x) mismatches += s(0, y, x) != full(y + info.top, x + info.left);
      CHECK(mismatches == 0);
    }
    SUBCASE("a camera-style DNG: a preview in IFD0, the mosaic with an odd ActiveArea in a SubIFD") {
      DngVariant v;
      v.rows = 41;
      v.cols = 57;
      v.cfa = {1, 2, 0, 1};  // gbrg
      v.black = {60, 64, 66, 70};
      v.active = {3, 5, 41, 55};
      v.preview = true;
      const Map2D full = known_mosaic(v.rows, v.cols, 21);
      v.codes = codes_of(full);
      write_dng_variant(tmp / "camera.dng", v);
      CameraRawInfo info;
      const RealStack s = read_camera_raw(tmp / "camera.dng", &info);
      REQUIRE((info.top == 3 || info.top == 4));
      REQUIRE((info.left == 5 || info.left == 6));
      const std::size_t dy = info.top - 3, dx = info.left - 5;
      CHECK(s.rows == 41 - info.top);
      CHECK(s.cols == 55 - info.left);
      CHECK(info.cfa == shifted_cell("gbrg", dy, dx));
      const std::array<double, 4> block{60, 64, 66, 70};
      for (std::size_t p = 0; p < 4; ++p) CHECK(info.channel_black_dn[p] == block[((p / 2 + dy) % 2) * 2 + (p % 2 + dx) % 2]);
      std::size_t mismatches = 0;
      for (std::size_t y = 0; y < s.rows; ++y)
        for (std::size_t x = 0; x < s.cols; ++x) mismatches += s(0, y, x) != full(y + info.top, x + info.left);
      CHECK(mismatches == 0);
    }
    SUBCASE("BlackLevelRepeatDim 2 x 2: one black level per CFA position, from the active area's corner") {
      // The DNG block starts at the ActiveArea corner, as the CFA pattern does; LibRaw 0.20 moves
      // an odd corner to even coordinates and shifts the pattern but not the block.
      const std::array<double, 4> block{60, 64, 66, 70};
      for (const auto& corner : {std::array<std::uint32_t, 2>{0, 0}, {2, 2}, {3, 5}, {3, 4}, {1, 0}}) {
        for (const auto& cfa : {std::array<std::uint8_t, 4>{0, 1, 1, 2}, {1, 0, 2, 1}, {2, 1, 1, 0}}) {
          CAPTURE(corner[0]);
          CAPTURE(corner[1]);
          DngVariant v;
          v.rows = 32;
          v.cols = 40;
          v.cfa = cfa;
          v.black = {60, 64, 66, 70};
          if (corner[0] + corner[1] > 0) v.active = {corner[0], corner[1], 32, 40};
          v.codes = codes_of(known_mosaic(v.rows, v.cols, 9));
          write_dng_variant(tmp / "black.dng", v);
          CameraRawInfo info;
          read_camera_raw(tmp / "black.dng", &info);
          const std::size_t dy = info.top - corner[0], dx = info.left - corner[1];
          for (std::size_t p = 0; p < 4; ++p) {
            CAPTURE(p);
            CHECK(info.channel_black_dn[p] == block[((p / 2 + dy) % 2) * 2 + (p % 2 + dx) % 2]);
          }
          CHECK(info.black_level_dn == 65);
        }
      }
    }
  }

  TEST_CASE("files that hold no raw Bayer mosaic are refused, naming the file") {
    TmpDir tmp;
    SUBCASE("a text file named .dng") {
      const std::string path = tmp / "notes.dng";
      std::ofstream(path) << "exposure notes, not an image\n";
      const std::string e = input_error_of([&] { read_camera_raw(path); });
      CHECK(contains(e, path));
      CHECK(contains(e, "not a camera raw file"));
      CHECK(contains(e, "16-bit TIFF/PNG"));
    }
    SUBCASE("a missing file") {
      const std::string e = input_error_of([&] { read_camera_raw(tmp / "absent.nef"); });
      CHECK(contains(e, tmp / "absent.nef"));
      CHECK(contains(e, "no such file"));
    }
    SUBCASE("a 16-bit TIFF named .dng") {
      RealStack dn(1, 32, 32, 100);
      write_tiff16(tmp / "plain.tif", dn);
      fs::rename(tmp / "plain.tif", tmp / "plain.dng");
      const std::string e = input_error_of([&] { read_camera_raw(tmp / "plain.dng"); });
      CHECK(contains(e, tmp / "plain.dng"));
    }
    SUBCASE("a linear (demosaiced) RGB DNG") {
      DngVariant v;
      v.rows = 30;
      v.cols = 30;
      v.samples = 3;
      v.photometric = 34892;  // LinearRaw
      v.codes.assign(v.rows * v.cols * 3, 1000);
      write_dng_variant(tmp / "linear.dng", v);
      const std::string e = input_error_of([&] { read_camera_raw(tmp / "linear.dng"); });
      CHECK(contains(e, tmp / "linear.dng"));
      CHECK(contains(e, "Bayer"));
      CHECK(contains(e, "16-bit TIFF/PNG"));
    }
    SUBCASE("a monochrome DNG") {
      DngVariant v;
      v.rows = 30;
      v.cols = 30;
      v.photometric = 34892;  // LinearRaw, one sample
      v.codes.assign(v.rows * v.cols, 1000);
      write_dng_variant(tmp / "mono.dng", v);
      const std::string e = input_error_of([&] { read_camera_raw(tmp / "mono.dng"); });
      CHECK(contains(e, tmp / "mono.dng"));
      CHECK(contains(e, "monochrome"));
      CHECK(contains(e, "Bayer"));
    }
    SUBCASE("a 2 x 2 pattern that is no Bayer pattern (both greens in one column)") {
      DngVariant v;
      v.rows = 30;
      v.cols = 30;
      v.cfa = {0, 1, 2, 1};
      v.codes.assign(v.rows * v.cols, 1000);
      write_dng_variant(tmp / "stripes.dng", v);
      const std::string e = input_error_of([&] { read_camera_raw(tmp / "stripes.dng"); });
      CHECK(contains(e, tmp / "stripes.dng"));
      CHECK(contains(e, "Bayer"));
    }
    SUBCASE("a DNG cut short: its directory lost, or its raw data") {
      const std::string path = tmp / "cut.dng";
      write_dng_mosaic(path, known_mosaic(48, 64, 13), "rggb", 64, 4095);
      const auto size = fs::file_size(path);
      // libtiff writes the directory after the data: cutting the end loses it.
      fs::resize_file(path, size - 2000);
      std::string e = input_error_of([&] { read_camera_raw(path); });
      CHECK(contains(e, path));
      CHECK(contains(e, "not a camera raw file"));
      // The directory intact, the data starting 1000 bytes before the end of the file.
      write_dng_mosaic(path, known_mosaic(48, 64, 13), "rggb", 64, 4095);
      patch_tag(path, TIFFTAG_STRIPOFFSETS, std::uint32_t(size - 1000));
      e = input_error_of([&] { read_camera_raw(path); });
      CHECK(contains(e, path));
      CHECK(contains(e, "cannot unpack"));
    }
    SUBCASE("a DNG declaring more than 2^28 pixels, refused before any allocation") {
      const std::string path = tmp / "huge.dng";
      write_dng_mosaic(path, known_mosaic(48, 64, 17), "rggb", 64, 4095);
      patch_tag(path, TIFFTAG_IMAGEWIDTH, 20000);
      patch_tag(path, TIFFTAG_IMAGELENGTH, 20000);
      const std::string e = input_error_of([&] { read_camera_raw(path); });
      CHECK(contains(e, path));
      CHECK(contains(e, "20000 x 20000"));
      CHECK(contains(e, "2^28"));
    }
  }

  TEST_CASE("write_dng_mosaic refuses what a DNG mosaic cannot hold, naming the file and leaving none") {
    TmpDir tmp;
    const std::string path = tmp / "bad.dng";
    Map2D m = known_mosaic(24, 24, 1);
    auto refused = [&](auto&& write) {
      const std::string e = input_error_of(write);
      CHECK(contains(e, path));
      CHECK(tmp.entries() == 0);
    };
    refused([&] { write_dng_mosaic(path, m, "rgbg", 64, 4095); });
    refused([&] { write_dng_mosaic(path, m, "rggb", 64.5, 4095); });
    refused([&] { write_dng_mosaic(path, m, "rggb", 4095, 4095); });
    refused([&] { write_dng_mosaic(path, m, "rggb", 64, 70000); });
    refused([&] { write_dng_mosaic(path, m, "rggb", 64, 4095, "", "x"); });
    refused([&] { write_dng_mosaic(path, Map2D(), "rggb", 64, 4095); });
    m.data[5] = 2.5;
    refused([&] { write_dng_mosaic(path, m, "rggb", 64, 4095); });
    m.data[5] = -1;
    refused([&] { write_dng_mosaic(path, m, "rggb", 64, 4095); });
    m.data[5] = 65536;
    refused([&] { write_dng_mosaic(path, m, "rggb", 64, 4095); });
  }
}
