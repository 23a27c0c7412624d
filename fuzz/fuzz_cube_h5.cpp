// Fuzz target: an HDF5 cube file (/cube, bands x H x W) through read_cube and the dataset layer.
#include "scene_target.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  return qdo::fuzz::scene_target("cube.h5", data, size);
}
