// Fuzz target: a camera raw capture (read_camera_raw through LibRaw, the reader of qdo calibrate
// and reconstruct for .dng, .nef, ...). Seeds: DNGs of the four Bayer layouts, an odd size, a
// 16-bit range, and a DNG cut short.
#include <cmath>

#include "fuzz_util.hpp"
#include "qdo/data/io.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace qdo;
  const std::string path = fuzz::scratch().write("capture.dng", data, size);
  try {
    CameraRawInfo info;
    const RealStack c = read_camera_raw(path, &info);
    if (c.planes != 1 || c.data.size() != c.rows * c.cols || c.rows == 0 || c.cols == 0 || c.rows != info.rows || c.cols != info.cols)
      fuzz::fail("read_camera_raw returned an inconsistent mosaic");
    if (info.cfa != "rggb" && info.cfa != "bggr" && info.cfa != "grbg" && info.cfa != "gbrg")
      fuzz::fail("read_camera_raw named a layout that is no Bayer pattern");
    for (double x : c.data)
      if (!(x >= 0 && x <= 65535 && x == std::floor(x))) fuzz::fail("a raw code that is not an integer in [0, 65535]");
  } catch (const InputError& e) {
    fuzz::expect_names(e, path);
  }
  return 0;
}
