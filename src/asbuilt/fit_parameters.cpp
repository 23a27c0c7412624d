// The parameters of the as-built fit (fit.hpp): their names, the default set for a design, and
// the check of a requested set against the configuration and the design.
#include "qdo/asbuilt/fit.hpp"

#include <algorithm>
#include <cmath>
#include <set>

#include "qdo/design/design.hpp"
#include "qdo/runtime/error.hpp"

#include "fit_internal.hpp"

namespace qdo {

using fit_detail::fmt;

std::vector<std::string> fit_parameter_names() {
  return {"levels", "masks", "scale", "z", "d", "offset", "shift", "overlay", "aperture"};
}

std::vector<int> fit_detail::design_level_map(const Design& design) {
  const std::size_t levels = design.levels_m.size();
  std::vector<int> level_of(design.height_m.data.size(), 0);
  if (levels < 2) return level_of;
  for (std::size_t i = 0; i < level_of.size(); ++i) {
    const double h = design.height_m.data[i];
    std::size_t best = 0;
    for (std::size_t l = 1; l < levels; ++l)
      if (std::fabs(design.levels_m[l] - h) < std::fabs(design.levels_m[best] - h)) best = l;
    level_of[i] = int(best);
  }
  return level_of;
}

FitMaskSet fit_mask_set(const Design& design, bool binary) {
  const std::size_t levels = design.levels_m.size();
  if (levels < 2) throw InputError("masks need a quantized design (a design file with /levels_m)");
  FitMaskSet ms;
  ms.binary = binary;
  ms.n = design.height_m.rows;
  const std::vector<int> level_of = fit_detail::design_level_map(design);
  if (binary) {
    const int k = mask_count(int(levels));  // InputError unless a power of two
    for (int j = 0; j < k; ++j) {
      std::vector<std::uint8_t> open(level_of.size());
      for (std::size_t i = 0; i < open.size(); ++i) open[i] = (level_of[i] >> j) & 1 ? 0 : 1;
      ms.open.push_back(std::move(open));
    }
    return ms;
  }
  std::vector<std::size_t> count(levels, 0);
  for (int l : level_of) ++count[std::size_t(l)];
  for (std::size_t l = 0; l < levels; ++l)
    if (count[l] > 0) ms.order.push_back(l);
  std::stable_sort(ms.order.begin(), ms.order.end(),
                   [&](std::size_t a, std::size_t b) { return design.levels_m[a] > design.levels_m[b]; });
  std::vector<std::size_t> rank(levels, 0);
  for (std::size_t r = 0; r < ms.order.size(); ++r) rank[ms.order[r]] = r;
  for (std::size_t m = 1; m < ms.order.size(); ++m) {
    std::vector<std::uint8_t> open(level_of.size());
    for (std::size_t i = 0; i < open.size(); ++i) open[i] = rank[std::size_t(level_of[i])] >= m ? 1 : 0;
    ms.open.push_back(std::move(open));
  }
  return ms;
}

bool is_overlay_parameter(const std::string& name) {
  return name.size() > 2 && name[0] == 'o' && (name[1] == 'x' || name[1] == 'y') &&
         std::all_of(name.begin() + 2, name.end(), [](char c) { return c >= '0' && c <= '9'; });
}

std::vector<std::string> overlay_parameter_names(const Design& design, const std::vector<std::string>& parameters) {
  if (std::find(parameters.begin(), parameters.end(), "overlay") == parameters.end()) return {};
  const bool binary = std::find(parameters.begin(), parameters.end(), "masks") != parameters.end();
  const FitMaskSet ms = fit_mask_set(design, binary);
  std::vector<std::string> names;
  for (std::size_t m = 1; m < ms.open.size(); ++m) {
    names.push_back("ox" + std::to_string(m + 1));
    names.push_back("oy" + std::to_string(m + 1));
  }
  return names;
}

std::vector<std::string> default_fit_parameters(const Design& design) {
  if (design.levels_m.size() >= 2) return {"levels", "z", "offset"};
  return {"scale", "z", "offset"};
}

void check_fit_parameters(const SystemConfig& cfg, const Design& design, const std::vector<std::string>& parameters) {
  cfg.validate();
  if (design.height_m.rows != cfg.n || design.height_m.cols != cfg.n)
    throw InputError("the design is " + std::to_string(design.height_m.rows) + " x " + std::to_string(design.height_m.cols) +
                     "; the configuration's DOE grid is N x N = " + std::to_string(cfg.n) + " x " + std::to_string(cfg.n));
  if (std::fabs(design.pitch_m - cfg.pitch_m) > 1e-6 * cfg.pitch_m)
    throw InputError("the design's pitch_m is " + fmt("%g", design.pitch_m) + "; the configuration's is " + fmt("%g", cfg.pitch_m));
  std::set<std::string> given;
  const auto known = fit_parameter_names();
  for (const auto& name : parameters) {
    if (std::find(known.begin(), known.end(), name) == known.end())
      reject("--fit", name, "a comma-separated list of levels, masks, scale, z, d, offset, shift, overlay, aperture");
    if (!given.insert(name).second) reject("--fit", name, "each parameter once");
  }
  given.erase("aperture");  // not a continuous parameter (fit_as_built scans it)
  if (given.empty()) reject("--fit", "aperture alone", "at least one of levels, masks, scale, z, d, offset, shift, overlay");
  const auto has = [&](const char* s) { return given.count(s) > 0; };
  const std::size_t levels = design.levels_m.size();
  if ((has("levels") || has("masks")) && levels < 2)
    reject("--fit", has("levels") ? "levels" : "masks",
           "levels or masks only for a quantized design (a design file with /levels_m); this design has no level table: fit scale instead");
  if (has("levels") && has("masks")) reject("--fit", "levels,masks", "one of levels (every level free) and masks (subset sums)");
  if (has("scale") && (has("levels") || has("masks")))
    reject("--fit", "scale with " + std::string(has("levels") ? "levels" : "masks"),
           "scale or free level depths, not both: a global scale of the heights is exactly a scale of every level depth (a "
           "degenerate pair)");
  if (has("overlay")) {
    if (levels < 2)
      reject("--fit", "overlay", "overlay only for a quantized design (a design file with /levels_m): its masks come from the level map");
    const std::size_t k = fit_mask_set(design, has("masks")).open.size();
    if (k < 2)
      reject("--fit", "overlay",
             "overlay for a design made with 2 masks or more (the first mask defines the alignment, the offset moves it); this design "
             "needs " + std::to_string(k));
  }
  if (has("d") && cfg.scene_at_infinity)
    reject("--fit", "d", "d only for a finite object distance (the configuration's scene is at infinity)");
  for (double l : design.levels_m)
    if (!std::isfinite(l)) throw InputError("the design's level table holds a non-finite value");
  if (has("masks")) {
    const int k = mask_count(int(levels));  // InputError unless a power of two
    for (std::size_t l = 0; l < levels; ++l) {
      double sum = 0;
      for (int j = 0; j < k; ++j)
        if (l & (std::size_t(1) << j)) sum += design.levels_m[std::size_t(1) << j];
      if (std::fabs(sum - design.levels_m[l]) > 1e-9 || std::fabs(design.levels_m[0]) > 1e-9)
        reject("--fit", "masks",
               "masks only for a QDO+M design: level 0 at 0 and every level the subset sum of the log2(L) mask depths (level " +
                   std::to_string(l) + " is " + fmt("%.2f", design.levels_m[l] * 1e9) + " nm, the subset sum " + fmt("%.2f", sum * 1e9) +
                   " nm, level 0 " + fmt("%.2f", design.levels_m[0] * 1e9) + " nm); fit levels instead");
    }
  }
}

}  // namespace qdo
