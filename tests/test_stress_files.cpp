// Stability suite (doctest suite "stress", STABILITY.md): hostile input to every reader
// (JSON configurations, HDF5 designs, cubes and checkpoints, .mat v5 and v7.3, PNG band
// folders, CSV tables): truncated, corrupt, mistyped, misshapen or absurdly large files are
// InputErrors naming the file, never a crash or a silent misread.
#include <hdf5.h>
#include <matio.h>
#include <png.h>
#include <zlib.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "stress_common.hpp"
#include "qdo/data/datasets.hpp"
#include "qdo/design/design.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/design/run.hpp"

using namespace qdo;
using namespace qdo::test;
using namespace qdo::test::stress_suite;
namespace fs = std::filesystem;

namespace {

// Runs `reader` on truncations of `good` at many lengths and on copies with bytes flipped at
// many positions (deterministic): each either succeeds (then `accept` checks the result) or
// throws an InputError naming the file. Returns how many variants were rejected.
std::size_t mutate_and_read(const std::string& path, const std::string& good, const std::function<void()>& reader,
                            std::size_t variants = 96) {
  std::size_t rejected = 0;
  std::mt19937_64 rng(1234);
  for (std::size_t k = 0; k < variants; ++k) {
    std::string bad = good;
    if (k % 2 == 0) {
      bad.resize(good.size() * k / variants);  // truncated (0 .. almost all of it)
    } else {
      const std::size_t flips = 1 + k % 7;
      for (std::size_t f = 0; f < flips; ++f) bad[rng() % bad.size()] = static_cast<char>(rng() & 0xff);
    }
    spit(path, bad);
    const std::string err = input_error(reader);
    if (!err.empty()) {
      ++rejected;
      CAPTURE(k);
      CAPTURE(err);
      CHECK(has(err, path));
    }
  }
  return rejected;
}

struct MatCloser {
  void operator()(mat_t* m) const { Mat_Close(m); }
};
struct MatVarFreer {
  void operator()(matvar_t* v) const { Mat_VarFree(v); }
};
template <typename T>
void write_mat(const std::string& path, mat_ft ver, const std::string& name, std::vector<std::size_t> dims, matio_classes cls,
               matio_types type, std::vector<T> data, matio_compression comp = MAT_COMPRESSION_NONE) {
  std::unique_ptr<mat_t, MatCloser> m(Mat_CreateVer(path.c_str(), nullptr, ver));
  REQUIRE(m);
  std::unique_ptr<matvar_t, MatVarFreer> v(
      Mat_VarCreate(name.c_str(), cls, type, int(dims.size()), dims.data(), data.data(), MAT_F_DONT_COPY_DATA));
  REQUIRE(v);
  REQUIRE(Mat_VarWrite(m.get(), v.get(), comp) == 0);
}

void write_png_gray(const std::string& path, std::uint32_t w, std::uint32_t h, bool sixteen) {
  png_image img;
  std::memset(&img, 0, sizeof img);
  img.version = PNG_IMAGE_VERSION;
  img.width = w;
  img.height = h;
  img.format = sixteen ? PNG_FORMAT_LINEAR_Y : PNG_FORMAT_GRAY;
  std::vector<std::uint16_t> px(std::size_t(w) * h);
  for (std::size_t i = 0; i < px.size(); ++i) px[i] = static_cast<std::uint16_t>((i * 2654435761u) & (sixteen ? 0xffff : 0xff));
  std::vector<std::uint8_t> px8(px.begin(), px.end());
  const int ok = png_image_write_to_file(&img, path.c_str(), 0, sixteen ? static_cast<const void*>(px.data()) : px8.data(), 0, nullptr);
  png_image_free(&img);
  REQUIRE(ok);
}

std::uint32_t crc32(const unsigned char* p, std::size_t n) {
  std::uint32_t c = 0xffffffffu;
  for (std::size_t i = 0; i < n; ++i) {
    c ^= p[i];
    for (int k = 0; k < 8; ++k) c = (c >> 1) ^ (0xedb88320u & (0u - (c & 1u)));
  }
  return c ^ 0xffffffffu;
}

// A PNG whose IHDR declares width x height (gray 16-bit) followed by a tiny IDAT and IEND,
// with valid CRCs: a header that promises far more pixels than the file holds.
std::string png_claiming(std::uint32_t width, std::uint32_t height) {
  std::string s("\x89PNG\r\n\x1a\n", 8);
  auto be32 = [](std::uint32_t v) {
    std::string b(4, '\0');
    for (int i = 0; i < 4; ++i) b[std::size_t(i)] = char((v >> (24 - 8 * i)) & 0xff);
    return b;
  };
  auto chunk = [&](const std::string& type, const std::string& data) {
    std::string body = type + data;
    s += be32(std::uint32_t(data.size())) + body +
         be32(crc32(reinterpret_cast<const unsigned char*>(body.data()), body.size()));
  };
  std::string ihdr = be32(width) + be32(height);
  ihdr += std::string("\x10\x00\x00\x00\x00", 5);  // bit depth 16, gray, deflate, filter 0, no interlace
  chunk("IHDR", ihdr);
  chunk("IDAT", std::string("\x78\x9c\x63\x00\x00\x00\x01\x00\x01", 9));  // zlib stream of one zero byte
  chunk("IEND", "");
  return s;
}

}  // namespace

TEST_SUITE("stress") {
  TEST_CASE("JSON configuration: deep nesting, huge and non-finite numbers, wrong types are named InputErrors [cpu]") {
    // A value nested 300,000 deep (under the 1 MiB cap): rejected naming the key, without
    // recursing through it (regression: the message used to dump the whole value recursively).
    const std::string deep = "{\"n\": " + std::string(300000, '[') + std::string(300000, ']') + "}";
    const std::string e1 = input_error([&] { config_from_json_text(deep, "deep.json"); });
    CHECK(has(e1, "deep.json"));
    CHECK(has(e1, "'n'"));
    CHECK(e1.size() < 400);
    // A huge string value is quoted, but shortened.
    const std::string e2 = input_error([&] { config_from_json_text("{\"pitch_m\": \"" + std::string(500000, 'x') + "\"}", "s.json"); });
    CHECK(has(e2, "'pitch_m'"));
    CHECK(e2.size() < 400);
    for (const std::string doc : {R"({"pitch_m": 1e999})", R"({"pitch_m": -1e-999})", R"({"n": 1e20})", R"({"n": -32})",
                            R"({"n": 18446744073709551615})", R"({"n": 64.5})", R"({"bands": 0})", R"({"noise_seed": -1})",
                            R"({"scene_distance_m": "-inf"})", R"({"sensor_distance_m": 0})", R"({"strict_sampling": "yes"})",
                            R"({"preset": ["small"]})", R"({"preset": "huge"})", R"({"camera": ""})"}) {
      CAPTURE(doc);
      const std::string e = input_error([&] { config_from_json_text(doc, "h.json"); });
      CHECK(has(e, "h.json"));
      CHECK(has(e, "'"));  // names the key
    }
    for (const std::string doc : {"", "{", "\xef\xbb\xbf{", "{\"n\": 32,}", "[1, 2]", "null", "{\"n\": \"\xff\"}", "{\"a\":1}\0"}) {
      CAPTURE(doc);
      CHECK(has(input_error([&] { config_from_json_text(doc, "m.json"); }), "m.json"));
    }
    // Files: a folder, a FIFO-like device, and a file over the cap are refused before reading.
    const auto dir = temp_dir("stress_json");
    CHECK(has(input_error([&] { config_from_json_file(dir.string()); }), dir.string()));
    CHECK(has(input_error([&] { config_from_json_file("/dev/zero"); }), "/dev/zero"));
    spit((dir / "big.json").string(), "{\"n\": 32" + std::string(2 << 20, ' ') + "}");
    CHECK(has(input_error([&] { config_from_json_file((dir / "big.json").string()); }), "1 MiB"));
    fs::remove_all(dir);
  }

  TEST_CASE("HDF5 design, cube and checkpoint files: truncated, corrupt, mistyped, misshapen [cpu]") {
    const auto dir = temp_dir("stress_h5");
    const std::string design = (dir / "design.h5").string(), cube = (dir / "cube.h5").string(), ck = (dir / "ck.h5").string();
    Design d;
    d.height_m = random_heights(8, 1e-6, 1);
    d.pitch_m = 4e-6;
    d.levels_m = {0, 1e-6};
    write_design(design, d);
    write_cube(cube, random_cube(3, 5, 6, 2), {450, 500, 550});
    DesignState st;
    st.w.assign(16, 0.25);
    st.offsets = {0, 0.1, -0.1, 0};
    st.adam_w.m.assign(16, 1e-3);
    st.adam_w.v.assign(16, 1e-6);
    st.step = st.adam_w.t = 12;
    save_checkpoint(ck, st);
    const std::string bad = (dir / "bad.h5").string();
    // Every truncation and corruption: an InputError naming the file, or a valid result.
    CHECK(mutate_and_read(bad, slurp(design), [&] {
            const Design r = read_design(bad);
            CHECK(all_finite(r.height_m.data));
          }) > 40);
    CHECK(mutate_and_read(bad, slurp(cube), [&] {
            const RealStack c = read_cube(bad, {});
            CHECK(all_finite(c.data));
          }) > 40);
    CHECK(mutate_and_read(bad, slurp(ck), [&] { load_checkpoint(bad, 16, 4); }) > 40);
    // Wrong types and shapes.
    auto write = [&](const std::vector<H5Dataset>& sets) { h5_write_unchecked(bad, sets); };
    write({H5Dataset{"/height_m", {4, 5}, std::vector<double>(20, 0.0), {{"pitch_m", 4e-6}}, {}}});
    CHECK(has(input_error([&] { read_design(bad); }), "not a square"));
    write({H5Dataset{"/height_m", {2, 2, 2}, std::vector<double>(8, 0.0), {{"pitch_m", 4e-6}}, {}}});
    CHECK(has(input_error([&] { read_design(bad); }), "not a square"));
    write({H5Dataset{"/height_m", {2, 2}, std::vector<double>(4, 0.0), {}, {{"pitch_m", "4e-6"}}}});
    CHECK(has(input_error([&] { read_design(bad); }), "pitch_m"));
    write({H5Dataset{"/height_m", {2, 2}, std::vector<double>(4, 0.0), {{"pitch_m", -1}}, {}}});
    CHECK(has(input_error([&] { read_design(bad); }), "pitch_m"));
    write({H5Dataset{"/height_m", {2, 2}, {0, 1, std::nan(""), 0}, {{"pitch_m", 4e-6}}, {}}});
    CHECK(has(input_error([&] { read_design(bad); }), "non-finite"));
    write({H5Dataset{"/cube", {3, 4}, std::vector<double>(12, 0.0), {}, {}}});
    CHECK(has(input_error([&] { read_cube(bad, {}); }), "not a 3-D cube"));
    // A string dataset where numbers belong.
    {
      H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
      const hid_t f = H5Fcreate(bad.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
      const hid_t t = H5Tcopy(H5T_C_S1);
      H5Tset_size(t, 8);
      const hsize_t dims[2] = {2, 2};
      const hid_t sp = H5Screate_simple(2, dims, nullptr);
      const hid_t ds = H5Dcreate2(f, "/height_m", t, sp, H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
      H5Dclose(ds);
      H5Sclose(sp);
      H5Tclose(t);
      H5Fclose(f);
    }
    CHECK(has(input_error([&] { read_design(bad); }), "not numeric"));
    // Checkpoints: sizes, ranges and counters a corrupt file could hold.
    auto ckpt = [&](const std::string& name, std::vector<double> v) {
      std::vector<H5Dataset> sets;
      for (const char* n : {"/w", "/offsets", "/adam_w_m", "/adam_w_v", "/adam_a_m", "/adam_a_v", "/counters"}) {
        std::vector<double> def = std::string(n) == "/counters" ? std::vector<double>{3, 3, 3}
                                  : (std::string(n) == "/w" || std::string(n).rfind("/adam_w", 0) == 0) ? std::vector<double>(16, 0.1)
                                                                                                        : std::vector<double>(4, 0.0);
        if (name == n) def = v;
        sets.push_back(H5Dataset{n, {def.size()}, def, {}, {}});
      }
      h5_write_unchecked(bad, sets);
      return input_error([&] { load_checkpoint(bad, 16, 4); });
    };
    CHECK(ckpt("", {}).empty());  // the defaults load
    CHECK(has(ckpt("/w", std::vector<double>(15, 0.0)), "'/w' has 15 values"));
    CHECK(has(ckpt("/w", std::vector<double>(16, 1.5)), "outside [-1, 1]"));
    CHECK(has(ckpt("/counters", {-1, 0, 0}), "/counters"));
    CHECK(has(ckpt("/counters", {2.5, 0, 0}), "/counters"));
    // Regression (src/design/run.cpp): counters beyond the range of a long (undefined behaviour in the
    // conversion), negative second moments (NaN weights after resume) and offsets beyond their
    // clip limits are rejected naming the dataset.
    CHECK(has(ckpt("/counters", {1e300, 0, 0}), "/counters"));
    CHECK(has(ckpt("/adam_w_v", std::vector<double>(16, -1.0)), "/adam_w_v"));
    CHECK(has(ckpt("/offsets", {0, 3, 0, 0}), "/offsets"));
    CHECK(has(ckpt("/offsets", {0.5, 0, 0, 0}), "/offsets"));
    fs::remove_all(dir);
  }

  TEST_CASE("absurdly large declared shapes are refused before allocating (HDF5, .mat v5, PNG) [cpu]") {
    const auto dir = temp_dir("stress_big");
    // HDF5: /height_m declared 32768 x 32768 (8 GiB of float64) with no data written: a 2 KiB file.
    const std::string h5 = (dir / "big.h5").string();
    for (const std::string name : {"/height_m", "/cube"}) {
      H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
      const hid_t f = H5Fcreate(h5.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
      const bool cube = name == "/cube";
      const hsize_t dims[3] = {cube ? 31ull : 32768ull, cube ? 8192ull : 32768ull, 8192};
      const hsize_t chunk[3] = {1, 64, 64};
      const hid_t sp = H5Screate_simple(cube ? 3 : 2, dims, nullptr);
      const hid_t pl = H5Pcreate(H5P_DATASET_CREATE);
      H5Pset_chunk(pl, cube ? 3 : 2, cube ? chunk : chunk + 1);
      const hid_t ds = H5Dcreate2(f, name.c_str(), H5T_IEEE_F64LE, sp, H5P_DEFAULT, pl, H5P_DEFAULT);
      const hid_t as = H5Screate(H5S_SCALAR);
      const hid_t at = H5Acreate2(ds, "pitch_m", H5T_IEEE_F64LE, as, H5P_DEFAULT, H5P_DEFAULT);
      const double pitch = 4e-6;
      H5Awrite(at, H5T_NATIVE_DOUBLE, &pitch);
      H5Aclose(at);
      H5Sclose(as);
      H5Dclose(ds);
      H5Pclose(pl);
      H5Sclose(sp);
      H5Fclose(f);
      REQUIRE(fs::file_size(h5) < 100000);
      const std::string e = cube ? input_error([&] { read_cube(h5, {}); }) : input_error([&] { read_design(h5); });
      CAPTURE(e);
      CHECK(has(e, h5));
      CHECK(has(e, "declares"));
      if (cube) {
        CHECK(has(input_error([&] { load_scene(h5, "auto", 31); }), "declares"));
        CHECK(has(input_error([&] { probe_scene(h5, "auto", 31); }), "declares"));
      }
    }
    // Regression (fuzz_cube_h5, fuzz/corpus/cube_h5/crash-compact-no-data.h5): a compact
    // dataset whose layout message stores no data crashed libhdf5's read (NULL memcpy); and a
    // contiguous dataset never written holds no data. Both refused before reading.
    const fs::path corpus = fs::path(__FILE__).parent_path().parent_path() / "fuzz" / "corpus";
    const std::string compact = (corpus / "cube_h5" / "crash-compact-no-data.h5").string();
    for (const auto& read : std::vector<std::function<void()>>{[&] { read_cube(compact, {"/rad", "auto", 0, 0, {}, false}); },
                                                               [&] { load_scene(compact, "auto", 0); }}) {
      const std::string e = input_error(read);
      CAPTURE(e);
      CHECK(has(e, "stores 0 bytes"));
    }
    {
      H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
      const hid_t f = H5Fcreate(h5.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
      const hsize_t dims[2] = {4, 4};
      const hid_t sp = H5Screate_simple(2, dims, nullptr);
      const hid_t ds = H5Dcreate2(f, "/height_m", H5T_IEEE_F64LE, sp, H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
      H5Dclose(ds);
      H5Sclose(sp);
      H5Fclose(f);
    }
    CHECK(has(input_error([&] { read_design(h5); }), "unwritten"));
    // Regression (fuzz_mat, fuzz/corpus/mat/crash-v73-datatype-4gb.mat): a v7.3 variable whose
    // datatype claims 4 GiB per element made libhdf5 (through libmatio) zero 4 GB for a 3.8 KiB
    // file. The variable's dataset is now checked like any HDF5 dataset first.
    const std::string v73 = (corpus / "mat" / "crash-v73-datatype-4gb.mat").string();
    CHECK(has(input_error([&] { read_cube(v73, {}); }), "corrupt datatype"));
    // MATLAB v5: a 4 x 5 x 3 double variable whose header is patched to claim 32768 x 32768 x 2.
    const std::string mat = (dir / "big.mat").string();
    write_mat(mat, MAT_FT_MAT5, "cube", {4, 5, 3}, MAT_C_DOUBLE, MAT_T_DOUBLE, std::vector<double>(60, 0.5));
    std::string bytes = slurp(mat);
    REQUIRE(bytes.size() > 176);
    auto put32 = [&](std::size_t at, std::uint32_t v) {
      for (int i = 0; i < 4; ++i) bytes[at + std::size_t(i)] = char((v >> (8 * i)) & 0xff);
    };
    // 128-byte header, miMATRIX tag (8), array flags (16), dims tag (8): dims at byte 160.
    put32(160, 32768);
    put32(164, 32768);
    put32(168, 2);
    spit(mat, bytes);
    const std::string em = input_error([&] { read_cube(mat, {}); });
    CAPTURE(em);
    CHECK(has(em, mat));
    // Regression (fuzz_mat, fuzz/corpus/mat/crash-dims-tag-oom.mat): a dims tag declaring
    // 587 MB made libmatio allocate 1.2 GB while merely listing the variables. Now refused from
    // the array header, uncompressed and inside a compressed (zlib) variable.
    write_mat(mat, MAT_FT_MAT5, "cube", {4, 5, 3}, MAT_C_DOUBLE, MAT_T_DOUBLE, std::vector<double>(60, 0.5));
    bytes = slurp(mat);
    put32(156, 0x2300000c);  // the dims tag's byte count
    spit(mat, bytes);
    for (const auto& read : std::vector<std::function<void()>>{[&] { read_cube(mat, {}); }, [&] { load_scene(mat, "auto", 0); },
                                                               [&] { probe_scene(mat, "auto", 3); }}) {
      const std::string e = input_error(read);
      CAPTURE(e);
      CHECK(has(e, mat));
      CHECK(has(e, "dimensions"));
    }
    {
      // The same element deflated into a miCOMPRESSED (type 15) element.
      const std::string element = bytes.substr(128);
      uLongf zlen = compressBound(uLong(element.size()));
      std::string z(zlen, '\0');
      REQUIRE(compress2(reinterpret_cast<Bytef*>(&z[0]), &zlen, reinterpret_cast<const Bytef*>(element.data()), uLong(element.size()), 6) == Z_OK);
      z.resize(zlen);
      std::string file = bytes.substr(0, 128) + std::string(8, '\0') + z;
      for (int i = 0; i < 4; ++i) {
        file[128 + std::size_t(i)] = char((15u >> (8 * i)) & 0xff);
        file[132 + std::size_t(i)] = char((std::uint32_t(zlen) >> (8 * i)) & 0xff);
      }
      spit(mat, file);
      const std::string e = input_error([&] { load_scene(mat, "auto", 0); });
      CAPTURE(e);
      CHECK(has(e, "dimensions"));
    }
    // PNG: a valid 60-byte file whose header declares 1,000,000 x 1,000,000 16-bit pixels.
    const std::string pdir = (dir / "pngs").string();
    fs::create_directories(pdir);
    spit(pdir + "/band_1.png", png_claiming(1000000, 1000000));
    const std::string ep = input_error([&] { read_png_band_folder(pdir, 0); });
    CAPTURE(ep);
    CHECK(has(ep, "band_1.png"));
    CHECK(has(ep, "declares"));
    spit(pdir + "/band_1.png", png_claiming(40000, 40000));
    CHECK(has(input_error([&] { read_png_band_folder(pdir, 0); }), "declares"));
    CHECK(has(input_error([&] { load_scene(pdir, "auto", 0); }), "declares"));
    fs::remove_all(dir);
  }

  TEST_CASE(".mat v5 and v7.3: truncated, corrupt, wrong classes and shapes [cpu]") {
    const auto dir = temp_dir("stress_mat");
    const std::string v5 = (dir / "v5.mat").string(), v5z = (dir / "v5z.mat").string(), v73 = (dir / "v73.mat").string();
    std::vector<std::uint16_t> u16(4 * 5 * 3);
    for (std::size_t i = 0; i < u16.size(); ++i) u16[i] = std::uint16_t(i * 997);
    write_mat(v5, MAT_FT_MAT5, "cube", {4, 5, 3}, MAT_C_UINT16, MAT_T_UINT16, u16);
    write_mat(v5z, MAT_FT_MAT5, "cube", {4, 5, 3}, MAT_C_UINT16, MAT_T_UINT16, u16, MAT_COMPRESSION_ZLIB);
    write_mat(v73, MAT_FT_MAT73, "cube", {4, 5, 3}, MAT_C_UINT16, MAT_T_UINT16, u16);
    const std::string bad = (dir / "bad.mat").string();
    for (const std::string& good : {v5, v5z, v73}) {
      CAPTURE(good);
      CHECK(mutate_and_read(bad, slurp(good), [&] {
              const RealStack c = read_cube(bad, {});
              CHECK(all_finite(c.data));
              load_scene(bad, "auto", 0);
            }) > 30);
    }
    // Wrong classes: char, complex, logical is fine (0/1), 2-D.
    write_mat(bad, MAT_FT_MAT5, "cube", {4, 5, 3}, MAT_C_CHAR, MAT_T_UINT8, std::vector<std::uint8_t>(60, 'a'));
    CHECK(has(input_error([&] { read_cube(bad, {}); }), bad));
    CHECK(has(input_error([&] { read_cube(bad, {"cube", "auto", 0, 0, {}, false}); }), "not a real numeric"));
    write_mat(bad, MAT_FT_MAT5, "cube", {4, 15}, MAT_C_DOUBLE, MAT_T_DOUBLE, std::vector<double>(60, 0.5));
    CHECK(has(input_error([&] { read_cube(bad, {"cube", "auto", 0, 0, {}, false}); }), "not a 3-D cube"));
    {
      std::unique_ptr<mat_t, MatCloser> m(Mat_CreateVer(bad.c_str(), nullptr, MAT_FT_MAT5));
      std::vector<double> re(60, 1.0), im(60, 2.0);
      mat_complex_split_t z{re.data(), im.data()};
      std::size_t dims[3] = {4, 5, 3};
      std::unique_ptr<matvar_t, MatVarFreer> v(Mat_VarCreate("cube", MAT_C_DOUBLE, MAT_T_DOUBLE, 3, dims, &z, MAT_F_COMPLEX | MAT_F_DONT_COPY_DATA));
      REQUIRE(Mat_VarWrite(m.get(), v.get(), MAT_COMPRESSION_NONE) == 0);
    }
    CHECK(has(input_error([&] { read_cube(bad, {"cube", "auto", 0, 0, {}, false}); }), "complex"));
    CHECK(has(input_error([&] { read_cube(v5, {"nope", "auto", 0, 0, {}, false}); }), "'nope'"));
    // Regression (fuzz_mat, fuzz/corpus/mat/crash-v4-fallback-timeout.mat): a file without the
    // v5 / v7.3 header made libmatio fall back to its v4 reader, which allocated what the first
    // bytes declared (12 s, half a gigabyte). Only v5 and v7.3 are accepted now.
    std::string v4 = "\x00\x00\x00\x00\x20\x00\x00\x00\x01\x00\x00\x00\x00\x00\x00\x00\xff\xff\xff\x7f";
    v4.resize(208, 'x');
    spit(bad, v4);
    CHECK(has(input_error([&] { read_cube(bad, {}); }), "v5 or v7.3"));
    CHECK(has(input_error([&] { load_scene(bad, "auto", 0); }), "v5 or v7.3"));
    std::string wrong_version = slurp(v5);
    wrong_version[124] = 0x03;
    spit(bad, wrong_version);
    CHECK(has(input_error([&] { read_cube(bad, {}); }), "v5 or v7.3"));
    CHECK(has(input_error([&] { read_cube(v5, {"", "auto", 0, 7, {}, false}); }), "no band axis of length 7"));
    fs::remove_all(dir);
  }

  TEST_CASE("PNG band folders and CSV tables: truncated, corrupt, unbounded streams [cpu]") {
    const auto dir = temp_dir("stress_png");
    const std::string pdir = (dir / "scene").string();
    fs::create_directories(pdir);
    const std::string band = pdir + "/scene_ms_01.png";
    for (bool sixteen : {false, true}) {
      write_png_gray(band, 7, 5, sixteen);
      const std::string good = slurp(band);
      CHECK(mutate_and_read(band, good, [&] {
              const RealStack c = read_png_band_folder(pdir, 0);
              for (double v : c.data) CHECK((v >= 0 && v <= 1));
            }) > 30);
      spit(band, good);
    }
    // A second band of another size, and a band that is not a PNG at all.
    write_png_gray(pdir + "/scene_ms_02.png", 6, 5, true);
    CHECK(has(input_error([&] { read_png_band_folder(pdir, 0); }), "scene_ms_02.png"));
    spit(pdir + "/scene_ms_02.png", "not a png");
    CHECK(has(input_error([&] { read_png_band_folder(pdir, 0); }), "scene_ms_02.png"));
    // CSV: the parser takes anything and names the origin; the file reader refuses what is not
    // a regular file or is too large (regression: it used to read /dev/zero until memory ran out).
    for (const std::string t : {"", "# only\n", ",a\n", "a,a\n", "a,b\n1\n", "a,b\n1,2,3\n"}) {
      CAPTURE(t);
      const std::string e = input_error([&] { parse_csv(t, "t.csv"); });
      CHECK(has(e, "t.csv"));
    }
    const CsvTable odd = parse_csv("x,y\n1e999,nan\n0x10,abc\n\xff\xfe,\0\n", "odd.csv");  // cells that are not numbers are NaN
    CHECK(std::isinf(odd.columns[0][0]));
    CHECK(std::isnan(odd.columns[1][1]));
    CHECK(has(input_error([&] { read_csv("/dev/zero"); }), "/dev/zero"));
    CHECK(has(input_error([&] { read_csv(dir.string()); }), dir.string()));
    CHECK(has(input_error([&] { read_csv((dir / "missing.csv").string()); }), "missing.csv"));
    const std::string huge = (dir / "huge.csv").string();
    {
      std::ofstream out(huge, std::ios::binary);
      out << "wavelength_nm,R,G,B\n";
      const std::string row = "500,1,1,1\n";
      for (std::size_t i = 0; i < (70u << 20) / row.size(); ++i) out << row;
    }
    CHECK(has(input_error([&] { read_csv(huge); }), "huge.csv"));
    // A camera CSV with a non-numeric or negative response is refused naming the file.
    SystemConfig c = tiny_config(32, 3);
    c.camera = (dir / "cam.csv").string();
    spit(c.camera, "wavelength_nm,R,G,B\n450,1,1,1\n500,x,1,1\n550,1,1,1\n");
    CHECK(has(input_error([&] { sensor_response(c); }), "cam.csv"));
    spit(c.camera, "wavelength_nm,R,G,B\n450,1,1,1\n500,-1,1,1\n550,1,1,1\n");
    CHECK(has(input_error([&] { sensor_response(c); }), "cam.csv"));
    fs::remove_all(dir);
  }

  TEST_CASE("CSV camera tables: a missing column is named with its file [cpu]") {
    // Regression: the error used to lack the file; CsvTable now keeps its origin.
    const auto dir = temp_dir("stress_csvcol");
    SystemConfig c = tiny_config(32, 3);
    c.camera = (dir / "cam.csv").string();
    spit(c.camera, "wavelength_nm,red,G,B\n450,1,1,1\n550,1,1,1\n");
    CHECK(has(input_error([&] { sensor_response(c); }), "cam.csv"));
    fs::remove_all(dir);
  }

  TEST_CASE("CSV camera tables with unsorted or repeated wavelengths are refused, not misinterpolated [cpu]") {
    // Regression: with srf_interpolate an unsorted table (400, 600, 500, 700) used to interpolate
    // 450 nm between 400 and 600 although the table holds 500 nm = 100; now it is refused.
    const auto dir = temp_dir("stress_csvsort");
    SystemConfig c = tiny_config(32, 3);
    c.camera = (dir / "cam.csv").string();
    spit(c.camera, "wavelength_nm,R,G,B\n400,1,1,1\n600,1,1,1\n500,100,1,1\n700,1,1,1\n");
    CHECK(has(input_error([&] { sensor_response(c); }), "increasing"));
    fs::remove_all(dir);
  }
}
