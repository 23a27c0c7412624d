// Fuzz target: a MATLAB .mat file (v5, compressed or not, and v7.3 = HDF5 with a 512-byte
// header) through read_cube (libmatio) and the dataset layer (format detection, probe, load).
#include "scene_target.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  return qdo::fuzz::scene_target("cube.mat", data, size);
}
