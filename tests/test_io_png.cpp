// Tests of the file I/O layer (src/data/io_*.cpp), PNG: gray, montage, RGB and map images are valid
// files of the expected size; bad input and non-finite values are refused.
#include <sstream>
#include <fstream>
#include <doctest/doctest.h>

#include <algorithm>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include "svg_text.hpp"
#include "common.hpp"
#include "io_common.hpp"
#include "qdo/data/figure.hpp"
#include "qdo/data/datasets.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"

namespace fs = std::filesystem;
using namespace qdo;
using namespace qdo::test::io_suite;
using qdo::test::input_error_of;
using qdo::test::slurp;

namespace {

// Signature and IHDR width/height of a PNG file (big-endian at byte 16 and 20).
struct PngHeader {
  bool signature_ok = false;
  std::uint32_t width = 0, height = 0;
  int color_type = -1;
};
PngHeader png_header(const std::string& path) {
  const std::string b = slurp(path);
  PngHeader h;
  if (b.size() < 33) return h;
  static const unsigned char sig[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  h.signature_ok = std::equal(sig, sig + 8, reinterpret_cast<const unsigned char*>(b.data())) &&
                   b.compare(12, 4, "IHDR") == 0;
  auto be32 = [&](std::size_t o) {
    std::uint32_t v = 0;
    for (std::size_t i = 0; i < 4; ++i) v = (v << 8) | static_cast<unsigned char>(b[o + i]);
    return v;
  };
  h.width = be32(16);
  h.height = be32(20);
  h.color_type = static_cast<unsigned char>(b[25]);
  return h;
}

}  // namespace

TEST_SUITE("io") {
  TEST_CASE("PNG files are valid and have the expected size") {
    TmpDir tmp;
    const std::string g = tmp / "gray.png";
    write_png(g, 5, 3, 1, std::vector<unsigned char>(15, 128));
    PngHeader h = png_header(g);
    CHECK(h.signature_ok);
    CHECK(h.width == 5);
    CHECK(h.height == 3);
    CHECK(h.color_type == 0);
    CHECK_THROWS_AS(write_png(g, 5, 3, 1, std::vector<unsigned char>(14)), InputError);
    CHECK_THROWS_AS(write_png(g, 5, 3, 2, std::vector<unsigned char>(30)), InputError);

    // The PSF and height figures (figure.hpp): a PNG and an SVG beside it, titled and labelled.
    RealStack s(5, 10, 12);
    for (std::size_t i = 0; i < s.size(); ++i) s.data[i] = static_cast<double>(i % 17);
    const std::string m = tmp / "montage.png";
    write_psf_figure(m, "five planes", s, {400, 450, 500, 600, 700}, 5e-6, 6);
    CHECK(png_header(m).signature_ok);
    const auto svg = qdo::test::svg_texts(tmp / "montage.svg");
    for (const char* text : {"five planes", "400 nm", "700 nm", "x (µm)", "PSF / panel maximum"}) {
      CAPTURE(text);
      CHECK(qdo::test::svg_has(svg, text));
    }
    CHECK_THROWS_AS(write_psf_figure(m, "t", s, {400, 500}, 5e-6), InputError);
    CHECK_THROWS_AS(write_psf_figure(m, "t", s, {}, 0.0), InputError);
    RealStack rgb(3, 4, 6);
    for (std::size_t i = 0; i < rgb.size(); ++i) rgb.data[i] = static_cast<double>(i);
    const std::string r = tmp / "rgb.png";
    write_rgb_png(r, rgb);
    h = png_header(r);
    CHECK(h.signature_ok);
    CHECK(h.width == 6);
    CHECK(h.height == 4);
    CHECK_THROWS_AS(write_rgb_png(r, RealStack(2, 4, 6)), InputError);

    Map2D map(7, 9);
    for (std::size_t i = 0; i < map.data.size(); ++i) map.data[i] = static_cast<double>(i) * 1e-9;
    const std::string mp = tmp / "map.png";
    write_height_figure(mp, "a ramp", map, 1e-5);
    CHECK(png_header(mp).signature_ok);
    const auto msvg = qdo::test::svg_texts(tmp / "map.svg");
    for (const char* text : {"a ramp", "x (mm)", "y (mm)", "height (nm)"}) {
      CAPTURE(text);
      CHECK(qdo::test::svg_has(msvg, text));
    }
    write_height_figure(mp, "constant", Map2D(2, 2, 3e-7), 1e-5);  // constant map: no division by zero
    CHECK(png_header(mp).signature_ok);
    CHECK(tmp.entries() == 6);  // gray, montage (png, svg), rgb, map (png, svg): no temp files
  }

  TEST_CASE("16-bit PNGs are read as their stored codes, whatever gAMA, sRGB, cHRM or iCCP chunk they carry") {
    // libpng's simplified API turned 12-bit codes into linear light when a file carried gAMA
    // (ImageMagick's default): captures, darks, depth maps and CAVE band images must come back
    // as stored.
    TmpDir tmp;
    Map2D codes(3, 5);
    for (std::size_t i = 0; i < codes.data.size(); ++i) codes.data[i] = double((i * 977 + 13) % 4096);  // 12-bit codes
    RealStack rgb(3, 3, 5);
    for (std::size_t i = 0; i < rgb.data.size(); ++i) rgb.data[i] = double((i * 4099 + 7) % 65536);
    const std::string chrm = std::string(32, '\x01');
    const std::string iccp = std::string("icc\0\0", 5) + std::string("\x78\x9c\x03\x00\x00\x00\x00\x01", 8);  // an empty zlib stream
    for (const auto& [type, data] : std::vector<std::pair<std::string, std::string>>{
             {"gAMA", gama_2_2()}, {"sRGB", std::string(1, '\0')}, {"cHRM", chrm}, {"iCCP", iccp}}) {
      CAPTURE(type);
      const std::string g = tmp / ("gray_" + type + ".png"), c = tmp / ("rgb_" + type + ".png");
      write_png16_gray(g, codes);
      write_png16_rgb(c, rgb);
      add_png_chunk(g, type, data);
      add_png_chunk(c, type, data);
      REQUIRE(contains(slurp(g), type));
      CHECK(read_png16_gray(g).data == codes.data);
      CHECK(read_png16(g).data == codes.data);
      CHECK(read_png16(c).data == rgb.data);
    }
    // A CAVE band folder of 16-bit files with gAMA: the bands are the codes / 65535.
    const std::string dir = tmp / "scene_ms";
    fs::create_directories(dir);
    for (int b = 1; b <= 3; ++b) {
      const std::string f = dir + "/scene_ms_0" + std::to_string(b) + ".png";
      Map2D band = codes;
      for (double& v : band.data) v += 1000.0 * b;
      write_png16_gray(f, band);
      add_png_chunk(f, "gAMA", gama_2_2());
    }
    const RealStack cube = load_scene(dir, "cave-png", 3);
    REQUIRE(cube.planes == 3);
    for (std::size_t i = 0; i < codes.data.size(); ++i) CHECK(cube.data[2 * codes.data.size() + i] == (codes.data[i] + 3000.0) / 65535.0);
    // What a raw frame cannot be is still refused, naming the file: 8-bit, colour.
    const std::string e8 = tmp / "eight.png";
    write_png(e8, 5, 3, 1, std::vector<unsigned char>(15, 128));
    CHECK(contains(input_error_of([&] { read_png16_gray(e8); }), "16-bit grayscale"));
    CHECK(contains(input_error_of([&] { read_png16(e8); }), "eight.png"));
    CHECK(contains(input_error_of([&] { read_png16_gray(tmp / "rgb_gAMA.png"); }), "colour"));
  }
}
