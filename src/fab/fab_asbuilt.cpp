// The camera as built (fab.hpp: fabricate): a design's masks made with one draw of the tolerance
// study's errors, the relief moved against the aperture, the DOE-sensor distance changed.
#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "fab/fab_internal.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/fab/fab.hpp"
#include "qdo/physics/optics.hpp"

namespace qdo::fab {

AsBuiltCamera fabricate(const Design& d, const SystemConfig& cfg, const AsBuiltOptions& o) {
  cfg.validate();
  const auto nonneg = [](const char* name, double v, double limit, const char* unit) {
    if (!(std::isfinite(v) && v >= 0 && v <= limit))
      reject(name, v, std::string("a size in [0, ") + std::to_string(limit) + "] " + unit);
  };
  nonneg("etch_depth_error_m", o.etch_depth_error_m, 1e-5, "m");
  nonneg("overlay_m", o.overlay_m, 1e-3, "m");
  nonneg("edge_blur_m", o.edge_blur_m, 1e-3, "m");
  if (o.oversample < 1 || o.oversample > 16) reject("oversample", o.oversample, "an integer in [1, 16]");
  const double half_grid_m = 0.5 * double(cfg.n) * cfg.pitch_m;
  for (const auto& [name, v] : {std::pair<const char*, double>{"offset_x_m", o.offset_x_m}, {"offset_y_m", o.offset_y_m}})
    if (!(std::isfinite(v) && std::abs(v) <= half_grid_m))
      reject(name, v, "a lateral offset within half the DOE grid, |offset| <= " + std::to_string(half_grid_m) + " m");
  // An assembly error, not a new camera: at most half the DOE-sensor distance either way.
  if (!(std::isfinite(o.sensor_distance_error_m) && std::abs(o.sensor_distance_error_m) <= 0.5 * cfg.sensor_distance_m))
    reject("sensor_distance_error_m (--sensor-distance-error-um)", to_str(o.sensor_distance_error_m) + " m",
           "an assembly error of at most half the DOE-sensor distance " + to_str(cfg.sensor_distance_m) + " m, i.e. |error| <= " +
               to_str(0.5e6 * cfg.sensor_distance_m) + " um");
  if (d.height_m.rows != cfg.n || d.height_m.cols != cfg.n)
    reject("design", std::to_string(d.height_m.rows) + " x " + std::to_string(d.height_m.cols),
           "a design on the configuration's " + std::to_string(cfg.n) + " x " + std::to_string(cfg.n) + " grid");

  AsBuiltCamera r;
  Constraints c;
  c.min_feature_um = 0;                         // fabricate whatever the design is,
  c.max_height_nm = 2 * cfg.h_max_m() * 1e9;    // up to the simulator's height range (as qdo tolerance)
  r.plan = plan_masks_named(d, cfg, o.scheme, c, r.scheme_note);
  // The draws of qdo tolerance's trial o.trial (same streams and indices).
  Perturbation pt;
  draw_trial_errors(o.seed, o.trial, r.plan, o.etch_depth_error_m, o.overlay_m, pt.depth_error_m, pt.shift_x_m, pt.shift_y_m);
  pt.edge_blur_m = o.edge_blur_m;
  const Map2D fabricated = perturbed_heights(r.plan, d.height_m, pt, o.oversample);
  r.depth_error_m = pt.depth_error_m;
  r.shift_x_m = pt.shift_x_m;
  r.shift_y_m = pt.shift_y_m;

  // Realised level heights: each level's design height less the depth errors of the masks open
  // over it (the constant perturbed_heights may add to keep the relief >= 0 is left out: a piston,
  // invisible in a PSF; level differences are what qdo fit sees).
  r.level_height_m.assign(r.plan.levels.size(), 0.0);
  for (std::size_t l = 0; l < r.plan.levels.size(); ++l) {
    double h = r.plan.levels[l].height_m;
    for (int m : r.plan.levels[l].masks) h -= pt.depth_error_m[std::size_t(m)];
    r.level_height_m[l] = h;
  }

  r.design.pitch_m = d.pitch_m;
  r.design.height_m = fabricated;
  // The relief moved against the aperture exactly (optics.hpp move_relief): whole pixels in the
  // map, the rest as the optical axis moved the other way; the aperture a continuous circle
  // (aperture_edge "area"), as a made one is, and as qdo fit's model of an offset is.
  r.cfg = move_relief(cfg, r.design.height_m, o.offset_x_m, o.offset_y_m);
  r.cfg.sensor_distance_m = cfg.sensor_distance_m + o.sensor_distance_error_m;
  if (o.padding_px) r.cfg.padding_px = *o.padding_px;
  r.cfg.validate();
  return r;
}

}  // namespace qdo::fab
