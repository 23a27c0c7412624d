// Built-in scenes, so the main job needs no download.
#pragma once
#include <string>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

// A ColorChecker chart under D65 on the configuration's band grid: bands x S x S cube with
// S = cfg.scene_size_px, values in [0, 1]. The 24 measured patch reflectances (BabelColor
// average, data/colorchecker24_400-700nm_10nm.csv) times D65 (data/cie_d65_400-700nm_10nm.csv),
// normalised so the brightest D65 sample is 1, on a dark background with a soft vertical
// illumination gradient and three small bright white dots (point-like sources that show the
// PSF directly). Wavelengths outside 400..700 nm are an InputError; others are linearly
// interpolated from the 10 nm tables.
RealStack builtin_chart_scene(const SystemConfig& cfg);

// A scene by name, as the commands' --scene and Python's read_cube take it: "builtin" (the chart
// above), a folder of CAVE PNG bands (read_png_band_folder; key must be empty), or a cube file
// (read_cube: .mat, .h5, .npy, ...; key selects the variable) with cfg's band count and centres
// (resample_bands: interpolated from the file's own axis). Every scene passes conform_radiance
// (io.hpp: its notes on stderr). bands x H x W in [0, 1]. An InputError naming key_argument for
// a key with a folder.
RealStack read_scene(const SystemConfig& cfg, const std::string& path, const std::string& key, bool resample_bands,
                     const std::string& key_argument = "key");

// Linear interpolation of a tabulated spectrum (wl_nm ascending) at `at_nm`; InputError naming
// `what` outside the table.
std::vector<double> interpolate_spectrum(const std::vector<double>& wl_nm, const std::vector<double>& values,
                                         const std::vector<double>& at_nm, const std::string& what);

}  // namespace qdo
