// The inputs many commands share, read from options as typed (option_inputs.hpp).
#include "qdo/design/option_inputs.hpp"

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <limits>
#include <utility>

#include "qdo/data/data_root.hpp"
#include "qdo/data/scenes.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/strprintf.hpp"
#include "qdo/runtime/util.hpp"

namespace fs = std::filesystem;

namespace qdo {

RealStack scene_from_options(const SystemConfig& cfg, const TextOptions& a) {
  return read_scene(cfg, a.get("scene", "builtin"), a.get("key"), a.has("resample-bands"), "--key");
}

// The configuration from --config or --preset, with the camera response checked too, so every
// configuration error surfaces before any device work or output.
SystemConfig config_from_options(const TextOptions& a, bool allow_points) {
  SystemConfig c;
  if (a.has("config")) {
    if (a.has("preset"))
      reject("--preset", a.get("preset"), "omitted when --config is given (put \"preset\" in the file)");
    c = config_from_json_file(a.get("config"));
  } else {
    c = preset_config(a.get("preset", "small"));
  }
  // The commands image and write one PSF stack of bands planes: a configuration with several object
  // points (config.hpp) is qdo design's training conditions (allow_points); qdo simulate builds its
  // depth layers and field points from its own options (--depth, --field-grid).
  if (c.point_count() > 1 && !allow_points)
    reject("object_points", to_str(c.point_count()) + " points",
           "at most one point in the commands but qdo design (stacks of several object points: the library's Simulator "
           "and "
           "qdo.Optics.psf(height_m, object_points=...); designs over several points: qdo design; images of "
           "layered scenes and field-dependent images: qdo simulate --depth / --field-grid)");
  sensor_response(c);
  return c;
}

std::string apply_model_padding(SystemConfig& cfg, const TextOptions& a, double z_m) {
  const std::string v = a.get("model-padding", "auto");
  const std::size_t before = cfg.padding_px;
  if (v == "config") return "";
  if (v != "auto") {
    cfg.padding_px = std::size_t(parse_int("--model-padding", v, 0, int(4 * cfg.n)));
    return cfg.padding_px == before ? "" : strprintf("model: padding_px %zu (--model-padding; the configuration's %zu)", cfg.padding_px, before);
  }
  const double z_sampled_m = kModelPaddingZMargin * z_m;
  const SampledPadding need = sampled_padding_px(cfg, z_sampled_m);
  if (need.padding_px <= before) return "";
  cfg.padding_px = need.padding_px;
  return strprintf(
      "model: padding_px raised from %zu to %zu so the transfer function is sampled in every band up to z = %.4g mm%s "
      "(--model-padding auto; config keeps the configuration's)",
      before, cfg.padding_px, z_sampled_m * 1e3,
      need.sampled ? "" : ": not reached even at the limit 4 n, the long wavelengths stay under-sampled");
}

QuantizerOption quantizer_from_options(const TextOptions& a) {
  QuantizerOption s;
  if (!a.has("levels")) {
    if (a.has("placement")) reject("--placement", a.get("placement"), "given together with --levels");
    return s;
  }
  s.active = true;
  s.q.levels = parse_int("--levels", a.get("levels"), 2, 65536);
  s.q.placement = placement_from_string(a.get("placement", "inclusive"));
  s.q.validate();
  return s;
}

Map2D design_heights_from_options(const SystemConfig& cfg, const TextOptions& a, QuantizerOption* q_out) {
  const QuantizerOption qs = quantizer_from_options(a);
  Map2D h = design_heights_from_spec(cfg, a.get("design"), "--design");
  if (qs.active) h = quantize_heights(h, cfg.h_max_m(), qs.q);
  if (q_out) *q_out = qs;
  return h;
}

std::vector<std::string> scene_paths_from_options(const TextOptions& a, const std::string& name) {
  const std::vector<std::string> out = resolve_datasets(split_items(a.get(name)), "--" + name);
  for (const std::string& p : out)
    if (p.rfind("synthetic:", 0) != 0 && !fs::exists(p))
      reject("--" + name, p,
             "existing scene files or folders, or dataset names under the data root (qdo data lists them)");
  return out;
}

namespace {

// A distance of --object-distances: metres > 0 (at least 1e-6, as the configuration takes) or inf.
double object_distance(const std::string& v) {
  if (v == "inf") return std::numeric_limits<double>::infinity();
  char* end = nullptr;
  const double d = std::strtod(v.c_str(), &end);
  if (v.empty() || *end || !std::isfinite(d) || d < 1e-6)
    reject("--object-distances", v,
           "distances in metres > 0 (at least 1e-6 m) or inf, comma-separated, e.g. 0.5,1,2,5");
  return d;
}

}  // namespace

void object_points_from_options(const TextOptions& a, SystemConfig& c) {
  if ((a.has("object-distances") || a.has("field-angles")) && !c.object_points.empty())
    reject(a.has("object-distances") ? "--object-distances" : "--field-angles",
           a.get(a.has("object-distances") ? "object-distances" : "field-angles"),
           "omitted when the configuration lists object_points (" + to_str(c.object_points.size()) +
               " points in --config): give the points one way");
  if (a.has("object-distances") || a.has("field-angles")) {
    std::vector<double> distances;
    for (const std::string& v : split_items(a.get("object-distances"))) distances.push_back(object_distance(v));
    if (a.has("object-distances") && distances.empty())
      reject("--object-distances", a.get("object-distances"),
             "one or more distances in metres or inf, comma-separated");
    if (distances.empty()) distances.push_back(c.points()[0].distance_m);
    std::vector<std::pair<double, double>> angles;
    for (const std::string& v : split_items(a.get("field-angles"))) {
      const auto colon = v.find(':');
      const double x =
          parse_double("--field-angles", colon == std::string::npos ? v : v.substr(0, colon), -89, 89, "deg");
      const double y =
          colon == std::string::npos ? 0.0 : parse_double("--field-angles", v.substr(colon + 1), -89, 89, "deg");
      angles.push_back({x, y});
    }
    if (a.has("field-angles") && angles.empty())
      reject("--field-angles", a.get("field-angles"),
             "one or more angles in degrees (A on the x axis, or X:Y), comma-separated");
    // Each value once, as eval-points asks: 1,1 is one point, not a range that eval then refuses.
    for (std::size_t i = 0; i < distances.size(); ++i)
      for (std::size_t j = 0; j < i; ++j)
        if (distances[i] == distances[j])
          reject("--object-distances", a.get("object-distances"),
                 "distinct distances (" + split_items(a.get("object-distances"))[i] + " is given twice)");
    for (std::size_t i = 0; i < angles.size(); ++i)
      for (std::size_t j = 0; j < i; ++j)
        if (angles[i] == angles[j])
          reject("--field-angles", a.get("field-angles"),
                 "distinct angles (" + split_items(a.get("field-angles"))[i] + " is given twice)");
    if (angles.empty()) angles.push_back({0.0, 0.0});
    // Each off-axis angle within the sampling at each distance, named with the limit there.
    for (const auto& ang : angles) {
      if (ang.first == 0 && ang.second == 0) continue;
      for (double d : distances) {
        const std::string why = object_point_limit(c, ObjectPoint{d, ang.first, ang.second});
        if (why.empty()) continue;
        const std::string text = ang.second == 0 ? to_str(ang.first) : to_str(ang.first) + ":" + to_str(ang.second);
        reject("--field-angles", text + " deg",
               "angles within the sampling at every distance: at " +
                   (std::isinf(d) ? std::string("inf") : to_str(d) + " m") +
                   " this configuration supports field angles up to " + to_str(max_field_angle_deg(c, d)) +
                   " deg on one axis (" + why + ")");
      }
    }
    c.object_points = object_point_grid(distances, angles);
    if (c.object_points.size() > 4096)
      reject("--object-distances", a.get("object-distances"), "at most 4096 object points (distances x angles)");
  }
}

PsfInput psf_input_from_options(const SystemConfig& cfg, const TextOptions& a) {
  const PsfSpec spec =
      psf_spec_from_options(a.get("psf"), a.get("design"), "--psf", "--design", "the PSF comes from one of them");
  if (spec.kind == PsfSpec::Kind::File) {
    if (a.has("levels")) reject("--levels", a.get("levels"), "no --levels with --psf (the PSF file is used as it is)");
    return read_psf_input(spec, cfg);
  }
  if (spec.kind == PsfSpec::Kind::Run)
    reject("--design", "(missing)", "lens:NM, flat, or a design .h5 file (or --psf FILE: a PSF stack)");
  PsfInput in;
  in.spec = spec;
  in.heights = design_heights_from_options(cfg, a);
  return in;
}

}  // namespace qdo
