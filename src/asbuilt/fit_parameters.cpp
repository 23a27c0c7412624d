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

std::vector<std::string> fit_parameter_names() { return {"levels", "masks", "scale", "z", "d", "offset", "shift", "aperture"}; }

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
      reject("--fit", name, "a comma-separated list of levels, masks, scale, z, d, offset, shift, aperture");
    if (!given.insert(name).second) reject("--fit", name, "each parameter once");
  }
  given.erase("aperture");  // not a continuous parameter (fit_as_built scans it)
  if (given.empty()) reject("--fit", "aperture alone", "at least one of levels, masks, scale, z, d, offset, shift");
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
