// The depth inputs of qdo simulate --depth: the depth map and its layers, checked before any
// device work (private to src/cli/).
#pragma once
#include <string>
#include <vector>

#include "cli.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo::cli {

// --depth builtin: the built-in chart's layered depth (metres, scene_size_px x scene_size_px).
Map2D builtin_chart_depth(const SystemConfig& cfg);
// The --depth map, rows x cols metres (> 0 or inf): "builtin", a 16-bit PNG (codes x --depth-scale
// metres, 0 = infinity) or an HDF5 dataset (FILE[:/KEY], default /depth_m; /inverse_depth_per_m in
// diopters); the scene's size, every value checked; InputError naming the option otherwise.
Map2D read_depth_map(const Args& a, const SystemConfig& cfg, std::size_t rows, std::size_t cols);
// --depth-layers, or the default rule (the map's distinct values when at most 8, else 8 layers
// evenly spaced in diopters); `rule` says which, for the report. Metres, inf allowed.
std::vector<double> depth_layers(const Args& a, const Map2D& depth, std::string& rule);

}  // namespace qdo::cli
