// Helpers shared by the tests of the training scenes (doctest suite "datasets",
// tests/test_datasets_*.cpp): a temporary folder, CAVE-like PNG band folders, random cubes.
#pragma once
#include <doctest/doctest.h>
#include <png.h>
#include <unistd.h>

#include <cstdint>
#include <cstring>
#include <filesystem>
#include <random>
#include <string>
#include <system_error>
#include <vector>

#include "qdo/runtime/error.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo::test::datasets_suite {

// A fresh temporary folder, removed with everything in it at the end of the test.
class TempDir {
 public:
  explicit TempDir(const std::string& tag) {
    static int counter = 0;
    path_ = std::filesystem::temp_directory_path() /
            ("qdo_ds_" + tag + "_" + std::to_string(static_cast<long>(::getpid())) + "_" + std::to_string(counter++));
    std::filesystem::remove_all(path_);
    std::filesystem::create_directories(path_);
  }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  ~TempDir() {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  std::string operator/(const std::string& name) const { return (path_ / name).string(); }
  std::string str() const { return path_.string(); }

 private:
  std::filesystem::path path_;
};

// A 16-bit grayscale PNG through libpng's simplified write API (pixels row-major).
inline void write_png16(const std::string& path, std::size_t w, std::size_t h, const std::vector<std::uint16_t>& px) {
  png_image img;
  std::memset(&img, 0, sizeof img);
  img.version = PNG_IMAGE_VERSION;
  img.width = static_cast<png_uint_32>(w);
  img.height = static_cast<png_uint_32>(h);
  img.format = PNG_FORMAT_LINEAR_Y;
  const int ok = png_image_write_to_file(&img, path.c_str(), 0, px.data(), 0, nullptr);
  png_image_free(&img);
  REQUIRE(ok);
}

// Test value of band b, pixel (y, x), below 4096 and distinct per position.
inline std::uint16_t tv(std::size_t b, std::size_t y, std::size_t x) {
  return static_cast<std::uint16_t>((b * 131 + y * 17 + x * 3 + 1) % 4096);
}

// A CAVE-like folder: `bands` 16-bit PNGs of h x w, band b holding tv(b, y, x) * 16.
inline void write_png_folder(const std::string& dir, std::size_t bands, std::size_t h, std::size_t w,
                             bool zero_pad = true) {
  std::filesystem::create_directories(dir);
  for (std::size_t b = 0; b < bands; ++b) {
    std::vector<std::uint16_t> px(h * w);
    for (std::size_t y = 0; y < h; ++y)
      for (std::size_t x = 0; x < w; ++x) px[y * w + x] = static_cast<std::uint16_t>(tv(b, y, x) * 16);
    const std::string num = (zero_pad && b + 1 < 10 ? "0" : "") + std::to_string(b + 1);
    write_png16(dir + "/scene_ms_" + num + ".png", w, h, px);
  }
}

inline RealStack random_stack(std::size_t b, std::size_t h, std::size_t w, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  RealStack c(b, h, w);
  for (double& v : c.data) v = static_cast<double>(rng() >> 11) * (1.0 / 9007199254740992.0);
  return c;
}

// The InputError message of f(), failing the test when f does not throw one.
template <typename F>
inline std::string input_error(F&& f) {
  try {
    f();
  } catch (const InputError& e) {
    return e.what();
  }
  FAIL("no InputError thrown");
  return "";
}

inline bool same(const RealStack& a, const RealStack& b) {
  return a.planes == b.planes && a.rows == b.rows && a.cols == b.cols && a.data == b.data;
}

}  // namespace qdo::test::datasets_suite
