// The depth inputs of qdo simulate --depth (simulate_depth.hpp): the depth map (a file, or the
// built-in chart's layers) and the depth layers the image is formed at.
#include "simulate_depth.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <limits>
#include <set>
#include <string>
#include <vector>

#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"
#include "qdo/data/scenes.hpp"

namespace qdo::cli {

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr std::size_t kMaxDefaultLayers = 8;  // the default layer rule's largest layer count

std::string metres(double d) { return std::isinf(d) ? std::string("inf") : to_str(d); }
double diopters(double d) { return std::isinf(d) ? 0.0 : 1.0 / d; }

// --depth FILE[:KEY]: KEY (an HDF5 dataset path, starting with '/') follows the last ":/".
struct DepthSpec {
  std::string path, key;
};
DepthSpec depth_spec(const std::string& s) {
  DepthSpec d;
  const std::size_t k = s.rfind(":/");
  if (k != std::string::npos && k > 0) {
    d.path = s.substr(0, k);
    d.key = s.substr(k + 1);
  } else {
    d.path = s;
  }
  return d;
}

bool ends_with_ci(const std::string& s, const std::string& suffix) {
  if (s.size() < suffix.size()) return false;
  for (std::size_t i = 0; i < suffix.size(); ++i)
    if (std::tolower(static_cast<unsigned char>(s[s.size() - suffix.size() + i])) != suffix[i]) return false;
  return true;
}

}  // namespace

// --depth builtin: a layered depth for the built-in chart scene (scenes.hpp, the same geometry):
// row r = 0 .. 3 of patches at 2^(r + 2) z (z the DOE-sensor distance: 4 z, 8 z, 16 z, 32 z), the
// background and the white dots at infinity. s x s, s = cfg.scene_size_px.
Map2D builtin_chart_depth(const SystemConfig& cfg) {
  const std::size_t s = cfg.scene_size_px;
  Map2D d(s, s, kInf);
  const double margin = 0.08 * double(s), cell_w = (double(s) - 2 * margin) / 6.0, cell_h = (double(s) - 2 * margin) / 4.0;
  for (std::size_t y = 0; y < s; ++y)
    for (std::size_t x = 0; x < s; ++x) {
      const double u = (double(x) - margin) / cell_w, v = (double(y) - margin) / cell_h;
      const double gap_u = u - std::floor(u), gap_v = v - std::floor(v);
      const bool inside = u >= 0 && u < 6 && v >= 0 && v < 4 && gap_u > 0.08 && gap_u < 0.92 && gap_v > 0.08 && gap_v < 0.92;
      if (inside) d(y, x) = std::ldexp(cfg.sensor_distance_m, int(v) + 2);
    }
  return d;
}

// The depth map in metres (rows x cols, +inf = infinitely far), read and checked: the scene's
// size, every value finite > 0 or +inf (the first bad pixel named).
Map2D read_depth_map(const Args& a, const SystemConfig& cfg, std::size_t rows, std::size_t cols) {
  const std::string spec = a.get("depth");
  if (spec == "builtin") {
    if (a.get("scene", "builtin") != "builtin")
      reject("--depth", spec, "a depth map file for --scene " + a.get("scene") + " (--depth builtin is the built-in chart's)");
    if (a.has("depth-scale")) reject("--depth-scale", a.get("depth-scale"), "only with a 16-bit PNG depth map (--depth FILE.png)");
    return builtin_chart_depth(cfg);
  }
  const DepthSpec ds = depth_spec(spec);
  Map2D depth;
  const bool png = ends_with_ci(ds.path, ".png");
  if (png) {
    if (!ds.key.empty()) reject("--depth", spec, "no :KEY with a PNG depth map (FILE.png holds one 16-bit plane)");
    const double scale = parse_double("--depth-scale", a.get("depth-scale", "0.001"), 0, 1e6, "m per code", true);
    const Map2D codes = read_png16_gray(ds.path);
    depth = Map2D(codes.rows, codes.cols);
    for (std::size_t i = 0; i < codes.data.size(); ++i) depth.data[i] = codes.data[i] == 0 ? kInf : codes.data[i] * scale;
  } else {
    if (a.has("depth-scale")) reject("--depth-scale", a.get("depth-scale"), "only with a 16-bit PNG depth map (--depth FILE.png)");
    const std::string key = ds.key.empty() ? "/depth_m" : ds.key;
    const H5Dataset d = h5_read(ds.path, key, std::size_t(1) << 28);
    const bool two_d = d.shape.size() == 2, one_plane = d.shape.size() == 3 && d.shape[0] == 1;
    if (!two_d && !one_plane) {
      std::string sh;
      for (std::size_t e : d.shape) sh += (sh.empty() ? "" : " x ") + to_str(e);
      reject("--depth", spec, "an H x W (or 1 x H x W) dataset of depths in metres (" + key + " is " + sh + ")");
    }
    depth = Map2D(d.shape[d.shape.size() - 2], d.shape[d.shape.size() - 1]);
    depth.data = d.values();
    if (key == "/inverse_depth_per_m") {  // diopters (depth.h5 of an earlier run): 0 = infinity
      for (std::size_t i = 0; i < depth.data.size(); ++i) {
        const double q = depth.data[i];
        if (!(q >= 0) || std::isinf(q))
          reject("--depth", spec,
                 "inverse depths in 1/m, finite and >= 0 (0 = infinitely far) at every pixel (pixel (" + to_str(i / depth.cols) + ", " +
                     to_str(i % depth.cols) + ") = " + to_str(q) + ")");
        depth.data[i] = q > 0 ? 1.0 / q : kInf;
      }
    }
  }
  if (depth.rows != rows || depth.cols != cols)
    reject("--depth", spec,
           "a depth map of the scene's size, " + to_str(rows) + " x " + to_str(cols) + " (the map is " + to_str(depth.rows) + " x " +
               to_str(depth.cols) + ")");
  for (std::size_t i = 0; i < depth.data.size(); ++i) {
    const double v = depth.data[i];
    if (!(v > 0))  // NaN, zero, negative and -inf; +inf (infinitely far) passes
      reject("--depth", spec,
             "depths in metres > 0 or +inf (infinitely far) at every pixel (pixel (" + to_str(i / cols) + ", " + to_str(i % cols) +
                 ") = " + to_str(v) + ")");
  }
  return depth;
}

// --depth-layers D1,D2,... (metres > 0 or "inf"), or the default rule: the map's distinct values when
// there are at most 8, else 8 layers evenly spaced in diopters between its nearest and farthest.
std::vector<double> depth_layers(const Args& a, const Map2D& depth, std::string& rule) {
  std::vector<double> layers;
  if (a.has("depth-layers")) {
    const std::string s = a.get("depth-layers");
    for (const std::string& v : split_items(s)) {
      if (v == "inf" || v == "+inf") {
        layers.push_back(kInf);
        continue;
      }
      char* end = nullptr;
      const double d = std::strtod(v.c_str(), &end);
      if (*end || !std::isfinite(d) || !(d > 0)) reject("--depth-layers", v, "distances in metres > 0, or inf (comma-separated)");
      layers.push_back(d);
    }
    if (layers.empty()) reject("--depth-layers", s, "one or more distances in metres > 0, or inf (comma-separated)");
    for (std::size_t i = 0; i < layers.size(); ++i)
      for (std::size_t j = 0; j < i; ++j)
        if (layers[i] == layers[j]) reject("--depth-layers", s, "distinct layers (" + metres(layers[i]) + " m is listed twice)");
    if (layers.size() > 256) reject("--depth-layers", s, "at most 256 layers");
    rule = "given (--depth-layers)";
    return layers;
  }
  std::set<double> distinct;
  for (double v : depth.data) {
    distinct.insert(v);
    if (distinct.size() > kMaxDefaultLayers) break;
  }
  if (distinct.size() <= kMaxDefaultLayers) {
    layers.assign(distinct.begin(), distinct.end());
    rule = "the depth map's " + to_str(layers.size()) + " distinct values";
    return layers;
  }
  double dmin = kInf, dmax = 0;  // diopters
  for (double v : depth.data) {
    dmin = std::min(dmin, diopters(v));
    dmax = std::max(dmax, diopters(v));
  }
  for (std::size_t k = 0; k < kMaxDefaultLayers; ++k) {
    const double q = dmax + (dmin - dmax) * double(k) / double(kMaxDefaultLayers - 1);  // near to far
    layers.push_back(q > 0 ? 1.0 / q : kInf);
  }
  rule = to_str(kMaxDefaultLayers) + " layers evenly spaced in diopters between the map's nearest (" + metres(1.0 / dmax) +
         " m) and farthest (" + metres(dmin > 0 ? 1.0 / dmin : kInf) + " m)";
  return layers;
}

}  // namespace qdo::cli
