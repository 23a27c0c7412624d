// Fuzz target: a CAVE-style PNG band folder holding the input as its only band file.
#include <cmath>
#include <filesystem>

#include "fuzz_util.hpp"
#include "qdo/data/datasets.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace qdo;
  static const std::string dir = [] {
    const std::string d = fuzz::scratch().path("pngscene");
    std::filesystem::create_directories(d);
    return d;
  }();
  const std::string path = fuzz::scratch().write("pngscene/scene_ms_01.png", data, size);
  bool probed = false;
  SceneShape shape;
  try {
    shape = probe_scene(dir, "cave-png", 0);
    probed = true;
  } catch (const InputError& e) {
    fuzz::expect_names(e, path);
  }
  try {
    const RealStack c = read_png_band_folder(dir, 0);
    if (c.planes != 1 || c.data.size() != c.rows * c.cols || c.rows == 0 || c.cols == 0)
      fuzz::fail("read_png_band_folder returned an inconsistent cube");
    for (double v : c.data)
      if (!(v >= 0 && v <= 1)) fuzz::fail("PNG value outside [0, 1]");
    if (probed && !(shape == SceneShape{c.planes, c.rows, c.cols})) fuzz::fail("probe_scene and the reader disagree");
  } catch (const InputError& e) {
    fuzz::expect_names(e, path);
  }
  return 0;
}
