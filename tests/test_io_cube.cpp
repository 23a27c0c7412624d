// Tests of the file I/O layer (src/data/io_*.cpp), hyperspectral cubes: the stored band axis checked
// or resampled, the radiance rule, and read_cube on .mat v5 and v7.3 files (the CAVE scenes in
// ../shared when present, files written here, truncated and corrupted ones).
#include <doctest/doctest.h>
#include <matio.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <limits>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "common.hpp"
#include "io_common.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"

namespace fs = std::filesystem;
using namespace qdo;
using namespace qdo::test::io_suite;
using qdo::test::input_error_of;
using qdo::test::slurp;

namespace {

struct MatCloser {
  void operator()(mat_t* m) const { Mat_Close(m); }
};
struct MatVarFreer {
  void operator()(matvar_t* v) const { Mat_VarFree(v); }
};

// Writes MATLAB variables (name, dims, class, column-major data) with matio, as v5 or v7.3.
template <typename T>
void mat_write(mat_t* mat, const std::string& name, std::vector<std::size_t> dims, matio_classes cls, matio_types type,
               std::vector<T> data, matio_compression compression = MAT_COMPRESSION_NONE) {
  std::unique_ptr<matvar_t, MatVarFreer> v(
      Mat_VarCreate(name.c_str(), cls, type, static_cast<int>(dims.size()), dims.data(), data.data(), MAT_F_DONT_COPY_DATA));
  REQUIRE(v);
  REQUIRE(Mat_VarWrite(mat, v.get(), compression) == 0);
}

const std::string kShared = QDO_SHARED_DIR;
const std::string kCave = kShared + "/data/hsi/cave";

}  // namespace

TEST_SUITE("io") {
  TEST_CASE("a cube's stored band axis is read and checked against the configured bands") {
    TmpDir tmp;
    const std::vector<double> grid = {400, 450, 500, 550};  // the configured bands
    RealStack cube(4, 2, 3);
    for (std::size_t b = 0; b < 4; ++b)
      for (std::size_t i = 0; i < 6; ++i) cube.plane(b)[i] = 0.1 * double(b) + 0.01 * double(i);
    CubeReadOptions o;
    o.wavelengths_nm = grid;
    // The same grid (within 0.5 nm): read as is.
    write_cube(tmp / "same.h5", cube, {400.2, 450, 500, 549.7});
    CHECK(read_cube(tmp / "same.h5", o).data == cube.data);
    // Shifted by 5 nm: refused, naming the file, the dataset and both grids.
    write_cube(tmp / "shifted.h5", cube, {405, 455, 505, 555});
    std::string msg = input_error_of([&] { read_cube(tmp / "shifted.h5", o); });
    CHECK(contains(msg, tmp / "shifted.h5"));
    CHECK(contains(msg, "'/wavelengths_nm'"));
    CHECK(contains(msg, "4 bands, 405 ... 555 nm (step 50)"));
    CHECK(contains(msg, "4 bands, 400 ... 550 nm (step 50)"));
    CHECK(contains(msg, "--resample-bands"));
    // Reversed (700 -> 400 order): refused, said to be descending.
    write_cube(tmp / "reversed.h5", cube, {550, 500, 450, 400});
    msg = input_error_of([&] { read_cube(tmp / "reversed.h5", o); });
    CHECK(contains(msg, "descending"));
    // Another band count: the file's axis decides the band axis; refused naming both grids.
    RealStack five(5, 2, 3, 0.25);
    write_cube(tmp / "five.h5", five, {400, 437.5, 475, 512.5, 550});
    msg = input_error_of([&] { read_cube(tmp / "five.h5", o); });
    CHECK(contains(msg, "5 bands"));
    CHECK(contains(msg, "4 bands"));
    // An axis that is not a wavelength in nm (µm here), not monotonic, or of the wrong length.
    write_cube(tmp / "um.h5", cube, {0.40, 0.45, 0.50, 0.55});
    CHECK(contains(input_error_of([&] { read_cube(tmp / "um.h5", o); }), "not a wavelength in nm"));
    write_cube(tmp / "flat.h5", cube, {500, 500, 500, 500});
    CHECK(contains(input_error_of([&] { read_cube(tmp / "flat.h5", o); }), "not strictly monotonic"));
    h5_write(tmp / "short.h5", {H5Dataset{"/cube", {4, 2, 3}, cube.data, {}, {}},
                                H5Dataset{"/bands", {3}, {400, 450, 500}, {}, {}}});
    CHECK(contains(input_error_of([&] { read_cube(tmp / "short.h5", o); }), "'/bands'"));

    // With resample: linear interpolation along wavelength, descending axes included; the grid
    // must lie inside the file's range.
    o.resample_bands = true;
    const RealStack rev = read_cube(tmp / "reversed.h5", o);  // plane 0 was labelled 550 nm
    REQUIRE(rev.planes == 4);
    for (std::size_t b = 0; b < 4; ++b)
      for (std::size_t i = 0; i < 6; ++i) CHECK(rev.plane(b)[i] == doctest::Approx(cube.plane(3 - b)[i]).epsilon(1e-15));
    const RealStack r = read_cube(tmp / "five.h5", o);
    REQUIRE(r.planes == 4);
    for (double v : r.data) CHECK(v == doctest::Approx(0.25).epsilon(1e-12));
    RealStack ramp(3, 1, 1);
    ramp.data = {0.0, 0.5, 1.0};
    const RealStack rr = conform_band_axis(ramp, {400, 500, 600}, {450, 550}, true, "ramp");
    CHECK(rr.data[0] == doctest::Approx(0.25));
    CHECK(rr.data[1] == doctest::Approx(0.75));
    msg = input_error_of([&] { read_cube(tmp / "shifted.h5", o); });  // 400 nm lies below 405 - 0.5
    CHECK(contains(msg, "outside the file's range"));
    // Without a configured grid (the library default) the axis is not compared.
    CHECK(read_cube(tmp / "shifted.h5").data == cube.data);

    // A MATLAB file's band axis variable is read as well.
    const std::string m = tmp / "axis.mat";
    {
      std::unique_ptr<mat_t, MatCloser> mat(Mat_CreateVer(m.c_str(), nullptr, MAT_FT_MAT5));
      REQUIRE(mat);
      std::vector<double> hwb(2 * 3 * 4, 0.5);
      mat_write(mat.get(), "cube", {2, 3, 4}, MAT_C_DOUBLE, MAT_T_DOUBLE, hwb);
      mat_write(mat.get(), "wavelengths_nm", {1, 4}, MAT_C_DOUBLE, MAT_T_DOUBLE, std::vector<double>{410, 460, 510, 560});
    }
    o.resample_bands = false;
    msg = input_error_of([&] { read_cube(m, o); });
    CHECK(contains(msg, "variable 'wavelengths_nm'"));
    CHECK(contains(msg, "410 ... 560 nm"));
  }

  TEST_CASE("the radiance rule: strongly negative refused, slightly negative set to 0, HDR divided by its maximum") {
    RealStack ok(2, 2, 2, 0.5);
    RadianceReport r = conform_radiance(ok, "ok");
    CHECK(r.negative == 0);
    CHECK(r.divided_by == 0);
    CHECK(ok.data == std::vector<double>(8, 0.5));

    RealStack slight(1, 2, 2, 0.3);
    slight.data[1] = -0.004;  // dark-frame noise
    r = conform_radiance(slight, "slight");
    CHECK(r.negative == 1);
    CHECK(r.min == -0.004);
    CHECK(slight.data[1] == 0.0);
    CHECK(slight.data[0] == 0.3);

    RealStack neg(1, 2, 2, 0.3);
    neg.data[3] = -0.2;
    const std::string msg = input_error_of([&] { conform_radiance(neg, "file 'neg.h5'"); });
    CHECK(contains(msg, "file 'neg.h5'"));
    CHECK(contains(msg, "-0.2"));
    CHECK(contains(msg, "1 negative"));

    RealStack hdr(1, 1, 4);
    hdr.data = {0.0, 1.0, 271.5, 543.0};
    r = conform_radiance(hdr, "hdr");
    CHECK(r.divided_by == 543.0);
    CHECK(hdr.data == std::vector<double>{0.0, 1.0 / 543.0, 0.5, 1.0});

    RealStack rounding(1, 1, 2);
    rounding.data = {1.0 + 1e-9, 0.5};  // float rounding above 1: clipped, not rescaled
    r = conform_radiance(rounding, "rounding");
    CHECK(r.divided_by == 0);
    CHECK(rounding.data == std::vector<double>{1.0, 0.5});

    RealStack inf(1, 1, 2);
    inf.data = {0.5, std::numeric_limits<double>::infinity()};
    CHECK(contains(input_error_of([&] { conform_radiance(inf, "inf"); }), "not finite"));
  }

  TEST_CASE("read_cube on the CAVE scenes") {
    if (!qdo::test::skip_unless(fs::is_directory(kCave), "no CAVE data at " + kCave)) return;
    const std::array<std::pair<const char*, const char*>, 3> scenes{
        {{"balloons_256.mat", "Omsi"}, {"chart_and_stuffed_toy_256.mat", "NRD"}, {"cloth_256.mat", "NRD"}}};
    for (const auto& [file, key] : scenes) {
      CAPTURE(file);
      const std::string path = kCave + "/" + file;
      CubeReadOptions o;
      o.expected_bands = 31;
      const RealStack cube = read_cube(path, o);
      REQUIRE(cube.planes == 31);
      REQUIRE(cube.rows == 256);
      REQUIRE(cube.cols == 256);
      const auto [lo, hi] = std::minmax_element(cube.data.begin(), cube.data.end());
      CHECK(*lo >= 0.0);
      CHECK(*hi <= 1.0);
      CHECK(*hi > 0.5);

      // The same values with the key given and with no key (the only 3-D variable).
      CubeReadOptions keyed;
      keyed.key = key;
      CHECK(read_cube(path, keyed).data == cube.data);

      // Spot values against the raw uint16 array read independently (column-major H x W x B).
      std::unique_ptr<mat_t, MatCloser> mat(Mat_Open(path.c_str(), MAT_ACC_RDONLY));
      REQUIRE(mat);
      std::unique_ptr<matvar_t, MatVarFreer> v(Mat_VarRead(mat.get(), key));
      REQUIRE(v);
      REQUIRE(v->class_type == MAT_C_UINT16);
      REQUIRE(v->rank == 3);
      CHECK(v->dims[0] == 256);
      CHECK(v->dims[2] == 31);
      const auto* raw = static_cast<const std::uint16_t*>(v->data);
      std::uint16_t raw_max = 0;
      for (std::size_t i = 0; i < 256 * 256 * 31; ++i) raw_max = std::max(raw_max, raw[i]);
      CHECK(*hi == static_cast<double>(raw_max) / 65535.0);
      for (const auto& ijk : std::vector<std::array<std::size_t, 3>>{{0, 0, 0}, {10, 200, 5}, {200, 10, 30}, {128, 77, 15}}) {
        const std::size_t i = ijk[0], j = ijk[1], k = ijk[2];
        CHECK(cube(k, i, j) == static_cast<double>(raw[i + 256 * j + 256 * 256 * k]) / 65535.0);
      }
      // A bright pixel (the maximum), so the check is not passed by zeros alone.
      const std::size_t at = static_cast<std::size_t>(std::max_element(raw, raw + 256 * 256 * 31) - raw);
      CHECK(cube(at / 65536, at % 256, (at / 256) % 256) == static_cast<double>(raw_max) / 65535.0);

      o.expected_bands = 30;
      const std::string msg = input_error_of([&] { read_cube(path, o); });
      CHECK(contains(msg, file));
      CHECK(contains(msg, key));
      CHECK(contains(msg, "[256 x 256 x 31]"));
      CHECK(contains(msg, "30"));
      o.expected_bands = 31;
      o.layout = "bhw";
      CHECK(contains(input_error_of([&] { read_cube(path, o); }), "31 bands expected"));
    }
  }

  TEST_CASE("read_cube on a truncated .mat file fails cleanly") {
    if (!qdo::test::skip_unless(fs::is_directory(kCave), "no CAVE data at " + kCave)) return;
    TmpDir tmp;
    const std::string cut = tmp / "truncated.mat";
    for (std::size_t bytes : {1000u, 100u, 10u, 0u}) {
      CAPTURE(bytes);
      const std::string full = slurp(kCave + "/balloons_256.mat");
      write_text_atomic(cut, full.substr(0, bytes));
      CubeReadOptions o;
      o.key = "Omsi";
      CHECK(contains(input_error_of([&] { read_cube(cut, o); }), cut));
      CHECK(contains(input_error_of([&] { read_cube(cut); }), cut));
    }
  }

  TEST_CASE("read_cube on .mat v5 and v7.3 files written here") {
    TmpDir tmp;
    // MATLAB dims [H=4, W=3, B=5]; value 100*i + 10*j + k at column-major i + 4*j + 12*k.
    const std::size_t H = 4, W = 3, B = 5;
    auto value = [](std::size_t a, std::size_t b, std::size_t c, double ka, double kb, double kc) {
      return ka * static_cast<double>(a) + kb * static_cast<double>(b) + kc * static_cast<double>(c);
    };
    std::vector<double> hwb(H * W * B);
    for (std::size_t k = 0; k < B; ++k)
      for (std::size_t j = 0; j < W; ++j)
        for (std::size_t i = 0; i < H; ++i) hwb[i + H * j + H * W * k] = value(i, j, k, 100, 10, 1) + 0.5;
    // MATLAB dims [B=5, H=4, W=3] uint16; value 1000*b + 10*y + x.
    std::vector<std::uint16_t> bhw(B * H * W);
    for (std::size_t x = 0; x < W; ++x)
      for (std::size_t y = 0; y < H; ++y)
        for (std::size_t b = 0; b < B; ++b) bhw[b + B * y + B * H * x] = static_cast<std::uint16_t>(1000 * b + 10 * y + x);

    for (const mat_ft version : {MAT_FT_MAT5, MAT_FT_MAT73}) {
      CAPTURE(static_cast<int>(version));
      const std::string path = tmp / (version == MAT_FT_MAT5 ? "v5.mat" : "v73.mat");
      {
        std::unique_ptr<mat_t, MatCloser> mat(Mat_CreateVer(path.c_str(), nullptr, version));
        REQUIRE(mat);
        mat_write(mat.get(), "cube_hwb", {H, W, B}, MAT_C_DOUBLE, MAT_T_DOUBLE, hwb);
        mat_write(mat.get(), "cube_bhw", {B, H, W}, MAT_C_UINT16, MAT_T_UINT16, bhw);
        mat_write(mat.get(), "flat", {2, 2}, MAT_C_DOUBLE, MAT_T_DOUBLE, std::vector<double>{1, 2, 3, 4});
      }
      CubeReadOptions o;
      o.key = "cube_hwb";
      for (std::size_t expected : {std::size_t(0), B}) {
        o.expected_bands = expected;  // 0: assume hwb; 5: the last axis has 5
        const RealStack c = read_cube(path, o);
        REQUIRE(c.planes == B);
        REQUIRE(c.rows == H);
        REQUIRE(c.cols == W);
        for (std::size_t k = 0; k < B; ++k)
          for (std::size_t i = 0; i < H; ++i)
            for (std::size_t j = 0; j < W; ++j) CHECK(c(k, i, j) == value(i, j, k, 100, 10, 1) + 0.5);  // float: scale 1
      }
      o.scale = 2;
      CHECK(read_cube(path, o)(4, 3, 2) == (320.0 + 4.5) / 2);

      o = CubeReadOptions{};
      o.key = "cube_bhw";
      o.layout = "bhw";
      const RealStack c = read_cube(path, o);
      REQUIRE(c.planes == B);
      REQUIRE(c.rows == H);
      REQUIRE(c.cols == W);
      for (std::size_t b = 0; b < B; ++b)
        for (std::size_t y = 0; y < H; ++y)
          for (std::size_t x = 0; x < W; ++x) CHECK(c(b, y, x) == value(b, y, x, 1000, 10, 1) / 65535.0);
      o.layout = "auto";
      o.expected_bands = B;  // the last axis (3) does not match; the first (5) does
      CHECK(read_cube(path, o).data == c.data);

      // No key with two 3-D variables: the error lists both.
      std::string msg = input_error_of([&] { read_cube(path); });
      CHECK(contains(msg, path));
      CHECK(contains(msg, "cube_hwb"));
      CHECK(contains(msg, "cube_bhw"));
      o.key = "nope";
      msg = input_error_of([&] { read_cube(path, o); });
      CHECK(contains(msg, "nope"));
      CHECK(contains(msg, path));
      o.key = "flat";
      CHECK(contains(input_error_of([&] { read_cube(path, o); }), "3-D"));

      // The same file truncated: an InputError naming it, never zeros or a crash.
      const std::string cut = tmp / "cut.mat";
      const std::string full = slurp(path);
      for (const std::size_t bytes : {full.size() * 2 / 3, full.size() - 8, std::size_t(600)}) {
        CAPTURE(bytes);
        write_text_atomic(cut, full.substr(0, bytes));
        o.key = "cube_hwb";
        CHECK(contains(input_error_of([&] { read_cube(cut, o); }), "cut.mat"));
      }
    }

    // One 3-D variable only (plus a 2-D one): found without a key; non-finite values rejected.
    const std::string one = tmp / "one.mat";
    std::vector<double> with_nan(hwb);
    with_nan[7] = std::numeric_limits<double>::infinity();
    {
      std::unique_ptr<mat_t, MatCloser> mat(Mat_CreateVer(one.c_str(), nullptr, MAT_FT_MAT5));
      REQUIRE(mat);
      mat_write(mat.get(), "flat", {2, 2}, MAT_C_DOUBLE, MAT_T_DOUBLE, std::vector<double>{1, 2, 3, 4});
      mat_write(mat.get(), "x", {H, W, B}, MAT_C_DOUBLE, MAT_T_DOUBLE, with_nan);
    }
    const std::string msg = input_error_of([&] { read_cube(one); });
    CHECK(contains(msg, "one.mat"));
    CHECK(contains(msg, "1 non-finite"));
  }

  TEST_CASE("read_cube refuses a compressed .mat variable with corrupted payload bytes") {
    // libmatio ignores zlib errors: a compressed v5 variable with a few damaged bytes used to
    // load silently as different data. Every byte must decode, with zlib's end of stream and
    // adler32 check; the error names the file and the variable.
    TmpDir tmp;
    const std::size_t H = 6, W = 5, B = 4;
    std::vector<double> cube(H * W * B);
    for (std::size_t i = 0; i < cube.size(); ++i) cube[i] = 0.25 + 0.5 * std::sin(0.37 * static_cast<double>(i));
    const std::string path = tmp / "zlib.mat";
    {
      std::unique_ptr<mat_t, MatCloser> mat(Mat_CreateVer(path.c_str(), nullptr, MAT_FT_MAT5));
      REQUIRE(mat);
      mat_write(mat.get(), "scene", {H, W, B}, MAT_C_DOUBLE, MAT_T_DOUBLE, cube, MAT_COMPRESSION_ZLIB);
    }
    CubeReadOptions o;
    o.key = "scene";
    const RealStack good = read_cube(path, o);
    REQUIRE(good.planes == B);
    CHECK(good(1, 2, 3) == cube[2 + H * 3 + H * W * 1]);

    const std::string full = slurp(path);
    REQUIRE(full.size() > 128 + 8 + 64);
    REQUIRE(static_cast<unsigned char>(full[128]) == 15);  // one miCOMPRESSED element
    const std::size_t payload = 136, end = full.size();
    const std::string bad = tmp / "bad.mat";
    // Bytes in the middle of the deflate data, near its end and in the adler32 trailer.
    for (const std::size_t at : {payload + (end - payload) / 2, payload + (end - payload) * 3 / 4, end - 6, end - 2}) {
      CAPTURE(at);
      std::string b = full;
      b[at] = static_cast<char>(b[at] ^ 0x5a);
      write_text_atomic(bad, b);
      const std::string msg = input_error_of([&] { read_cube(bad, o); });
      CHECK(contains(msg, bad));
      CHECK(contains(msg, "variable 'scene'"));
      CHECK(contains(msg, "corrupt"));
      CHECK(contains(input_error_of([&] { read_cube(bad); }), bad));  // the variable scan checks it too
    }
    // Damage at the start of the stream (zlib header, array header): refused, naming the file.
    for (const std::size_t at : {payload, payload + 1, payload + 5}) {
      CAPTURE(at);
      std::string b = full;
      b[at] = static_cast<char>(b[at] ^ 0x5a);
      write_text_atomic(bad, b);
      CHECK(contains(input_error_of([&] { read_cube(bad, o); }), bad));
    }
  }
}
