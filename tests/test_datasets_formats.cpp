// Training scenes, the readers: small files written here in every format (HDF5, ICVL .mat v7.3,
// Harvard and KAIST .mat v5, CAVE PNG folders, PNG band folders) and the real CAVE scenes when
// ../shared is present; the radiance rule and the band axis; corrupt inputs.
#include <doctest/doctest.h>
#include <matio.h>
#include <png.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <vector>

#include "common.hpp"
#include "datasets_common.hpp"
#include "qdo/data/config.hpp"
#include "qdo/data/datasets.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"

namespace fs = std::filesystem;
using namespace qdo;
using namespace qdo::test::datasets_suite;

namespace {

#ifdef QDO_SHARED_DIR
const std::string kSharedDir = QDO_SHARED_DIR;
#else
const std::string kSharedDir = "/work/shared";
#endif

struct MatCloser {
  void operator()(mat_t* m) const { Mat_Close(m); }
};
struct MatVarFreer {
  void operator()(matvar_t* v) const { Mat_VarFree(v); }
};

// Writes variables into a new .mat file. dims are MATLAB's, data column-major.
struct MatVarSpec {
  std::string name;
  std::vector<std::size_t> dims;
  std::vector<double> f64;          // used when u16 is empty
  std::vector<std::uint16_t> u16;
};
void write_mat(const std::string& path, mat_ft version, const std::vector<MatVarSpec>& vars) {
  std::unique_ptr<mat_t, MatCloser> mat(Mat_CreateVer(path.c_str(), nullptr, version));
  REQUIRE(mat);
  for (const MatVarSpec& s : vars) {
    std::vector<std::size_t> dims = s.dims;
    void* data = s.u16.empty() ? const_cast<double*>(s.f64.data()) : static_cast<void*>(const_cast<std::uint16_t*>(s.u16.data()));
    std::unique_ptr<matvar_t, MatVarFreer> v(Mat_VarCreate(s.name.c_str(), s.u16.empty() ? MAT_C_DOUBLE : MAT_C_UINT16,
                                                           s.u16.empty() ? MAT_T_DOUBLE : MAT_T_UINT16,
                                                           static_cast<int>(dims.size()), dims.data(), data,
                                                           MAT_F_DONT_COPY_DATA));
    REQUIRE(v);
    REQUIRE(Mat_VarWrite(mat.get(), v.get(), MAT_COMPRESSION_NONE) == 0);
  }
}

// A PNG through libpng's simplified write API in any format (pixels row-major, interleaved).
template <typename T>
void write_png_format(const std::string& path, std::size_t w, std::size_t h, png_uint_32 format, const std::vector<T>& px) {
  png_image img;
  std::memset(&img, 0, sizeof img);
  img.version = PNG_IMAGE_VERSION;
  img.width = static_cast<png_uint_32>(w);
  img.height = static_cast<png_uint_32>(h);
  img.format = format;
  REQUIRE(px.size() == PNG_IMAGE_SIZE(img) / sizeof(T));
  const int ok = png_image_write_to_file(&img, path.c_str(), 0, px.data(), 0, nullptr);
  png_image_free(&img);
  REQUIRE(ok);
}

std::vector<double> band_grid(std::size_t bands) {
  std::vector<double> wl;
  for (std::size_t b = 0; b < bands; ++b) wl.push_back(400.0 + 10.0 * static_cast<double>(b));
  return wl;
}

}  // namespace

TEST_SUITE("datasets") {
  TEST_CASE("an all-zero or constant training scene is refused, naming the file") {
    CHECK_THROWS_WITH_AS(check_training_scene(RealStack(3, 8, 8, 0.0), "zeros.h5"),
                         doctest::Contains("file 'zeros.h5': an all-zero scene"), InputError);
    CHECK_THROWS_WITH_AS(check_training_scene(RealStack(3, 8, 8, 0.5), "gray.h5"),
                         doctest::Contains("file 'gray.h5': a constant scene"), InputError);
    CHECK_THROWS_WITH_AS(check_training_scene(RealStack(3, 8, 8, 0.5), "gray.h5"), doctest::Contains("0.5"), InputError);
    CHECK_THROWS_AS(check_training_scene(RealStack(), "empty.h5"), InputError);
    RealStack one_pixel(3, 8, 8, 0.0);
    one_pixel(2, 7, 7) = 1e-3;  // any variation is information
    CHECK_NOTHROW(check_training_scene(one_pixel, "x.h5"));
  }

  TEST_CASE("HDF5 /cube files read back exactly (format h5 and auto)") {
    TempDir tmp("h5");
    const RealStack cube = random_stack(4, 5, 7, 1);
    const std::string path = tmp / "scene.h5";
    write_cube(path, cube, {400, 500, 600, 700});
    CHECK(detect_scene_format(path) == "h5");
    CHECK(same(load_scene(path, "auto", 4), cube));
    CHECK(same(load_scene(path, "h5", 0), cube));
    CHECK(probe_scene(path, "auto", 4) == SceneShape{4, 5, 7});
    CHECK(input_error([&] { load_scene(path, "auto", 31); }).find(path) != std::string::npos);
  }

  TEST_CASE("ICVL .mat v7.3 (key rad, uint16 <= 4095, MATLAB H x W x 31) reads as 31 x H x W / 4095") {
    TempDir tmp("icvl");
    const std::size_t H = 6, W = 5, B = 31;
    MatVarSpec rad{"rad", {H, W, B}, {}, std::vector<std::uint16_t>(H * W * B)};
    for (std::size_t b = 0; b < B; ++b)
      for (std::size_t x = 0; x < W; ++x)
        for (std::size_t y = 0; y < H; ++y) rad.u16[y + H * (x + W * b)] = tv(b, y, x);
    rad.u16[0] = 4095;  // the top of ICVL's 12-bit range
    MatVarSpec bands{"bands", {1, B}, band_grid(B), {}};
    const std::string path = tmp / "scene.mat";
    write_mat(path, MAT_FT_MAT73, {rad, bands});
    CHECK(detect_scene_format(path) == "icvl");
    CHECK(probe_scene(path, "auto", 31) == SceneShape{B, H, W});
    for (const char* fmt : {"auto", "icvl"}) {
      const RealStack c = load_scene(path, fmt, 31);
      REQUIRE(c.planes == B);
      REQUIRE(c.rows == H);
      REQUIRE(c.cols == W);
      CHECK(c(0, 0, 0) == doctest::Approx(1.0));
      bool ok = true;
      for (std::size_t b = 0; b < B; ++b)
        for (std::size_t y = 0; y < H; ++y)
          for (std::size_t x = 0; x < W; ++x)
            if ((b || y || x) && std::abs(c(b, y, x) - tv(b, y, x) / 4095.0) > 1e-15) ok = false;
      CHECK(ok);
    }
    // Same values as doubles: still divided by 4095.
    MatVarSpec radd{"rad", {H, W, B}, std::vector<double>(rad.u16.begin(), rad.u16.end()), {}};
    const std::string pd = tmp / "scene_double.mat";
    write_mat(pd, MAT_FT_MAT73, {radd});
    CHECK(load_scene(pd, "auto", 31)(3, 2, 1) == doctest::Approx(tv(3, 2, 1) / 4095.0));
  }

  TEST_CASE("a scene's stored band axis is checked when the index is built; every scene passes the radiance rule") {
    TempDir tmp("axis");
    const std::size_t H = 6, W = 5, B = 31;
    std::vector<double> grid(B);
    for (std::size_t b = 0; b < B; ++b) grid[b] = 400.0 + 10.0 * double(b);
    // ICVL-like .mat v7.3 with `bands`: on the grid it loads; shifted by 5 nm it is refused when the
    // index is built (not when the scene is first drawn), naming the file and both grids.
    MatVarSpec rad{"rad", {H, W, B}, {}, std::vector<std::uint16_t>(H * W * B, 1000)};
    rad.u16[3] = 4000;
    std::vector<double> shifted(grid);
    for (double& v : shifted) v += 5.0;
    fs::create_directories(tmp / "good");
    fs::create_directories(tmp / "bad");
    write_mat(tmp / "good/a.mat", MAT_FT_MAT73, {rad, MatVarSpec{"bands", {1, B}, grid, {}}});
    write_mat(tmp / "bad/b.mat", MAT_FT_MAT73, {rad, MatVarSpec{"bands", {1, B}, shifted, {}}});
    const SceneIndex good(std::vector<std::string>{tmp / "good"}, "auto", B, grid);
    CHECK(good.load(0).data.size() == B * H * W);
    const std::string msg = input_error([&] { SceneIndex(std::vector<std::string>{tmp / "bad"}, "auto", B, grid); });
    CHECK(msg.find("b.mat") != std::string::npos);
    CHECK(msg.find("405 ... 705 nm") != std::string::npos);
    CHECK(msg.find("400 ... 700 nm") != std::string::npos);
    // Without a configured grid (the library's default) the axis is not compared.
    CHECK(SceneIndex(std::vector<std::string>{tmp / "bad"}, "auto", B).size() == 1);
    // An HDF5 cube of HDR values is divided by its maximum; strongly negative values are refused.
    RealStack hdr(B, H, W, 2.0);
    hdr(4, 1, 1) = 8.0;
    write_cube(tmp / "hdr.h5", hdr, grid);
    const RealStack c = load_scene(tmp / "hdr.h5", "auto", B, grid);
    CHECK(c(4, 1, 1) == 1.0);
    CHECK(c(0, 0, 0) == 0.25);
    RealStack neg(B, H, W, 0.5);
    neg(0, 2, 2) = -0.3;
    write_cube(tmp / "neg.h5", neg, grid);
    CHECK(input_error([&] { load_scene(tmp / "neg.h5", "auto", B, grid); }).find("negative") != std::string::npos);
  }

  TEST_CASE("Harvard (ref, scaled by its max) and KAIST (HSI) .mat v5 files") {
    TempDir tmp("v5");
    const std::size_t H = 4, W = 3, B = 31;
    MatVarSpec ref{"ref", {H, W, B}, std::vector<double>(H * W * B), {}};
    for (std::size_t b = 0; b < B; ++b)
      for (std::size_t x = 0; x < W; ++x)
        for (std::size_t y = 0; y < H; ++y) ref.f64[y + H * (x + W * b)] = 0.001 * tv(b, y, x);
    const double mx = *std::max_element(ref.f64.begin(), ref.f64.end());
    REQUIRE(mx > 1);  // not normalised, like the original data
    MatVarSpec lbl{"lbl", {H, W}, std::vector<double>(H * W, 1.0), {}};
    const std::string hp = tmp / "harvard.mat";
    write_mat(hp, MAT_FT_MAT5, {ref, lbl});
    CHECK(detect_scene_format(hp) == "harvard");
    CHECK(probe_scene(hp, "auto", 31) == SceneShape{B, H, W});
    const RealStack h = load_scene(hp, "auto", 31);
    REQUIRE(h.planes == B);
    REQUIRE(h.rows == H);
    REQUIRE(h.cols == W);
    double worst = 0;
    for (std::size_t b = 0; b < B; ++b)
      for (std::size_t y = 0; y < H; ++y)
        for (std::size_t x = 0; x < W; ++x) worst = std::max(worst, std::abs(h(b, y, x) - 0.001 * tv(b, y, x) / mx));
    CHECK(worst < 1e-15);
    CHECK(*std::max_element(h.data.begin(), h.data.end()) == doctest::Approx(1.0));

    MatVarSpec hsi{"HSI", {H, W, B}, std::vector<double>(H * W * B), {}};
    for (std::size_t b = 0; b < B; ++b)
      for (std::size_t x = 0; x < W; ++x)
        for (std::size_t y = 0; y < H; ++y) hsi.f64[y + H * (x + W * b)] = tv(b, y, x) / 4096.0;
    const std::string kp = tmp / "kaist.mat";
    write_mat(kp, MAT_FT_MAT5, {hsi});
    CHECK(detect_scene_format(kp) == "kaist");
    const RealStack k = load_scene(kp, "kaist", 31);
    REQUIRE(k.rows == H);
    CHECK(k(7, 3, 2) == tv(7, 3, 2) / 4096.0);
    CHECK(k(30, 0, 1) == tv(30, 0, 1) / 4096.0);

    // A generic .mat (no ICVL/Harvard/KAIST key): CAVE rules, uint16 / 65535.
    MatVarSpec cave{"NRD", {H, W, B}, {}, std::vector<std::uint16_t>(H * W * B)};
    for (std::size_t i = 0; i < cave.u16.size(); ++i) cave.u16[i] = static_cast<std::uint16_t>(i * 50);
    const std::string cp = tmp / "cave.mat";
    write_mat(cp, MAT_FT_MAT5, {cave});
    CHECK(detect_scene_format(cp) == "cave");
    CHECK(load_scene(cp, "auto", 31)(2, 1, 2) == doctest::Approx((1 + H * (2 + W * 2)) * 50 / 65535.0));
  }

  TEST_CASE("CAVE PNG folders: 31 16-bit bands sorted by number, / 65535; 8-bit / 255") {
    TempDir tmp("png");
    const std::size_t H = 7, W = 9;
    for (bool pad : {true, false}) {
      const std::string dir = tmp / (pad ? "padded" : "unpadded");
      write_png_folder(dir, 31, H, W, pad);
      CHECK(detect_scene_format(dir) == "cave-png");
      CHECK(probe_scene(dir, "auto", 31) == SceneShape{31, H, W});
      const RealStack c = load_scene(dir, "cave", 31);
      REQUIRE(c.planes == 31);
      REQUIRE(c.rows == H);
      REQUIRE(c.cols == W);
      bool ok = true;
      for (std::size_t b = 0; b < 31; ++b)
        for (std::size_t y = 0; y < H; ++y)
          for (std::size_t x = 0; x < W; ++x)
            if (std::abs(c(b, y, x) - tv(b, y, x) * 16 / 65535.0) > 1e-15) ok = false;
      CHECK(ok);
      const std::vector<std::string> files = png_band_files(dir);
      REQUIRE(files.size() == 31);
      CHECK(fs::path(files[9]).filename().string() == (pad ? "scene_ms_10.png" : "scene_ms_10.png"));
      CHECK(fs::path(files[1]).filename().string() == (pad ? "scene_ms_02.png" : "scene_ms_2.png"));
    }
    // 8-bit grayscale bands.
    const std::string d8 = tmp / "eight";
    fs::create_directories(d8);
    for (int b = 1; b <= 3; ++b) write_png(d8 + "/band_" + std::to_string(b) + ".png", 2, 1, 1, {static_cast<unsigned char>(b), 255});
    const RealStack e = load_scene(d8, "cave-png", 3);
    REQUIRE(e.planes == 3);
    CHECK(e(1, 0, 0) == 2 / 255.0);
    CHECK(e(2, 0, 1) == 1.0);
  }

  TEST_CASE("the real CAVE .mat scenes in ../shared") {
    const std::string dir = kSharedDir + "/data/hsi/cave";
    if (!qdo::test::skip_unless(fs::exists(dir), dir + " is absent")) return;
    const SceneIndex idx({dir});
    REQUIRE(idx.size() == 3);
    for (std::size_t i = 0; i < idx.size(); ++i) {
      CAPTURE(idx[i].path);
      CHECK(idx[i].format == "cave");
      CHECK(idx[i].shape == SceneShape{31, 256, 256});
      const RealStack c = idx.load(i);
      const double mx = *std::max_element(c.data.begin(), c.data.end());
      CHECK(*std::min_element(c.data.begin(), c.data.end()) >= 0);
      CHECK(mx <= 1.0);
      CHECK(mx > 0.6);  // the README lists maxima of 43764 .. 63432 of 65535
      CAPTURE(mx);
      CubeReadOptions opt;
      opt.scale = 65535;
      opt.expected_bands = 31;
      CHECK(same(c, read_cube(idx[i].path, opt)));
    }
  }

  TEST_CASE("PNG band folders: 8-bit grey, and 8/16-bit RGB(A) bands with R = G = B read as grey") {
    // The real CAVE database has one scene whose band images are RGB(A) with equal channels.
    TempDir tmp("grey_rgb");
    const std::size_t h = 3, w = 4, bands = 4;
    const std::string ref = tmp / "ref", mixed = tmp / "mixed";
    write_png_folder(ref, bands, h, w);
    fs::create_directories(mixed);
    for (std::size_t b = 0; b < bands; ++b) {
      const std::string name = mixed + "/scene_ms_0" + std::to_string(b + 1) + ".png";
      std::vector<std::uint16_t> g16(h * w);
      for (std::size_t i = 0; i < h * w; ++i) g16[i] = static_cast<std::uint16_t>(tv(b, i / w, i % w) * 16);
      if (b == 0) {  // 16-bit RGB
        std::vector<std::uint16_t> px;
        for (std::uint16_t v : g16) px.insert(px.end(), {v, v, v});
        write_png_format(name, w, h, PNG_FORMAT_LINEAR_RGB, px);
      } else if (b == 1) {  // 16-bit RGBA, opaque
        std::vector<std::uint16_t> px;
        for (std::uint16_t v : g16) px.insert(px.end(), {v, v, v, 65535});
        write_png_format(name, w, h, PNG_FORMAT_LINEAR_RGB_ALPHA, px);
      } else if (b == 2) {  // 8-bit RGBA, opaque
        std::vector<std::uint8_t> px;
        for (std::size_t i = 0; i < h * w; ++i) {
          const auto v = static_cast<std::uint8_t>(i * 20 + 3);
          px.insert(px.end(), {v, v, v, 255});
        }
        write_png_format(name, w, h, PNG_FORMAT_RGBA, px);
      } else {  // 8-bit grey
        std::vector<std::uint8_t> px(h * w);
        for (std::size_t i = 0; i < h * w; ++i) px[i] = static_cast<std::uint8_t>(i * 20 + 7);
        write_png_format(name, w, h, PNG_FORMAT_GRAY, px);
      }
    }
    const RealStack r = load_scene(ref, "auto", bands), m = load_scene(mixed, "auto", bands);
    REQUIRE(m.planes == bands);
    REQUIRE(m.rows == h);
    REQUIRE(m.cols == w);
    for (std::size_t i = 0; i < h * w; ++i) {
      CAPTURE(i);
      CHECK(m.plane(0)[i] == r.plane(0)[i]);  // 16-bit RGB: the grey value, exactly
      CHECK(m.plane(1)[i] == r.plane(1)[i]);  // 16-bit RGBA
      CHECK(m.plane(2)[i] == static_cast<double>(i * 20 + 3) / 255.0);
      CHECK(m.plane(3)[i] == static_cast<double>(i * 20 + 7) / 255.0);
    }
    CHECK(probe_scene(mixed, "auto", bands) == SceneShape{bands, h, w});
    // A transparent pixel in an RGBA band: refused naming the file and the pixel.
    const std::string bad = tmp / "transparent";
    write_png_folder(bad, bands, h, w);
    std::vector<std::uint8_t> px;
    for (std::size_t i = 0; i < h * w; ++i) px.insert(px.end(), {50, 50, 50, static_cast<std::uint8_t>(i == 5 ? 128 : 255)});
    write_png_format(bad + "/scene_ms_02.png", w, h, PNG_FORMAT_RGBA, px);
    const std::string msg = input_error([&] { load_scene(bad, "auto", bands); });
    CHECK(msg.find(bad + "/scene_ms_02.png") != std::string::npos);
    CHECK(msg.find("transparent pixel (row 1, column 1)") != std::string::npos);
  }

  TEST_CASE("corrupt, truncated and mis-shaped inputs are InputErrors naming the file") {
    TempDir tmp("bad");
    // A PNG folder with 30 bands.
    const std::string d30 = tmp / "thirty";
    write_png_folder(d30, 30, 4, 4);
    std::string m = input_error([&] { load_scene(d30, "auto", 31); });
    CHECK(m.find(d30) != std::string::npos);
    CHECK(m.find("30") != std::string::npos);
    CHECK(input_error([&] { SceneIndex({d30}); }).find(d30) != std::string::npos);

    // An 8-bit RGB PNG among 16-bit bands.
    const std::string drgb = tmp / "rgb";
    write_png_folder(drgb, 31, 4, 4);
    const std::string rgb = drgb + "/scene_ms_05.png";
    std::vector<unsigned char> coloured(48, 100);
    coloured[3 * 6 + 1] = 101;  // pixel (1, 2): G differs from R and B (grey RGB is accepted)
    write_png(rgb, 4, 4, 3, coloured);
    m = input_error([&] { load_scene(drgb, "auto", 31); });
    CHECK(m.find(rgb) != std::string::npos);
    CHECK(m.find("colour") != std::string::npos);
    CHECK(m.find("row 1, column 2") != std::string::npos);

    // A truncated PNG.
    const std::string dtr = tmp / "trunc";
    write_png_folder(dtr, 31, 4, 4);
    const std::string tr = dtr + "/scene_ms_07.png";
    {
      std::vector<std::uint16_t> px(64 * 64);
      std::mt19937_64 rng(3);
      for (auto& v : px) v = static_cast<std::uint16_t>(rng());
      write_png16(tr, 64, 64, px);
      fs::resize_file(tr, fs::file_size(tr) / 2);
    }
    m = input_error([&] { load_scene(dtr, "auto", 0); });
    CHECK(m.find(tr) != std::string::npos);
    // Not a PNG at all.
    { std::ofstream(dtr + "/scene_ms_07.png", std::ios::trunc) << "not a png"; }
    CHECK(input_error([&] { load_scene(dtr, "auto", 31); }).find(tr) != std::string::npos);

    // Two files claiming the same band number; a PNG without a number.
    const std::string ddup = tmp / "dup";
    write_png_folder(ddup, 3, 2, 2);
    fs::copy_file(ddup + "/scene_ms_02.png", ddup + "/other_2.png");
    CHECK(input_error([&] { load_scene(ddup, "auto", 0); }).find(ddup) != std::string::npos);
    const std::string dnum = tmp / "nonum";
    write_png_folder(dnum, 3, 2, 2);
    fs::copy_file(dnum + "/scene_ms_02.png", dnum + "/preview.png");
    CHECK(input_error([&] { load_scene(dnum, "auto", 0); }).find("preview.png") != std::string::npos);

    // Mis-shaped .mat: 30 bands where 31 are expected.
    const std::string mis = tmp / "thirty_bands.mat";
    write_mat(mis, MAT_FT_MAT73, {{"rad", {4, 3, 30}, {}, std::vector<std::uint16_t>(4 * 3 * 30, 7)}});
    CHECK(input_error([&] { load_scene(mis, "auto", 31); }).find(mis) != std::string::npos);
    CHECK(input_error([&] { probe_scene(mis, "auto", 31); }).find(mis) != std::string::npos);
    // A 2-D variable.
    const std::string flat = tmp / "flat.mat";
    write_mat(flat, MAT_FT_MAT5, {{"HSI", {4, 3}, std::vector<double>(12, 0.5), {}}});
    CHECK(input_error([&] { load_scene(flat, "auto", 31); }).find(flat) != std::string::npos);

    // Truncated .mat files (v5 and v7.3).
    for (mat_ft v : {MAT_FT_MAT5, MAT_FT_MAT73}) {
      const std::string t = tmp / (v == MAT_FT_MAT5 ? "trunc5.mat" : "trunc73.mat");
      write_mat(t, v, {{"ref", {8, 8, 31}, std::vector<double>(8 * 8 * 31, 0.25), {}}});
      fs::resize_file(t, fs::file_size(t) * 2 / 3);
      CHECK(input_error([&] { load_scene(t, "auto", 31); }).find(t) != std::string::npos);
    }
    // Garbage with a .mat name, an unknown file type, a missing path, an unknown format.
    const std::string junk = tmp / "junk.mat";
    { std::ofstream(junk) << "definitely not MATLAB"; }
    CHECK(input_error([&] { load_scene(junk, "auto", 31); }).find(junk) != std::string::npos);
    const std::string txt = tmp / "notes.txt";
    { std::ofstream(txt) << "hello"; }
    CHECK(input_error([&] { load_scene(txt, "auto", 31); }).find(txt) != std::string::npos);
    CHECK(input_error([&] { load_scene(tmp / "missing.mat", "auto", 31); }).find("missing.mat") != std::string::npos);
    CHECK(input_error([&] { load_scene(txt, "envi", 31); }).find("envi") != std::string::npos);
  }
}
