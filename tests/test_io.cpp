// Tests of the file I/O layer (src/io_*.cpp): HDF5 contract files, .mat cubes, CSV, PNG.
#include <doctest/doctest.h>
#include <hdf5.h>
#include <matio.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "common.hpp"
#include "qdo/error.hpp"
#include "qdo/io.hpp"

namespace fs = std::filesystem;
using namespace qdo;
using qdo::test::input_error_of;
using qdo::test::slurp;

namespace {

// A fresh directory under the temp dir, removed with everything in it at scope exit.
struct TmpDir {
  fs::path dir;
  TmpDir() {
    static int counter = 0;
    dir = fs::temp_directory_path() /
          ("qdo_io_test_" + std::to_string(static_cast<long>(::getpid())) + "_" + std::to_string(counter++));
    fs::remove_all(dir);
    fs::create_directories(dir);
  }
  ~TmpDir() {
    std::error_code ec;
    fs::remove_all(dir, ec);
  }
  std::string operator/(const std::string& name) const { return (dir / name).string(); }
  std::size_t entries() const {
    return static_cast<std::size_t>(std::distance(fs::directory_iterator(dir), fs::directory_iterator()));
  }
};

bool contains(const std::string& s, const std::string& part) { return s.find(part) != std::string::npos; }


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
const fs::path kDataDir = fs::path(__FILE__).parent_path().parent_path() / "data";

}  // namespace

TEST_SUITE("io") {
  TEST_CASE("design round trip keeps heights, pitch, levels and provenance") {
    TmpDir tmp;
    Design d;
    d.height_m = Map2D(3, 3);
    for (std::size_t i = 0; i < 9; ++i) d.height_m.data[i] = 1e-7 * static_cast<double>(i) - 3e-7;
    d.pitch_m = 2.5e-6;
    d.levels_m = {0.0, 1e-7, 2e-7, 3e-7};
    const std::string path = tmp / "design.h5";
    write_design(path, d, {{"commit", "abc123"}, {"tool", "qdo"}});
    CHECK(tmp.entries() == 1);  // no temp file left
    const Design r = read_design(path);
    CHECK(r.height_m.rows == 3);
    CHECK(r.height_m.cols == 3);
    CHECK(r.height_m.data == d.height_m.data);
    CHECK(r.pitch_m == d.pitch_m);
    CHECK(r.levels_m == d.levels_m);
    CHECK(h5_has(path, "/levels_m"));
    CHECK_FALSE(h5_has(path, "/nothing"));
    CHECK_FALSE(h5_has(path, "/no/such/group"));
    const H5Dataset h = h5_read(path, "height_m");
    CHECK(h.str_attrs.at("units") == "m");

    // Root string attribute, read independently with the HDF5 C API.
    hid_t f = H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
    REQUIRE(f >= 0);
    hid_t a = H5Aopen(f, "commit", H5P_DEFAULT);
    REQUIRE(a >= 0);
    hid_t t = H5Aget_type(a);
    CHECK(H5Tget_class(t) == H5T_STRING);
    CHECK(H5Tis_variable_str(t) == 0);
    std::string buf(H5Tget_size(t) + 1, '\0');
    CHECK(H5Aread(a, t, buf.data()) >= 0);
    CHECK(std::string(buf.c_str()) == "abc123");
    H5Tclose(t);
    H5Aclose(a);
    H5Fclose(f);

    // Without levels: the dataset is absent and levels_m stays empty.
    d.levels_m.clear();
    write_design(path, d);
    CHECK_FALSE(h5_has(path, "/levels_m"));
    CHECK(read_design(path).levels_m.empty());
  }

  TEST_CASE("write_psf, write_cube, write_rgb round trip") {
    TmpDir tmp;
    RealStack psf(2, 4, 4);
    for (std::size_t i = 0; i < psf.size(); ++i) psf.data[i] = std::sin(static_cast<double>(i));
    const std::string p = tmp / "psf.h5";
    write_psf(p, psf, {450, 550}, 1e-6, {{"z_m", 0.05}});
    const H5Dataset r = h5_read(p, "/psf");
    CHECK(r.shape == std::vector<std::size_t>{2, 4, 4});
    CHECK(r.data == psf.data);
    CHECK(r.num_attrs.at("pitch_m") == 1e-6);
    CHECK(r.num_attrs.at("z_m") == 0.05);
    const H5Dataset w = h5_read(p, "/wavelengths_nm");
    CHECK(w.data == std::vector<double>{450, 550});
    CHECK(w.str_attrs.at("units") == "nm");
    CHECK_THROWS_AS(write_psf(p, psf, {450}, 1e-6), InputError);

    RealStack cube(3, 5, 7);
    for (std::size_t i = 0; i < cube.size(); ++i) cube.data[i] = static_cast<double>(i) / 104.0;
    const std::string c = tmp / "cube.h5";
    write_cube(c, cube, {400, 500, 600});
    const RealStack back = read_cube(c);
    CHECK(back.planes == 3);
    CHECK(back.rows == 5);
    CHECK(back.cols == 7);
    CHECK(back.data == cube.data);
    CubeReadOptions o;
    o.expected_bands = 3;
    CHECK(read_cube(c, o).data == cube.data);  // auto prefers the first axis for HDF5
    o.expected_bands = 7;                      // last axis: read as hwb -> 7 x 3 x 5
    const RealStack hwb = read_cube(c, o);
    CHECK(hwb.planes == 7);
    CHECK(hwb.rows == 3);
    CHECK(hwb.cols == 5);
    CHECK(hwb(6, 2, 4) == cube(2, 4, 6));
    CHECK(hwb(1, 0, 3) == cube(0, 3, 1));
    o.expected_bands = 4;
    const std::string msg = input_error_of([&] { read_cube(c, o); });
    CHECK(contains(msg, c));
    CHECK(contains(msg, "[3 x 5 x 7]"));
    CHECK(contains(msg, "4"));

    RealStack rgb(3, 2, 2, 0.25);
    write_rgb(tmp / "rgb.h5", rgb);
    CHECK(h5_read(tmp / "rgb.h5", "/rgb").shape == std::vector<std::size_t>{3, 2, 2});
    CHECK_THROWS_AS(write_rgb(tmp / "bad.h5", RealStack(2, 2, 2)), InputError);
  }

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

  TEST_CASE("an output stage takes files from several threads at once (figures written beside HDF5 files)") {
    // Temporary files made first, then committed from 4 threads in a tight loop: the stage's
    // list is shared, so unguarded appends lose or corrupt entries.
    const auto dir = qdo::test::temp_dir("io_stage_threads");
    constexpr int kThreads = 4, kFiles = 2000;
    auto name = [&](int k, int i) { return (dir / ("f" + std::to_string(k) + "_" + std::to_string(i) + ".txt")).string(); };
    for (int k = 0; k < kThreads; ++k)
      for (int i = 0; i < kFiles; ++i) std::ofstream(name(k, i) + ".tmp") << "x\n";
    {
      OutputStage stage(true);
      std::vector<std::thread> threads;
      for (int k = 0; k < kThreads; ++k)
        threads.emplace_back([&, k] {
          for (int i = 0; i < kFiles; ++i) commit_output(name(k, i) + ".tmp", name(k, i));
        });
      for (auto& th : threads) th.join();
      CHECK_FALSE(std::filesystem::exists(name(0, 0)));  // deferred until the stage commits
      stage.commit();
    }
    std::size_t n = 0;
    for (const auto& e : std::filesystem::directory_iterator(dir)) n += e.path().extension() == ".txt";
    CHECK(n == std::size_t(kThreads * kFiles));
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("float32 datasets: stored in 4 bytes, read back to float rounding; values beyond float32 refused") {
    const auto dir = qdo::test::temp_dir("io_f32");
    const std::string p = (dir / "f.h5").string(), q = (dir / "d.h5").string();
    std::vector<double> v(4096);
    for (std::size_t i = 0; i < v.size(); ++i) v[i] = std::sin(0.37 * double(i)) * 1e-3;
    H5Dataset f{"/x", {64, 64}, v, {}, {}};
    f.float32 = true;
    H5Dataset d = f;
    d.float32 = false;
    h5_write(p, {f});
    h5_write(q, {d});
    const H5Dataset r = h5_read(p, "/x");
    REQUIRE(r.data.size() == v.size());
    for (std::size_t i = 0; i < v.size(); ++i) CHECK(r.data[i] == double(float(v[i])));
    CHECK(std::filesystem::file_size(q) - std::filesystem::file_size(p) == 4 * v.size());
    f.data[7] = 1e39;
    CHECK_THROWS_WITH_AS(h5_write((dir / "big.h5").string(), {f}), doctest::Contains("float32"), NumericalError);
    CHECK_FALSE(std::filesystem::exists(dir / "big.h5"));
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("large float32 datasets are written in slabs (a partial last one included) and from a view without a copy") {
    const auto dir = qdo::test::temp_dir("io_f32_slabs");
    // 5 x 600 x 600: 360,000 values per leading entry, so slabs of 2, 2 and 1 entries.
    std::vector<double> v(5 * 600 * 600);
    for (std::size_t i = 0; i < v.size(); ++i) v[i] = std::cos(1e-3 * double(i)) + double(i / 360000);
    H5Dataset f{"/stack", {5, 600, 600}, {}, {}, {}};
    f.view = &v;
    f.float32 = true;
    // A rank-1 dataset of 2^20 + 3 values: slabs of 2^20 and 3 along its only axis.
    std::vector<double> w((std::size_t(1) << 20) + 3);
    for (std::size_t i = 0; i < w.size(); ++i) w[i] = double(i % 977) * 0.5;
    H5Dataset g{"/line", {w.size()}, w, {}, {}};
    g.float32 = true;
    const std::string p = (dir / "slabs.h5").string();
    h5_write(p, {f, g});
    CHECK(f.data.empty());  // the view was not copied into the dataset
    const H5Dataset r = h5_read(p, "/stack"), rl = h5_read(p, "/line");
    REQUIRE(r.data.size() == v.size());
    std::size_t bad = 0;
    for (std::size_t i = 0; i < v.size(); ++i) bad += r.data[i] != double(float(v[i]));
    CHECK(bad == 0);
    REQUIRE(rl.data.size() == w.size());
    bad = 0;
    for (std::size_t i = 0; i < w.size(); ++i) bad += rl.data[i] != double(float(w[i]));
    CHECK(bad == 0);
    // The checks before writing see the view too: a NaN in it is refused, nothing written.
    v[123456] = std::nan("");
    CHECK_THROWS_AS(h5_write((dir / "nan.h5").string(), {f}), NumericalError);
    CHECK_FALSE(std::filesystem::exists(dir / "nan.h5"));
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("float32 datasets from a float view: written as they are, plain and compressed; NaN and misuse refused") {
    const auto dir = qdo::test::temp_dir("io_f32_view");
    // 3 x 300 x 500 floats (4.5 MB: compressed as one chunk per plane when asked).
    std::vector<float> v(3 * 300 * 500);
    for (std::size_t i = 0; i < v.size(); ++i) v[i] = float(std::sin(1e-3 * double(i))) * 1e-5f + float(i % 7);
    for (const bool compress : {false, true}) {
      CAPTURE(compress);
      H5Dataset f{"/stack", {3, 300, 500}, {}, {}, {}};
      f.f32_view = v.data();
      f.f32_count = v.size();
      f.float32 = true;
      f.compress = compress;
      const std::string p = (dir / (compress ? "z.h5" : "plain.h5")).string();
      h5_write(p, {f});
      const H5Dataset r = h5_read(p, "/stack");
      REQUIRE(r.shape == std::vector<std::size_t>{3, 300, 500});
      REQUIRE(r.data.size() == v.size());
      std::size_t bad = 0;
      for (std::size_t i = 0; i < v.size(); ++i) bad += r.data[i] != double(v[i]);
      CHECK(bad == 0);
    }
    H5Dataset f{"/stack", {3, 300, 500}, {}, {}, {}};
    f.f32_view = v.data();
    f.f32_count = v.size();
    // Without float32 set, or with a shape that does not match the count: refused, nothing written.
    CHECK_THROWS_WITH_AS(h5_write((dir / "no32.h5").string(), {f}), doctest::Contains("f32_view"), InputError);
    CHECK_FALSE(std::filesystem::exists(dir / "no32.h5"));
    f.float32 = true;
    f.f32_count = v.size() - 1;
    CHECK_THROWS_WITH_AS(h5_write((dir / "short.h5").string(), {f}), doctest::Contains("does not match"), InputError);
    CHECK_FALSE(std::filesystem::exists(dir / "short.h5"));
    f.f32_count = v.size();
    v[4321] = std::numeric_limits<float>::infinity();
    CHECK_THROWS_WITH_AS(h5_write((dir / "inf.h5").string(), {f}), doctest::Contains("NaN or Inf"), NumericalError);
    CHECK_FALSE(std::filesystem::exists(dir / "inf.h5"));
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("compressed datasets: chunked with HDF5's shuffle + deflate, read back exactly, edge chunks included") {
    const auto dir = qdo::test::temp_dir("io_deflate");
    // 2 x 1100 x 1000 float64: a plane is 8.8 MB, so chunks are bands of 524 rows (4 MiB) and the
    // last band of each plane is a partial edge chunk; 3 x 300 x 500 float32: one chunk per plane.
    for (const bool f32 : {false, true}) {
      const std::size_t planes = f32 ? 3 : 2, rows = f32 ? 300 : 1100, cols = f32 ? 500 : 1000;
      std::vector<double> v(planes * rows * cols);
      for (std::size_t i = 0; i < v.size(); ++i) v[i] = std::floor(4 * (0.5 + 0.5 * std::sin(0.001 * double(i)))) * 1e-7 +
                                                       (i % 977 == 0 ? std::sin(double(i)) : 0.0);
      H5Dataset d{"/g/x", {planes, rows, cols}, v, {{"pitch_m", 4e-6}}, {{"units", "m"}}};
      d.float32 = f32;
      d.compress = true;
      H5Dataset plain = d;
      plain.compress = false;
      const std::string pc = (dir / (f32 ? "c32.h5" : "c64.h5")).string(), pp = (dir / (f32 ? "p32.h5" : "p64.h5")).string();
      h5_write(pc, {d});
      h5_write(pp, {plain});
      const H5Dataset r = h5_read(pc, "/g/x");
      CHECK(r.shape == d.shape);
      CHECK(r.num_attrs.at("pitch_m") == 4e-6);
      REQUIRE(r.data.size() == v.size());
      std::size_t mismatches = 0;
      for (std::size_t i = 0; i < v.size(); ++i) mismatches += r.data[i] != (f32 ? double(float(v[i])) : v[i]);
      CHECK(mismatches == 0);
      CHECK(h5_read(pp, "/g/x").data == r.data);
      // Smaller on disk, and stored the way any HDF5 reader expects: chunked, 2 filters.
      CHECK(std::filesystem::file_size(pc) * 4 < std::filesystem::file_size(pp));
      const hid_t file = H5Fopen(pc.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
      REQUIRE(file >= 0);
      const hid_t ds = H5Dopen2(file, "/g/x", H5P_DEFAULT);
      const hid_t dcpl = H5Dget_create_plist(ds);
      CHECK(H5Pget_layout(dcpl) == H5D_CHUNKED);
      CHECK(H5Pget_nfilters(dcpl) == 2);
      hsize_t chunk[3] = {0, 0, 0};
      CHECK(H5Pget_chunk(dcpl, 3, chunk) == 3);
      CHECK(chunk[0] == 1);
      CHECK(chunk[1] == (f32 ? 300u : 524u));
      CHECK(chunk[2] == cols);
      H5Pclose(dcpl);
      H5Dclose(ds);
      H5Fclose(file);
    }
    // Small datasets stay contiguous even when asked (chunk overhead would exceed the gain).
    H5Dataset small{"/s", {16, 16}, std::vector<double>(256, 1.0), {}, {}};
    small.compress = true;
    const std::string ps = (dir / "s.h5").string();
    h5_write(ps, {small});
    const hid_t file = H5Fopen(ps.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
    const hid_t ds = H5Dopen2(file, "/s", H5P_DEFAULT);
    const hid_t dcpl = H5Dget_create_plist(ds);
    CHECK(H5Pget_layout(dcpl) != H5D_CHUNKED);
    H5Pclose(dcpl);
    H5Dclose(ds);
    H5Fclose(file);
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("a compressed dataset whose chunk bytes were damaged is refused naming the file, not read as garbage") {
    const auto dir = qdo::test::temp_dir("io_deflate_bad");
    std::vector<double> v(2 * 512 * 512);
    for (std::size_t i = 0; i < v.size(); ++i) v[i] = double(i % 7) * 0.25;
    H5Dataset d{"/x", {2, 512, 512}, v, {}, {}};
    d.compress = true;
    const std::string p = (dir / "x.h5").string();
    h5_write(p, {d});
    // Overwrite bytes in the middle of the file (inside the compressed chunks).
    {
      std::fstream f(p, std::ios::in | std::ios::out | std::ios::binary);
      const auto size = static_cast<std::streamoff>(std::filesystem::file_size(p));
      f.seekp(size / 2);
      const std::string junk(64, '\x5a');
      f.write(junk.data(), static_cast<std::streamsize>(junk.size()));
    }
    CHECK_THROWS_WITH_AS(h5_read(p, "/x"), doctest::Contains("x.h5"), InputError);
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("h5_read errors name the file and the dataset") {
    TmpDir tmp;
    const std::string path = tmp / "x.h5";
    h5_write(path, {H5Dataset{"/a", {2}, {1, 2}, {}, {}}});
    std::string msg = input_error_of([&] { h5_read(path, "/missing_thing"); });
    CHECK(contains(msg, path));
    CHECK(contains(msg, "/missing_thing"));
    msg = input_error_of([&] { h5_read(path, "/a", 1); });  // over max_elements
    CHECK(contains(msg, "/a"));
    CHECK(contains(msg, "limit"));
    msg = input_error_of([&] { h5_read(tmp / "absent.h5", "/a"); });
    CHECK(contains(msg, "absent.h5"));
    write_text_atomic(tmp / "text.h5", "not hdf5 at all\n");
    msg = input_error_of([&] { h5_read(tmp / "text.h5", "/a"); });
    CHECK(contains(msg, "text.h5"));
    CHECK(contains(msg, "HDF5"));
  }

  TEST_CASE("read_design rejects bad designs with a message naming the problem") {
    TmpDir tmp;
    const std::string path = tmp / "d.h5";
    h5_write(path, {H5Dataset{"/height_m", {2, 3}, std::vector<double>(6, 0.0), {{"pitch_m", 1e-6}}, {}}});
    std::string msg = input_error_of([&] { read_design(path); });
    CHECK(contains(msg, path));
    CHECK(contains(msg, "square"));

    std::vector<double> h(4, 0.0);
    h[2] = std::numeric_limits<double>::quiet_NaN();
    CHECK_THROWS_AS(h5_write(path, {H5Dataset{"/height_m", {2, 2}, h, {{"pitch_m", 1e-6}}, {}}}), NumericalError);
    CHECK_FALSE(std::filesystem::exists(path + ".tmp-" + std::to_string(::getpid())));
    h5_write_unchecked(path, {H5Dataset{"/height_m", {2, 2}, h, {{"pitch_m", 1e-6}}, {}}});
    msg = input_error_of([&] { read_design(path); });
    CHECK(contains(msg, "non-finite"));
    CHECK(contains(msg, "height_m"));

    h5_write(path, {H5Dataset{"/height_m", {2, 2}, std::vector<double>(4, 0.0), {}, {}}});
    msg = input_error_of([&] { read_design(path); });
    CHECK(contains(msg, "pitch_m"));
    CHECK(contains(msg, "missing"));

    for (double bad : {-1e-6, 0.0, std::numeric_limits<double>::quiet_NaN()}) {
      h5_write_unchecked(path, {H5Dataset{"/height_m", {2, 2}, std::vector<double>(4, 0.0), {{"pitch_m", bad}}, {}}});
      msg = input_error_of([&] { read_design(path); });
      CHECK(contains(msg, "pitch_m"));
      CHECK(contains(msg, "invalid"));
    }
    msg = input_error_of([&] { read_design(tmp / "none.h5"); });
    CHECK(contains(msg, "none.h5"));
  }

  TEST_CASE("a failed write leaves no file behind") {
    TmpDir tmp;
    const std::string missing_dir = tmp / "no_such_dir/out.h5";
    CHECK_THROWS_AS(h5_write(missing_dir, {H5Dataset{"/a", {1}, {1.0}, {}, {}}}), InputError);
    CHECK_THROWS_AS(write_png(tmp / "no_such_dir/x.png", 1, 1, 1, {0}), InputError);
    CHECK_THROWS_AS(write_text_atomic(tmp / "no_such_dir/x.txt", "x"), InputError);
    CHECK(tmp.entries() == 0);

    // The second dataset's shape does not match its data: the file was already being written.
    const std::string target = tmp / "half.h5";
    const std::string msg = input_error_of([&] {
      h5_write(target, {H5Dataset{"/good", {2, 2}, {1, 2, 3, 4}, {}, {}}, H5Dataset{"/bad", {3, 3}, {1, 2}, {}, {}}});
    });
    CHECK(contains(msg, "/bad"));
    CHECK(contains(msg, "half.h5"));
    CHECK(tmp.entries() == 0);  // neither target nor temp file

    // An existing file is untouched by a failed overwrite.
    write_text_atomic(target, "old");
    CHECK_THROWS_AS(h5_write(target, {H5Dataset{"/bad", {2}, {1}, {}, {}}}), InputError);
    CHECK(slurp(target) == "old");
    CHECK(tmp.entries() == 1);
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

  TEST_CASE("CSV tables from data/") {
    const CsvTable srf = read_csv((kDataDir / "srf_FLIR_GS3-U3-41S4C.csv").string());
    CHECK(srf.header == std::vector<std::string>{"wavelength_nm", "R", "G", "B"});
    REQUIRE(srf.column("R").size() == 31);
    CHECK(srf.column("R")[0] == 7.111793475);
    CHECK(srf.column("wavelength_nm")[0] == 400);
    CHECK(srf.column("wavelength_nm")[30] == 700);
    CHECK(srf.comments.size() == 4);

    const CsvTable cc = read_csv((kDataDir / "colorchecker24_400-700nm_10nm.csv").string());
    REQUIRE(cc.header.size() == 32);
    CHECK(cc.header[0] == "name");
    REQUIRE(cc.raw[0].size() == 24);
    CHECK(cc.raw[0][0] == "dark skin");
    CHECK(std::isnan(cc.columns[0][0]));
    CHECK(cc.column("400")[0] == 0.061);
    CHECK(cc.column("700")[0] == 0.182);
    const std::string msg = input_error_of([&] { cc.column("750"); });
    CHECK(contains(msg, "750"));
    CHECK(contains(msg, "name, 400, 410"));

    const CsvTable d65 = read_csv((kDataDir / "cie_d65_400-700nm_10nm.csv").string());
    CHECK(d65.column("relative_power")[0] == 82.7549);
  }

  TEST_CASE("CSV parsing details and malformed input") {
    const CsvTable t = parse_csv("# c1\n\n a , b \n1, 2\r\n  \n# c2\n3,x\n", "mem");
    CHECK(t.header == std::vector<std::string>{"a", "b"});
    CHECK(t.comments == std::vector<std::string>{"c1", "c2"});
    CHECK(t.column("a") == std::vector<double>{1, 3});
    CHECK(t.columns[1][0] == 2);
    CHECK(std::isnan(t.columns[1][1]));
    CHECK(t.raw[1][1] == "x");

    std::string msg = input_error_of([] { parse_csv("# c\na,b\n1,2\n3,4,5\n", "ragged.csv"); });
    CHECK(contains(msg, "ragged.csv"));
    CHECK(contains(msg, "line 4"));
    msg = input_error_of([] { parse_csv("# only comments\n", "empty.csv"); });
    CHECK(contains(msg, "empty.csv"));
    CHECK_THROWS_AS(read_csv("/nonexistent/table.csv"), InputError);
  }

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

    // 5 planes of 10 x 12 -> 3 x 2 grid with 2 px gaps.
    RealStack s(5, 10, 12);
    for (std::size_t i = 0; i < s.size(); ++i) s.data[i] = static_cast<double>(i % 17);
    const std::string m = tmp / "montage.png";
    write_montage_png(m, s, {400, 450, 500, 600, 700});
    h = png_header(m);
    CHECK(h.signature_ok);
    CHECK(h.width == 3 * 12 + 2 * 2);
    CHECK(h.height == 2 * 10 + 2);
    CHECK(h.color_type == 2);
    write_montage_png(m, s, {}, 1.0, 6);  // centre 6 x 6 crop, gray
    h = png_header(m);
    CHECK(h.width == 3 * 6 + 2 * 2);
    CHECK(h.height == 2 * 6 + 2);
    CHECK_THROWS_AS(write_montage_png(m, s, {400, 500}), InputError);

    RealStack big(1, 600, 600, 1.0);  // tiles larger than 256 px are box-averaged down
    write_montage_png(m, big, {});
    h = png_header(m);
    CHECK(h.width <= 256);
    CHECK(h.width == 200);

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
    for (std::size_t i = 0; i < map.data.size(); ++i) map.data[i] = static_cast<double>(i) * 1e-7;
    const std::string mp = tmp / "map.png";
    write_map_png(mp, map);
    h = png_header(mp);
    CHECK(h.signature_ok);
    CHECK(h.width == 9);
    CHECK(h.height == 7);
    write_map_png(mp, Map2D(2, 2, 3.0));  // constant map: mid colour, no division by zero
    CHECK(png_header(mp).signature_ok);
    Map2D bad(2, 2);
    bad.data[1] = std::numeric_limits<double>::quiet_NaN();
    CHECK_THROWS_AS(write_map_png(mp, bad), NumericalError);  // an output that is not finite: nothing written,
    CHECK(png_header(mp).signature_ok);                         // the earlier file of that name kept as it was
    CHECK(tmp.entries() == 4);  // gray, montage, rgb, map: no temp files
  }
}
