// qdo simulate --depth / --field-grid: the RGB sensor image of a scene whose PSF varies from pixel to
// pixel, through VaryingCamera (include/qdo/physics/varying.hpp).
//
//  --depth FILE[:KEY]   an H x W depth map (metres) beside the scene; each pixel goes to the nearest
//                       depth layer in diopters (depth_layer_weights); the design's PSF is computed
//                       at the layers some pixel uses only (one batched Simulator pass with on-axis
//                       object points), the others are reported as skipped.
//  --field-grid NX[xNY] a regular grid of field angles up to the field edge; each point's PSF
//                       recentred on the axis (set_shifts) and the image interpolated between
//                       neighbouring points (bilinear hats, field_grid_weights); points whose hats
//                       miss the scene are not computed. --field-rank R: the low-rank form.
//
// Every input (depth values and size, layers, field edge against the sampling limit, the points'
// sampling) is checked before the device starts. The configuration's noise is added on the host as
// the camera adds it (ref::add_noise, the camera's counters for scene 0).
#include "simulate_varying.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <memory>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "psf_outputs.hpp"
#include "simulate_depth.hpp"
#include "qdo/data/figure.hpp"
#include "qdo/physics/camera.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/point_psf.hpp"
#include "qdo/data/scenes.hpp"
#include "qdo/physics/sensor_reference.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/physics/varying.hpp"

namespace qdo::cli {

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr std::size_t kMaxDefaultLayers = 8;  // the default layer rule's largest layer count

const char* const kVaryingOptions[] = {"depth-layers", "depth-scale", "psf-placement", "field-edge-deg", "field-rank"};

std::string metres(double d) { return std::isinf(d) ? std::string("inf") : to_str(d); }
double diopters(double d) { return std::isinf(d) ? 0.0 : 1.0 / d; }

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

std::vector<double> linspace_sym(double edge, std::size_t n) {
  if (n == 1) return {0.0};
  std::vector<double> v(n);
  for (std::size_t i = 0; i < n; ++i) v[i] = -edge + 2.0 * edge * double(i) / double(n - 1);
  return v;
}

// The components whose weight map is nonzero somewhere (K x H x W weights).
std::vector<std::size_t> used_components(const RealStack& w) {
  std::vector<std::size_t> used;
  for (std::size_t k = 0; k < w.planes; ++k) {
    const double* p = w.plane(k);
    if (std::any_of(p, p + w.plane_size(), [](double v) { return v != 0.0; })) used.push_back(k);
  }
  return used;
}

RealStack pick_planes(const RealStack& w, const std::vector<std::size_t>& ks) {
  RealStack out(ks.size(), w.rows, w.cols);
  for (std::size_t i = 0; i < ks.size(); ++i) std::copy(w.plane(ks[i]), w.plane(ks[i]) + w.plane_size(), out.plane(i));
  return out;
}

// A configuration computing `points` (one on-axis point becomes the pre-object-point form, computed
// exactly as a configuration with that scene_distance_m), validated; a refusal names `option`.
SystemConfig points_config(const SystemConfig& cfg, const std::vector<ObjectPoint>& points, const std::string& option,
                           const std::string& value) {
  SystemConfig c = cfg;
  c.object_points = points;
  try {
    c.validate();
  } catch (const InputError& e) {
    reject(option, value, std::string("object points the configuration's sampling supports: ") + e.what());
  }
  return points.size() == 1 ? point_config(c, 0) : c;
}

}  // namespace

bool varying_requested(const Args& a) { return a.has("depth") || a.has("field-grid"); }

void check_no_orphan_varying_options(const Args& a) {
  for (const char* o : kVaryingOptions)
    if (a.has(o)) reject(std::string("--") + o, a.get(o), "only with --depth FILE or --field-grid NX[xNY]");
}

int simulate_varying(const Args& a, const SystemConfig& cfg, Precision p) {
  const bool depth_mode = a.has("depth");
  if (depth_mode && a.has("field-grid"))
    reject("--field-grid", a.get("field-grid"),
           "not together with --depth for now (a depth map and a field grid at once: K = layers x points components, not "
           "supported yet); run one or the other");
  const std::string what = depth_mode ? "--depth" : "--field-grid";
  if (a.get("capture", "scene") != "scene") reject("--capture", a.get("capture"), "scene with " + what);
  if (a.has("psf"))
    reject("--psf", a.get("psf"), "--design with " + what + " (a PSF stack file holds one PSF: it has no depth or field dependence)");
  if (a.get("formation", "qdo") != "qdo")
    reject("--formation", a.get("formation"), "qdo with " + what + " (--psf-placement output is the release's per-depth rule)");
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
    reject("convolution", "circular", "\"convolution\": \"linear\" with " + what + " (the varying operator is a linear convolution)");
  const PsfPlacement placement = psf_placement_from_string(a.get("psf-placement", "source"));
  const Map2D h = design_heights(cfg, a);
  const RealStack scene = scene_from_args(cfg, a);
  const std::size_t rows = scene.rows, cols = scene.cols;
  const double distance_m = cfg.scene_at_infinity ? kInf : cfg.scene_distance_m;

  // ---- The components, their weights and the PSF configuration (host, before any device work) ----
  nlohmann::json info;
  info["mode"] = depth_mode ? "depth" : "field";
  std::vector<std::size_t> used;  // components (layers / grid points) some pixel uses
  std::size_t total = 0;
  RealStack weights;              // used components x H x W
  SystemConfig psf_cfg;
  std::vector<std::pair<long, long>> shifts;
  Map2D layer_map;                // depth: each pixel's layer, in diopters (the figure)
  Map2D depth_diopters;           // depth: the map as read, 1/m (0 = infinity)
  std::string summary, note;
  std::size_t rank = 0;
  if (depth_mode) {
    const Map2D depth = read_depth_map(a, cfg, rows, cols);
    std::string rule;
    const std::vector<double> layers = depth_layers(a, depth, rule);
    const RealStack all = depth_layer_weights(depth, layers, rows, cols);
    total = layers.size();
    used = used_components(all);
    weights = pick_planes(all, used);
    std::vector<ObjectPoint> pts;
    for (std::size_t k : used) pts.push_back(ObjectPoint{layers[k], 0, 0});
    std::string lv;
    for (double d : layers) lv += (lv.empty() ? "" : ",") + metres(d);
    psf_cfg = points_config(cfg, pts, a.has("depth-layers") ? "--depth-layers" : "--depth", a.has("depth-layers") ? lv : a.get("depth"));
    layer_map = Map2D(rows, cols);
    std::vector<std::size_t> pixels(layers.size(), 0);
    for (std::size_t k = 0; k < layers.size(); ++k)
      for (std::size_t i = 0; i < rows * cols; ++i)
        if (all.plane(k)[i] != 0) {
          layer_map.data[i] = diopters(layers[k]);
          ++pixels[k];
        }
    nlohmann::json lj = nlohmann::json::array();
    for (std::size_t k = 0; k < layers.size(); ++k)
      lj.push_back({{"index", k}, {"distance_m", metres(layers[k])}, {"diopters", diopters(layers[k])}, {"pixels", pixels[k]},
                    {"computed", std::find(used.begin(), used.end(), k) != used.end()}});
    info["layers"] = lj;
    info["layer_rule"] = rule;
    info["depth_file"] = a.get("depth");
    depth_diopters = Map2D(rows, cols);
    for (std::size_t i = 0; i < rows * cols; ++i) depth_diopters.data[i] = diopters(depth.data[i]);
    std::string used_s, skipped_s;
    for (std::size_t k = 0; k < layers.size(); ++k) {
      std::string& s = std::find(used.begin(), used.end(), k) != used.end() ? used_s : skipped_s;
      s += (s.empty() ? "" : ", ") + (std::isinf(layers[k]) ? std::string("infinity") : metres(layers[k]) + " m");
    }
    summary = "depth layers (" + rule + "): " + to_str(used.size()) + " of " + to_str(layers.size()) + " used, PSFs computed at " +
              used_s + (skipped_s.empty() ? std::string("; none skipped") : "; skipped (no pixel at that depth): " + skipped_s);
  } else {
    const auto [nx, ny] = field_grid_size(a.get("field-grid"));
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
    if (a.has("field-edge-deg")) {
      const double e = parse_double("--field-edge-deg", a.get("field-edge-deg"), 0, 89, "deg", true);
      if (e > limit)
        reject("--field-edge-deg", a.get("field-edge-deg") + " deg",
               "a field edge within the sampling limit of this configuration at " + metres(distance_m) + " m: " + to_str(limit) +
                   " deg (max_field_angle_deg" + (limit_asm > limit_cfg ? ", with the \"asm\" propagator" : "") + ")");
      ex = ey = e;
      edge_rule = "given (--field-edge-deg)";
    }
    if ((nx > 1 && !(ex > 0)) || (ny > 1 && !(ey > 0)))
      reject("--field-grid", a.get("field-grid"),
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
          reject(a.has("field-edge-deg") ? "--field-edge-deg" : "--field-grid",
                 a.get(a.has("field-edge-deg") ? "field-edge-deg" : "field-grid"),
                 "field points within the sampling (the point at (" + to_str(ax) + ", " + to_str(ay) + ") deg is not: " + why +
                     "; the one-axis limit is " + to_str(limit) + " deg)");
      }
    if (grid_cfg.propagator != cfg.propagator)
      note = "propagator: \"asm\" (band-limited angular spectrum) instead of the configuration's Fresnel, which refuses "
             "these field angles";
    const FieldGrid fg = field_grid(grid_cfg, distance_m, tx, ty);
    const RealStack all = field_grid_weights(rows, cols, fg.rows_px, fg.cols_px);
    total = fg.points.size();
    used = used_components(all);
    weights = pick_planes(all, used);
    std::vector<ObjectPoint> pts;
    for (std::size_t k : used) {
      pts.push_back(fg.points[k]);
      shifts.push_back(fg.shifts_px[k]);
    }
    psf_cfg = points_config(grid_cfg, pts, "--field-grid", a.get("field-grid"));
    if (a.has("field-rank")) rank = std::size_t(parse_int("--field-rank", a.get("field-rank"), 1, int(used.size())));
    nlohmann::json pj = nlohmann::json::array();
    for (std::size_t k = 0; k < fg.points.size(); ++k)
      pj.push_back({{"index", k}, {"field_x_deg", fg.points[k].field_x_deg}, {"field_y_deg", fg.points[k].field_y_deg},
                    {"image_row_px", fg.rows_px[k / tx.size()]}, {"image_col_px", fg.cols_px[k % tx.size()]},
                    {"shift_px", {fg.shifts_px[k].first, fg.shifts_px[k].second}},
                    {"computed", std::find(used.begin(), used.end(), k) != used.end()}});
    info["points"] = pj;
    info["grid"] = {nx, ny};
    info["edge_deg"] = {ex, ey};
    info["edge_rule"] = edge_rule;
    info["sampling_limit_deg"] = limit;
    info["distance_m"] = metres(distance_m);
    info["propagator"] = grid_cfg.propagator == Propagator::Fresnel ? "fresnel" : "asm";
    summary = "field grid " + to_str(nx) + " x " + to_str(ny) + " up to (" + to_str(ex) + ", " + to_str(ey) + ") deg (" + edge_rule +
              "): " + to_str(used.size()) + " of " + to_str(total) + " points computed" +
              (used.size() < total ? " (" + to_str(total - used.size()) + " points' hats miss the scene)" : "");
  }
  std::vector<std::size_t> skipped;
  for (std::size_t k = 0; k < total; ++k)
    if (std::find(used.begin(), used.end(), k) == used.end()) skipped.push_back(k);
  info["computed"] = used;
  info["skipped"] = skipped;
  info["noise"] = {{"read_noise_sigma", cfg.read_noise_sigma}, {"full_well_photons", cfg.full_well_photons}, {"seed", cfg.noise_seed}};
  if (!note.empty()) info["note"] = note;

  // ---- Device work ----
  const std::string dir = out_dir(a);
  std::fprintf(stderr, "[simulate] %s\n", summary.c_str());
  Runtime rt(a.get("device"));
  const auto t0 = std::chrono::steady_clock::now();
  Simulator sim(rt, psf_cfg, p);
  sim.set_keep_field(false);
  sim.set_heights(h);
  sim.compute_psf();
  const RealStack psfs = sim.psf_sensor();  // (used * bands) x S x S, point-major
  const double psf_s = seconds_since(t0);
  std::fprintf(stderr, "[simulate] %zu PSF stack%s of %zu bands computed (%.1f s); imaging %zu x %zu\n", used.size(),
               used.size() == 1 ? "" : "s", cfg.bands, seconds_since(t0), rows, cols);
  RealStack rgb;
  VaryingReport report;
  if (rank > 0) {
    // Low rank: the recentred field PSFs' R principal components, weights u_r = sum_k a_{k,r} w_k.
    RealStack eff(psfs.planes, psfs.rows, psfs.cols);
    for (std::size_t k = 0; k < used.size(); ++k) {
      const RealStack part = shift_planes(point_planes(psfs, k, cfg.bands), shifts[k].first, shifts[k].second);
      std::copy(part.data.begin(), part.data.end(), eff.plane(k * cfg.bands));
    }
    const LowRankPsf lr = low_rank_psf(eff, cfg.bands, rank);
    SystemConfig one = psf_cfg;
    one.object_points.clear();
    VaryingCamera v(rt, one, p, rank);
    v.set_psfs(lr.psfs);
    rgb = v.images(scene, combine_weights(weights, lr.coeff), placement);
    report = v.last_report();
    info["rank"] = rank;
    info["truncation_error"] = lr.truncation_error;
    info["singular_values"] = lr.singular;
    summary += "; rank " + to_str(rank) + " (relative truncation error " + to_str(lr.truncation_error) + ")";
  } else {
    VaryingCamera v(sim);
    if (!shifts.empty()) v.set_shifts(shifts);
    rgb = v.images(scene, weights, placement);
    report = v.last_report();
  }
  ref::add_noise(rgb, cfg.read_noise_sigma, cfg.full_well_photons, cfg.noise_seed, 0);
  const double secs = seconds_since(t0);
  info["report"] = nlohmann::json::parse(report.to_json());
  info["seconds"] = secs;
  info["psf_seconds"] = psf_s;
  const SensorClip clip = clip_to_full_scale(rgb, "sensor image");
  info["clipped_fraction"] = clip.fraction();

  // ---- Outputs ----
  const std::vector<double> wl = cfg.wavelengths_nm();
  write_rgb(dir + "/sensor.h5", rgb, {{"clipped_fraction", clip.fraction()}, {"max_before_clip", clip.max_before}});
  write_rgb_png(dir + "/sensor.png", rgb);
  write_rgb_png(dir + "/scene.png", ref::sensor_integrate(scene, sensor_response(cfg)));
  {
    // The computed PSFs: (points * bands) x S x S, with each point's inverse distance and angles.
    std::vector<double> inv_d, fx, fy;
    for (const ObjectPoint& q : psf_cfg.points()) {
      inv_d.push_back(diopters(q.distance_m));
      fx.push_back(q.field_x_deg);
      fy.push_back(q.field_y_deg);
    }
    const std::size_t np = inv_d.size();
    h5_write(dir + "/psf_points.h5",
             {{"/psf_sensor", {psfs.planes, psfs.rows, psfs.cols}, psfs.data, {{"pitch_m", cfg.sensor_pitch_m}},
               {{"layout", "point-major: plane p * bands + b"}}},
              {"/wavelengths_nm", {wl.size()}, wl, {}, {{"units", "nm"}}},
              {"/inverse_distance_per_m", {np}, inv_d, {}, {{"units", "1/m (diopters), 0 = infinity"}}},
              {"/field_x_deg", {np}, fx, {}, {{"units", "deg"}}},
              {"/field_y_deg", {np}, fy, {}, {{"units", "deg"}}}},
             {{"config", config_to_json_text(psf_cfg)}, {"source", "qdo simulate " + what}});
    // Figure: each computed point's PSF at the middle band (field points recentred on the axis, as imaged).
    const std::size_t mid = cfg.bands / 2;
    RealStack fig(np, psfs.rows, psfs.cols);
    for (std::size_t k = 0; k < np; ++k) {
      RealStack one(1, psfs.rows, psfs.cols);
      std::copy(psfs.plane(k * cfg.bands + mid), psfs.plane(k * cfg.bands + mid) + psfs.plane_size(), one.plane(0));
      if (!shifts.empty()) one = shift_planes(one, shifts[k].first, shifts[k].second);
      std::copy(one.data.begin(), one.data.end(), fig.plane(k));
    }
    std::vector<std::string> titles;
    for (std::size_t k = 0; k < np; ++k) titles.push_back("point " + to_str(k));
    write_psf_panels(dir + "/psf.png", "PSF of each computed point at " + to_str(wl[mid]) + " nm (recentred; psf.h5 lists the points)",
                     fig, titles, cfg.sensor_pitch_m, 96);
  }
  write_height_figure(dir + "/design.png", "DOE height map", h, cfg.pitch_m);
  if (depth_mode) {
    ImagePlot dp;
    dp.title = "Depth layer each pixel was imaged at";
    dp.x_label = "x (pixels)";
    dp.y_label = "y (pixels)";
    dp.value_label = "1 / depth (1/m; 0 = infinity)";
    dp.values = layer_map;
    write_image_plot(dir + "/depth.png", dp);
    h5_write(dir + "/depth.h5",
             {{"/inverse_depth_per_m", {rows, cols}, depth_diopters.data, {}, {{"units", "1/m (diopters), 0 = infinity: the depth map read"}}},
              {"/layer_inverse_depth_per_m", {rows, cols}, layer_map.data, {}, {{"units", "1/m, the layer each pixel was imaged at"}}}},
             {{"source", "qdo simulate --depth " + a.get("depth")}});
  }
  write_text_atomic(dir + "/varying.json", info.dump(2) + "\n");
  std::printf("device: %s\nformation: qdo, spatially varying (%s placement)\n%s\n%s%s"
              "scene %zu x %zu x %zu -> sensor 3 x %zu x %zu in %.3f s (PSFs %.3f s + varying convolution + sensor, %s); "
              "%zu forward and %zu inverse FFTs of %zu x %zu, %zu components kept, %zu skipped in the operator\n"
              "noise: %s\n%s\n%s\nwrote %s/sensor.h5, sensor.png, scene.png, psf_points.h5, psf.png, design.png%s, varying.json\n",
              rt.info().name.c_str(), to_string(placement).c_str(), summary.c_str(), note.empty() ? "" : note.c_str(),
              note.empty() ? "" : "\n", scene.planes, rows, cols, rgb.rows, rgb.cols, secs, psf_s, to_string(p).c_str(), report.forward_ffts,
              report.inverse_ffts, report.grid_rows, report.grid_cols, report.kept.size(), report.skipped.size(),
              cfg.read_noise_sigma > 0 || cfg.full_well_photons > 0 ? "the configuration's (read noise and shot noise as the camera adds them)"
                                                                    : "none (the configuration's noise is zero)",
              sim.sampling().summary().c_str(), clip_summary(clip).c_str(), dir.c_str(), depth_mode ? ", depth.png, depth.h5" : "");
  return 0;
}

}  // namespace qdo::cli
