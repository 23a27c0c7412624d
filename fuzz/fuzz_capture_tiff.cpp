// Fuzz target: a 16-bit TIFF capture or raw frame (read_tiff16, the reader of qdo calibrate and
// reconstruct). Seeds: gray and RGB, little- and big-endian, tiled, several pages (refused),
// untyped samples (refused).
#include <cmath>

#include "fuzz_util.hpp"
#include "qdo/data/io.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace qdo;
  const std::string path = fuzz::scratch().write("capture.tif", data, size);
  try {
    const RealStack c = read_tiff16(path);
    if ((c.planes != 1 && c.planes != 3) || c.data.size() != c.planes * c.rows * c.cols || c.rows == 0 || c.cols == 0)
      fuzz::fail("read_tiff16 returned an inconsistent stack");
    for (double x : c.data)
      if (!(x >= 0 && x <= 65535 && x == std::floor(x))) fuzz::fail("a TIFF code that is not an integer in [0, 65535]");
  } catch (const InputError& e) {
    fuzz::expect_names(e, path);
  }
  return 0;
}
