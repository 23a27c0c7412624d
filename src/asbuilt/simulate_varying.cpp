// The spatially varying part of qdo simulate (simulate.hpp): --depth / --field-grid and their
// options turned into the capture specs of varying_capture.hpp (which plans, runs and writes it),
// and the report.
//
//  --depth FILE[:KEY]   an H x W depth map (metres) beside the scene, imaged at depth layers
//                       (--depth-layers, or the map's own; --depth-scale for a 16-bit PNG).
//  --field-grid NX[xNY] a regular grid of field angles up to the field edge (--field-edge-deg);
//                       --field-rank R: the low-rank form.
//
// Every input is checked before the device starts; refusals name the options as typed.
#include "qdo/asbuilt/simulate.hpp"

#include <cmath>
#include <cstdlib>
#include <limits>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include "qdo/design/option_inputs.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/strprintf.hpp"
#include "qdo/runtime/util.hpp"

namespace qdo {

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

const char* const kVaryingOptions[] = {"depth-layers", "depth-scale", "psf-placement", "field-edge-deg", "field-rank"};

// A number as given, NaN when it is not one (the library refuses it naming the option and the text).
double number_or_nan(const std::string& v) {
  char* end = nullptr;
  const double x = std::strtod(v.c_str(), &end);
  return v.empty() || *end ? std::numeric_limits<double>::quiet_NaN() : x;
}

// --field-grid NX[xNY].
std::pair<std::size_t, std::size_t> field_grid_size(const std::string& s) {
  const std::size_t x = s.find_first_of("xX");
  // Each side parsed with the whole value in the message: "3x" names "3x", not an empty part.
  const auto one = [&](const std::string& v) {
    if (v.empty() || v.find_first_not_of("0123456789") != std::string::npos)
      reject("--field-grid", s, "NX or NXxNY, integers in [1, 31] (e.g. 5 or 5x3)");
    return std::size_t(parse_int("--field-grid", v, 1, 31));
  };
  if (x == std::string::npos) {
    const std::size_t n = one(s);
    return {n, n};
  }
  return {one(s.substr(0, x)), one(s.substr(x + 1))};
}

// --depth-layers D1,D2,... (metres > 0 or "inf"); distinctness and count are the library's checks.
std::vector<double> depth_layers_option(const std::string& s) {
  std::vector<double> layers;
  for (const std::string& v : split_items(s)) {
    if (v == "inf" || v == "+inf") {
      layers.push_back(kInf);
      continue;
    }
    char* end = nullptr;
    const double d = std::strtod(v.c_str(), &end);
    if (*end || !std::isfinite(d) || !(d > 0))
      reject("--depth-layers", v, "distances in metres > 0, or inf (comma-separated)");
    layers.push_back(d);
  }
  if (layers.empty()) reject("--depth-layers", s, "one or more distances in metres > 0, or inf (comma-separated)");
  return layers;
}

// The --depth plan: the map read (DepthMapSource), the layers, the components.
VaryingPlan depth_plan(const TextOptions& a, const SystemConfig& cfg, PsfPlacement placement, std::size_t rows,
                       std::size_t cols) {
  const std::string spec = a.get("depth");
  if (spec == "builtin" && a.get("scene", "builtin") != "builtin")
    reject("--depth", spec,
           "a depth map file for --scene " + a.get("scene") + " (--depth builtin is the built-in chart's)");
  DepthMapSource src;
  src.spec = spec;
  src.spec_label = {"--depth", spec};
  if (a.has("depth-scale")) {
    src.scale_m_per_code = number_or_nan(a.get("depth-scale"));
    src.scale_label = {"--depth-scale", a.get("depth-scale")};
  }
  DepthCaptureSpec d;
  d.depth_m = read_depth_map(src, cfg, rows, cols);
  if (a.has("depth-layers")) d.layers_m = depth_layers_option(a.get("depth-layers"));
  d.source = spec;
  d.placement = placement;
  d.depth_label = {"--depth", spec};
  d.layers_label = {"--depth-layers", a.get("depth-layers")};
  return plan_depth_capture(cfg, d, rows, cols);
}

// The --field-grid plan: the grid, its edge, the components; --field-rank against the points computed.
VaryingPlan field_plan(const TextOptions& a, const SystemConfig& cfg, PsfPlacement placement, std::size_t rows,
                       std::size_t cols) {
  FieldCaptureSpec f;
  std::tie(f.nx, f.ny) = field_grid_size(a.get("field-grid"));
  if (a.has("field-edge-deg")) f.edge_deg = number_or_nan(a.get("field-edge-deg"));
  f.placement = placement;
  f.grid_label = {"--field-grid", a.get("field-grid")};
  f.edge_label = {"--field-edge-deg", a.get("field-edge-deg")};
  f.rank_label = {"--field-rank", a.get("field-rank")};
  VaryingPlan plan = plan_field_capture(cfg, f, rows, cols);
  if (a.has("field-rank"))
    plan.rank = std::size_t(parse_int("--field-rank", a.get("field-rank"), 1, int(plan.used.size())));
  return plan;
}

}  // namespace

bool varying_requested(const TextOptions& a) { return a.has("depth") || a.has("field-grid"); }

void check_no_orphan_varying_options(const TextOptions& a) {
  for (const char* o : kVaryingOptions)
    if (a.has(o)) reject(std::string("--") + o, a.get(o), "only with --depth FILE or --field-grid NX[xNY]");
}

void plan_varying_simulation(const TextOptions& a, SimulatePlan& plan) {
  const SystemConfig& cfg = plan.cfg;
  const bool depth_mode = a.has("depth");
  if (depth_mode && a.has("field-grid"))
    reject(
        "--field-grid", a.get("field-grid"),
        "not together with --depth for now (a depth map and a field grid at once: K = layers x points components, not "
        "supported yet); run one or the other");
  const std::string what = depth_mode ? "--depth" : "--field-grid";
  if (a.get("capture", "scene") != "scene") reject("--capture", a.get("capture"), "scene with " + what);
  if (a.has("psf"))
    reject("--psf", a.get("psf"),
           "--design with " + what + " (a PSF stack file holds one PSF: it has no depth or field dependence)");
  if (a.get("formation", "qdo") != "qdo")
    reject("--formation", a.get("formation"),
           "qdo with " + what + " (--psf-placement output is the release's per-depth rule)");
  for (const char* o : {"raw", "demosaic", "save", "compress", "frame-size", "peak", "darks", "centre"})
    if (a.has(o)) reject(std::string("--") + o, a.get(o, "yes"), "not with " + what + " for now");
  if (depth_mode) {
    for (const char* o : {"field-edge-deg", "field-rank"})
      if (a.has(o)) reject(std::string("--") + o, a.get(o), "only with --field-grid");
  } else {
    for (const char* o : {"depth-layers", "depth-scale"})
      if (a.has(o)) reject(std::string("--") + o, a.get(o), "only with --depth");
  }
  if (cfg.convolution != ConvolutionMode::Linear)
    reject("convolution", "circular",
           "\"convolution\": \"linear\" with " + what + " (the varying operator is a linear convolution)");
  const PsfPlacement placement = psf_placement_from_string(a.get("psf-placement", "source"));
  plan.kind = SimulateKind::Varying;
  plan.varying_option = what;
  plan.heights = design_heights_from_options(cfg, a);
  plan.scene = scene_from_options(cfg, a);
  const std::size_t rows = plan.scene.rows, cols = plan.scene.cols;
  plan.varying = depth_mode ? depth_plan(a, cfg, placement, rows, cols) : field_plan(a, cfg, placement, rows, cols);
}

std::string run_varying_simulation(Runtime& rt, const SimulatePlan& sp, const std::string& dir,
                                   const std::function<void(const std::string&)>& say) {
  const VaryingPlan& plan = sp.varying;
  const SystemConfig& cfg = sp.cfg;
  const RealStack& scene = sp.scene;
  const std::size_t rows = scene.rows, cols = scene.cols;
  const Precision p = sp.precision;
  const PsfPlacement placement = plan.placement;
  const bool depth_mode = plan.mode == VaryingMode::Depth;
  if (say) say(plan.summary);
  const VaryingCaptureResult r = run_varying_capture(rt, plan, sp.heights, scene, p, say);
  write_varying_outputs(dir, plan, r, sp.heights, scene, "qdo simulate " + sp.varying_option);
  const VaryingReport& report = r.report;
  return strprintf(
      "device: %s\nformation: qdo, spatially varying (%s placement)\n%s\n%s%s"
      "scene %zu x %zu x %zu -> sensor 3 x %zu x %zu in %.3f s (PSFs %.3f s + varying convolution + sensor, %s); "
      "%zu forward and %zu inverse FFTs of %zu x %zu, %zu components kept, %zu skipped in the operator\n"
      "noise: %s\n%s\n%s\nwrote %s/sensor.h5, sensor.png, scene.png, psf_points.h5, psf.png, design.png%s, "
      "varying.json\n",
      rt.info().name.c_str(), to_string(placement).c_str(), r.summary.c_str(),
      plan.note.empty() ? "" : plan.note.c_str(), plan.note.empty() ? "" : "\n", scene.planes, rows, cols, r.rgb.rows,
      r.rgb.cols, r.seconds, r.psf_seconds, to_string(p).c_str(), report.forward_ffts, report.inverse_ffts,
      report.grid_rows, report.grid_cols, report.kept.size(), report.skipped.size(),
      cfg.read_noise_sigma > 0 || cfg.full_well_photons > 0
          ? "the configuration's (read noise and shot noise as the camera adds them)"
          : "none (the configuration's noise is zero)",
      r.sampling_summary.c_str(), clip_summary(r.clip).c_str(), dir.c_str(), depth_mode ? ", depth.png, depth.h5" : "");
}

}  // namespace qdo
