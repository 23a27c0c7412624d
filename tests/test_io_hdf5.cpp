// Tests of the file I/O layer (src/data/io_*.cpp), HDF5: contract files (design, PSF, cube, RGB)
// round trip, float32 and compressed datasets, and the errors of h5_read and read_design.
#include <doctest/doctest.h>
#include <hdf5.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <string>
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
    const H5Dataset r = h5_read(p, "/psf_sensor");
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
}
