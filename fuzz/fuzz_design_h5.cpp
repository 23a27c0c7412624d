// Fuzz target: a design file (/height_m N x N with attribute pitch_m, optional /levels_m).
#include <cmath>

#include "fuzz_util.hpp"
#include "qdo/data/io.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace qdo;
  const std::string path = fuzz::scratch().write("design.h5", data, size);
  try {
    const Design d = read_design(path);
    if (d.height_m.rows == 0 || d.height_m.rows != d.height_m.cols || d.height_m.data.size() != d.height_m.rows * d.height_m.cols)
      fuzz::fail("read_design accepted a map that is not square N x N");
    for (double v : d.height_m.data)
      if (!std::isfinite(v)) fuzz::fail("read_design accepted a non-finite height");
    for (double v : d.levels_m)
      if (!std::isfinite(v)) fuzz::fail("read_design accepted a non-finite level");
    if (!(d.pitch_m > 0) || !std::isfinite(d.pitch_m)) fuzz::fail("read_design accepted pitch_m <= 0");
  } catch (const InputError& e) {
    fuzz::expect_names(e, path);
  }
  return 0;
}
