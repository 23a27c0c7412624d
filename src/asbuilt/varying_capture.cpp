// The host half of a spatially varying capture (varying_capture.hpp): the depth map and its layers,
// the field grid and its edge, the components some pixel uses, their weights and the PSF
// configuration, every input checked before any device work. The device half and the outputs:
// varying_capture_run.cpp.
#include "qdo/asbuilt/varying_capture.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "qdo/data/io.hpp"
#include "qdo/runtime/error.hpp"

namespace qdo {

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr std::size_t kMaxDefaultLayers = 8;  // the default layer rule's largest layer count
constexpr std::size_t kMaxLayers = 256;
constexpr std::size_t kMaxGridSide = 31;

std::string metres(double d) { return std::isinf(d) ? std::string("inf") : to_str(d); }
double diopters(double d) { return std::isinf(d) ? 0.0 : 1.0 / d; }
std::string shown(const InputLabel& l, const std::string& formatted) { return l.text.empty() ? formatted : l.text; }

// A number in (lo, hi] `unit`, refused as the command line's numbers are: "a number", then the range.
void check_number(const InputLabel& l, double v, double lo, double hi, const std::string& unit) {
  const std::string text = shown(l, to_str(v));
  if (!std::isfinite(v)) reject(l.name, text, "a number");
  if (!(v > lo) || v > hi) reject(l.name, text + " " + unit, "a number in (" + to_str(lo) + ", " + to_str(hi) + "] " + unit);
}

// FILE[:/KEY]: KEY (an HDF5 dataset path, starting with '/') follows the last ":/".
struct DepthFile {
  std::string path, key;
};
DepthFile depth_file(const std::string& s) {
  DepthFile d;
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

// depth (metres) of rows x cols, every value > 0 or +inf (the first bad pixel named).
void check_depth_map(const Map2D& depth, std::size_t rows, std::size_t cols, const std::string& name, const std::string& text) {
  if (depth.rows != rows || depth.cols != cols)
    reject(name, text,
           "a depth map of the scene's size, " + to_str(rows) + " x " + to_str(cols) + " (the map is " + to_str(depth.rows) + " x " +
               to_str(depth.cols) + ")");
  for (std::size_t i = 0; i < depth.data.size(); ++i) {
    const double v = depth.data[i];
    if (!(v > 0))  // NaN, zero, negative and -inf; +inf (infinitely far) passes
      reject(name, text,
             "depths in metres > 0 or +inf (infinitely far) at every pixel (pixel (" + to_str(i / cols) + ", " + to_str(i % cols) +
                 ") = " + to_str(v) + ")");
  }
}

std::vector<double> linspace_sym(double edge, std::size_t n) {
  if (n == 1) return {0.0};
  std::vector<double> v(n);
  for (std::size_t i = 0; i < n; ++i) v[i] = -edge + 2.0 * edge * double(i) / double(n - 1);
  return v;
}

// The components whose weight map is nonzero somewhere (weights: K x H x W).
std::vector<std::size_t> used_components(const RealStack& w) {
  std::vector<std::size_t> used;
  for (std::size_t k = 0; k < w.planes; ++k) {
    const double* p = w.plane(k);
    if (std::any_of(p, p + w.plane_size(), [](double v) { return v != 0.0; })) used.push_back(k);
  }
  return used;
}

// Planes ks of w (K x H x W): ks.size() x H x W.
RealStack pick_planes(const RealStack& w, const std::vector<std::size_t>& ks) {
  RealStack out(ks.size(), w.rows, w.cols);
  for (std::size_t i = 0; i < ks.size(); ++i) std::copy(w.plane(ks[i]), w.plane(ks[i]) + w.plane_size(), out.plane(i));
  return out;
}

bool contains(const std::vector<std::size_t>& v, std::size_t k) { return std::find(v.begin(), v.end(), k) != v.end(); }

// A configuration computing `points` (one on-axis point becomes the pre-object-point form, computed
// exactly as a configuration with that scene_distance_m), validated; a refusal names `name`.
SystemConfig points_config(const SystemConfig& cfg, const std::vector<ObjectPoint>& points, const std::string& name,
                           const std::string& value) {
  SystemConfig c = cfg;
  c.object_points = points;
  try {
    c.validate();
  } catch (const InputError& e) {
    reject(name, value, std::string("object points the configuration's sampling supports: ") + e.what());
  }
  return points.size() == 1 ? point_config(c, 0) : c;
}

void check_linear(const SystemConfig& cfg, const std::string& what) {
  if (cfg.convolution != ConvolutionMode::Linear)
    reject("convolution", "circular", "\"convolution\": \"linear\" with " + what + " (the varying operator is a linear convolution)");
}

// The plan's parts common to both modes, once the components are chosen; info_json from `info`.
void finish_plan(VaryingPlan& plan, nlohmann::json& info) {
  std::vector<std::size_t> skipped;
  for (std::size_t k = 0; k < plan.total; ++k)
    if (!contains(plan.used, k)) skipped.push_back(k);
  info["computed"] = plan.used;
  info["skipped"] = skipped;
  info["noise"] = {{"read_noise_sigma", plan.cfg.read_noise_sigma},
                   {"full_well_photons", plan.cfg.full_well_photons},
                   {"seed", plan.cfg.noise_seed}};
  if (!plan.note.empty()) info["note"] = plan.note;
  plan.info_json = info.dump();
}

}  // namespace

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

Map2D read_depth_map(const DepthMapSource& src, const SystemConfig& cfg, std::size_t rows, std::size_t cols) {
  const std::string& spec = src.spec;
  const std::string& name = src.spec_label.name;
  const std::string scale_text = src.scale_m_per_code ? shown(src.scale_label, to_str(*src.scale_m_per_code)) : "";
  const std::string png_only = "only with a 16-bit PNG depth map (" + name + " FILE.png)";
  Map2D depth;
  if (spec == "builtin") {
    if (src.scale_m_per_code) reject(src.scale_label.name, scale_text, png_only);
    depth = builtin_chart_depth(cfg);
  } else {
    const DepthFile df = depth_file(spec);
    if (ends_with_ci(df.path, ".png")) {
      if (!df.key.empty()) reject(name, spec, "no :KEY with a PNG depth map (FILE.png holds one 16-bit plane)");
      const double scale = src.scale_m_per_code.value_or(0.001);
      check_number(src.scale_label, scale, 0, 1e6, "m per code");
      const Map2D codes = read_png16_gray(df.path);
      depth = Map2D(codes.rows, codes.cols);
      for (std::size_t i = 0; i < codes.data.size(); ++i) depth.data[i] = codes.data[i] == 0 ? kInf : codes.data[i] * scale;
    } else {
      if (src.scale_m_per_code) reject(src.scale_label.name, scale_text, png_only);
      const std::string key = df.key.empty() ? "/depth_m" : df.key;
      const H5Dataset d = h5_read(df.path, key, std::size_t(1) << 28);
      const bool two_d = d.shape.size() == 2, one_plane = d.shape.size() == 3 && d.shape[0] == 1;
      if (!two_d && !one_plane) {
        std::string sh;
        for (std::size_t e : d.shape) sh += (sh.empty() ? "" : " x ") + to_str(e);
        reject(name, spec, "an H x W (or 1 x H x W) dataset of depths in metres (" + key + " is " + sh + ")");
      }
      depth = Map2D(d.shape[d.shape.size() - 2], d.shape[d.shape.size() - 1]);
      depth.data = d.values();
      if (key == "/inverse_depth_per_m") {  // diopters (depth.h5 of an earlier run): 0 = infinity
        for (std::size_t i = 0; i < depth.data.size(); ++i) {
          const double q = depth.data[i];
          if (!(q >= 0) || std::isinf(q))
            reject(name, spec,
                   "inverse depths in 1/m, finite and >= 0 (0 = infinitely far) at every pixel (pixel (" + to_str(i / depth.cols) +
                       ", " + to_str(i % depth.cols) + ") = " + to_str(q) + ")");
          depth.data[i] = q > 0 ? 1.0 / q : kInf;
        }
      }
    }
  }
  check_depth_map(depth, rows, cols, name, spec);
  return depth;
}

std::vector<double> default_depth_layers(const Map2D& depth_m, std::string& rule) {
  std::vector<double> layers;
  std::set<double> distinct;
  for (double v : depth_m.data) {
    distinct.insert(v);
    if (distinct.size() > kMaxDefaultLayers) break;
  }
  if (distinct.size() <= kMaxDefaultLayers) {
    layers.assign(distinct.begin(), distinct.end());
    rule = "the depth map's " + to_str(layers.size()) + " distinct values";
    return layers;
  }
  double dmin = kInf, dmax = 0;  // diopters
  for (double v : depth_m.data) {
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

VaryingPlan plan_depth_capture(const SystemConfig& cfg, const DepthCaptureSpec& spec, std::size_t rows, std::size_t cols) {
  check_linear(cfg, "a depth map");
  const std::string depth_text = shown(spec.depth_label, spec.source);
  check_depth_map(spec.depth_m, rows, cols, spec.depth_label.name, depth_text);
  VaryingPlan plan;
  plan.mode = VaryingMode::Depth;
  plan.cfg = cfg;
  plan.placement = spec.placement;
  plan.rows = rows;
  plan.cols = cols;
  plan.depth_source = spec.source;

  // The layers: given (checked), or the default rule.
  const bool given = !spec.layers_m.empty();
  std::string rule;
  std::vector<double> layers = spec.layers_m;
  std::string lv;  // the layers in metres, comma-separated
  for (double d : layers) lv += (lv.empty() ? "" : ",") + metres(d);
  if (given) {
    const std::string text = shown(spec.layers_label, lv);
    for (double d : layers)
      if (!(d > 0)) reject(spec.layers_label.name, to_str(d), "distances in metres > 0, or inf");
    for (std::size_t i = 0; i < layers.size(); ++i)
      for (std::size_t j = 0; j < i; ++j)
        if (layers[i] == layers[j]) reject(spec.layers_label.name, text, "distinct layers (" + metres(layers[i]) + " m is listed twice)");
    if (layers.size() > kMaxLayers) reject(spec.layers_label.name, text, "at most " + to_str(kMaxLayers) + " layers");
    rule = "given (" + spec.layers_label.name + ")";
  } else {
    layers = default_depth_layers(spec.depth_m, rule);
    lv.clear();
    for (double d : layers) lv += (lv.empty() ? "" : ",") + metres(d);
  }

  const RealStack all = depth_layer_weights(spec.depth_m, layers, rows, cols);
  plan.total = layers.size();
  plan.used = used_components(all);
  plan.weights = pick_planes(all, plan.used);
  std::vector<ObjectPoint> pts;
  for (std::size_t k : plan.used) pts.push_back(ObjectPoint{layers[k], 0, 0});
  plan.psf_cfg = points_config(cfg, pts, given ? spec.layers_label.name : spec.depth_label.name, given ? lv : depth_text);
  plan.layer_map = Map2D(rows, cols);
  std::vector<std::size_t> pixels(layers.size(), 0);
  for (std::size_t k = 0; k < layers.size(); ++k)
    for (std::size_t i = 0; i < rows * cols; ++i)
      if (all.plane(k)[i] != 0) {
        plan.layer_map.data[i] = diopters(layers[k]);
        ++pixels[k];
      }
  plan.depth_diopters = Map2D(rows, cols);
  for (std::size_t i = 0; i < rows * cols; ++i) plan.depth_diopters.data[i] = diopters(spec.depth_m.data[i]);

  nlohmann::json info;
  info["mode"] = "depth";
  nlohmann::json lj = nlohmann::json::array();
  for (std::size_t k = 0; k < layers.size(); ++k)
    lj.push_back({{"index", k}, {"distance_m", metres(layers[k])}, {"diopters", diopters(layers[k])}, {"pixels", pixels[k]},
                  {"computed", contains(plan.used, k)}});
  info["layers"] = lj;
  info["layer_rule"] = rule;
  info["depth_file"] = spec.source;
  std::string used_s, skipped_s;
  for (std::size_t k = 0; k < layers.size(); ++k) {
    std::string& s = contains(plan.used, k) ? used_s : skipped_s;
    s += (s.empty() ? "" : ", ") + (std::isinf(layers[k]) ? std::string("infinity") : metres(layers[k]) + " m");
  }
  plan.summary = "depth layers (" + rule + "): " + to_str(plan.used.size()) + " of " + to_str(layers.size()) + " used, PSFs computed at " +
                 used_s + (skipped_s.empty() ? std::string("; none skipped") : "; skipped (no pixel at that depth): " + skipped_s);
  finish_plan(plan, info);
  return plan;
}

VaryingPlan plan_field_capture(const SystemConfig& cfg, const FieldCaptureSpec& spec, std::size_t rows, std::size_t cols) {
  check_linear(cfg, "a field grid");
  const std::size_t nx = spec.nx, ny = spec.ny;
  const std::string grid_text = shown(spec.grid_label, nx == ny ? to_str(nx) : to_str(nx) + "x" + to_str(ny));
  if (nx < 1 || nx > kMaxGridSide || ny < 1 || ny > kMaxGridSide)
    reject(spec.grid_label.name, grid_text, "NX or NXxNY, integers in [1, " + to_str(kMaxGridSide) + "] (e.g. 5 or 5x3)");
  VaryingPlan plan;
  plan.mode = VaryingMode::Field;
  plan.cfg = cfg;
  plan.placement = spec.placement;
  plan.rows = rows;
  plan.cols = cols;
  const double distance_m = cfg.scene_at_infinity ? kInf : cfg.scene_distance_m;

  // The sampling limit: the configuration's, or the band-limited angular spectrum's when the
  // configuration's Fresnel refuses off-axis angles that asm supports.
  SystemConfig asm_cfg = cfg;
  asm_cfg.propagator = Propagator::AngularSpectrum;
  const double limit_cfg = max_field_angle_deg(cfg, distance_m), limit_asm = max_field_angle_deg(asm_cfg, distance_m);
  const double limit = std::max(limit_cfg, limit_asm);
  const double z = cfg.sensor_distance_m, rad = 180.0 / 3.14159265358979323846;
  const double geom_x = std::atan(0.5 * double(cols) * cfg.sensor_pitch_m / z) * rad;
  const double geom_y = std::atan(0.5 * double(rows) * cfg.sensor_pitch_m / z) * rad;
  // A point whose chief ray lands near the edge of the N x N window loses much of its PSF outside
  // the window (the sampling report's "energy outside the N x N window"): the default stops where
  // the chief ray is halfway to that edge, so PSFs up to a quarter of the window wide fit.
  const double half_window = std::atan(0.25 * double(cfg.n) * cfg.pitch_m / z) * rad;
  double ex = std::min({geom_x, half_window, limit}), ey = std::min({geom_y, half_window, limit});
  std::string edge_rule = "min(atan(half the scene's extent on the sensor / z), atan(a quarter of the N x N window / z) = " +
                          to_str(half_window) + " deg, the sampling limit " + to_str(limit) + " deg)";
  if (spec.edge_deg) {
    const double e = *spec.edge_deg;
    check_number(spec.edge_label, e, 0, 89, "deg");
    if (e > limit)
      reject(spec.edge_label.name, shown(spec.edge_label, to_str(e)) + " deg",
             "a field edge within the sampling limit of this configuration at " + metres(distance_m) + " m: " + to_str(limit) +
                 " deg (max_field_angle_deg" + (limit_asm > limit_cfg ? ", with the \"asm\" propagator" : "") + ")");
    ex = ey = e;
    edge_rule = "given (" + spec.edge_label.name + ")";
  }
  if ((nx > 1 && !(ex > 0)) || (ny > 1 && !(ey > 0)))
    reject(spec.grid_label.name, grid_text,
           "1 (on axis only): this configuration supports no off-axis field angle at " + metres(distance_m) + " m (sampling limit " +
               to_str(limit) + " deg)");
  const std::vector<double> tx = linspace_sym(ex, nx), ty = linspace_sym(ey, ny);
  // The grid on the configuration's propagator; asm where Fresnel refuses one of its points.
  SystemConfig grid_cfg = cfg;
  for (const double ay : ty)
    for (const double ax : tx)
      if (!object_point_limit(cfg, ObjectPoint{distance_m, ax, ay}).empty()) grid_cfg = asm_cfg;
  for (const double ay : ty)
    for (const double ax : tx) {
      const std::string why = object_point_limit(grid_cfg, ObjectPoint{distance_m, ax, ay});
      if (!why.empty())
        reject(spec.edge_deg ? spec.edge_label.name : spec.grid_label.name,
               spec.edge_deg ? shown(spec.edge_label, to_str(*spec.edge_deg)) : grid_text,
               "field points within the sampling (the point at (" + to_str(ax) + ", " + to_str(ay) + ") deg is not: " + why +
                   "; the one-axis limit is " + to_str(limit) + " deg)");
    }
  if (grid_cfg.propagator != cfg.propagator)
    plan.note = "propagator: \"asm\" (band-limited angular spectrum) instead of the configuration's Fresnel, which refuses "
                "these field angles";
  const FieldGrid fg = field_grid(grid_cfg, distance_m, tx, ty);
  const RealStack all = field_grid_weights(rows, cols, fg.rows_px, fg.cols_px);
  plan.total = fg.points.size();
  plan.used = used_components(all);
  plan.weights = pick_planes(all, plan.used);
  std::vector<ObjectPoint> pts;
  for (std::size_t k : plan.used) {
    pts.push_back(fg.points[k]);
    plan.shifts.push_back(fg.shifts_px[k]);
  }
  plan.psf_cfg = points_config(grid_cfg, pts, spec.grid_label.name, grid_text);
  if (spec.rank > plan.used.size())
    reject(spec.rank_label.name, shown(spec.rank_label, to_str(spec.rank)), "an integer in [1, " + to_str(plan.used.size()) + "]");
  plan.rank = spec.rank;

  nlohmann::json info;
  info["mode"] = "field";
  nlohmann::json pj = nlohmann::json::array();
  for (std::size_t k = 0; k < fg.points.size(); ++k)
    pj.push_back({{"index", k}, {"field_x_deg", fg.points[k].field_x_deg}, {"field_y_deg", fg.points[k].field_y_deg},
                  {"image_row_px", fg.rows_px[k / tx.size()]}, {"image_col_px", fg.cols_px[k % tx.size()]},
                  {"shift_px", {fg.shifts_px[k].first, fg.shifts_px[k].second}}, {"computed", contains(plan.used, k)}});
  info["points"] = pj;
  info["grid"] = {nx, ny};
  info["edge_deg"] = {ex, ey};
  info["edge_rule"] = edge_rule;
  info["sampling_limit_deg"] = limit;
  info["distance_m"] = metres(distance_m);
  info["propagator"] = grid_cfg.propagator == Propagator::Fresnel ? "fresnel" : "asm";
  plan.summary = "field grid " + to_str(nx) + " x " + to_str(ny) + " up to (" + to_str(ex) + ", " + to_str(ey) + ") deg (" + edge_rule +
                 "): " + to_str(plan.used.size()) + " of " + to_str(plan.total) + " points computed" +
                 (plan.used.size() < plan.total ? " (" + to_str(plan.total - plan.used.size()) + " points' hats miss the scene)" : "");
  finish_plan(plan, info);
  return plan;
}

}  // namespace qdo
