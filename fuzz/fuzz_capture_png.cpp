// Fuzz target: a 16-bit PNG capture or raw frame (read_png16, read_png16_gray: the readers of
// qdo calibrate, reconstruct, simulate --depth), which return the stored codes whatever chunk
// the file carries. Seeds: gray and RGB 16-bit files with gAMA, sRGB, cHRM and iCCP chunks.
#include <cmath>

#include "fuzz_util.hpp"
#include "qdo/data/io.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace qdo;
  const std::string path = fuzz::scratch().write("capture.png", data, size);
  auto codes_ok = [](const std::vector<double>& v) {
    for (double x : v)
      if (!(x >= 0 && x <= 65535 && x == std::floor(x))) fuzz::fail("a PNG code that is not an integer in [0, 65535]");
  };
  try {
    const RealStack c = read_png16(path);
    if ((c.planes != 1 && c.planes != 3) || c.data.size() != c.planes * c.rows * c.cols || c.rows == 0 || c.cols == 0)
      fuzz::fail("read_png16 returned an inconsistent stack");
    codes_ok(c.data);
  } catch (const InputError& e) {
    fuzz::expect_names(e, path);
  }
  try {
    const Map2D m = read_png16_gray(path);
    if (m.data.size() != m.rows * m.cols || m.rows == 0) fuzz::fail("read_png16_gray returned an inconsistent map");
    codes_ok(m.data);
  } catch (const InputError& e) {
    fuzz::expect_names(e, path);
  }
  return 0;
}
