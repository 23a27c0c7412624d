// The scene-file targets (HDF5 cubes, MATLAB .mat v5 / v7.3): read_cube, then the dataset
// layer (format detection, shape probe, load), which must agree with each other.
#pragma once
#include <cmath>

#include "fuzz_util.hpp"
#include "qdo/data/datasets.hpp"
#include "qdo/data/io.hpp"

namespace qdo::fuzz {

inline void check_cube(const RealStack& c, const std::string& what) {
  if (c.planes == 0 || c.rows == 0 || c.cols == 0 || c.data.size() != c.planes * c.rows * c.cols)
    fail(what + ": empty or inconsistent cube");
  for (double v : c.data)
    if (!std::isfinite(v)) fail(what + ": non-finite value in an accepted cube");
}

inline int scene_target(const std::string& name, const std::uint8_t* data, std::size_t size) {
  const std::string path = scratch().write(name, data, size);
  try {
    CubeReadOptions opt;
    check_cube(read_cube(path, opt), "read_cube");
    opt.expected_bands = 3;
    check_cube(read_cube(path, opt), "read_cube (3 bands)");
  } catch (const InputError& e) {
    expect_names(e, path);
  }
  // Against a configured grid: a stored band axis is compared (or resampled onto it); an
  // accepted cube then has exactly the configured bands.
  const std::vector<double> grid = {450, 500, 550};
  for (const bool resample : {false, true}) {
    try {
      CubeReadOptions opt;
      opt.wavelengths_nm = grid;
      opt.resample_bands = resample;
      const RealStack c = read_cube(path, opt);
      check_cube(c, "read_cube (grid)");
      if (c.planes != grid.size()) fail("read_cube with a grid returned another band count");
    } catch (const InputError& e) {
      expect_names(e, path);
    }
  }
  // The dataset layer with the grid: probe and load agree, and a loaded scene obeys the
  // radiance rule (every value in [0, 1]).
  try {
    const SceneShape s = probe_scene(path, "auto", grid.size(), grid);
    const RealStack c = load_scene(path, "auto", grid.size(), grid);
    check_cube(c, "load_scene (grid)");
    if (!(s == SceneShape{c.planes, c.rows, c.cols})) fail("probe_scene and load_scene disagree on the shape (grid)");
    for (double v : c.data)
      if (v < 0 || v > 1) fail("load_scene returned a value outside [0, 1]");
  } catch (const InputError& e) {
    expect_names(e, path);
  }
  // The dataset layer: probe (headers only where possible) and load must agree.
  bool probed = false;
  SceneShape shape;
  try {
    shape = probe_scene(path, "auto", 0);
    probed = true;
  } catch (const InputError& e) {
    expect_names(e, path);
  }
  try {
    const RealStack c = load_scene(path, "auto", 0);
    check_cube(c, "load_scene");
    if (probed && !(shape == SceneShape{c.planes, c.rows, c.cols})) fail("probe_scene and load_scene disagree on the shape");
  } catch (const InputError& e) {
    expect_names(e, path);
  }
  return 0;
}

}  // namespace qdo::fuzz
