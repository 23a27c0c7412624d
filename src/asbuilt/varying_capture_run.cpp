// The device half of a spatially varying capture (varying_capture.hpp): the PSFs of the plan's used
// components, the image through VaryingCamera (directly or in the low-rank form), the noise, and the
// output files. The plans: varying_capture.cpp.
#include "qdo/asbuilt/varying_capture.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "qdo/data/figure.hpp"
#include "qdo/data/io.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/point_psf.hpp"
#include "qdo/physics/sensor_reference.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/util.hpp"

namespace qdo {

namespace {

double diopters(double d) { return std::isinf(d) ? 0.0 : 1.0 / d; }

void check_run_inputs(const VaryingPlan& plan, const RealStack& scene) {
  if (scene.planes != plan.cfg.bands || scene.rows != plan.rows || scene.cols != plan.cols)
    reject("scene", to_str(scene.planes) + " x " + to_str(scene.rows) + " x " + to_str(scene.cols),
           "the planned scene's shape, bands x rows x cols = " + to_str(plan.cfg.bands) + " x " + to_str(plan.rows) + " x " +
               to_str(plan.cols));
  if (plan.weights.planes != plan.used.size() || plan.weights.rows != plan.rows || plan.weights.cols != plan.cols)
    reject("plan.weights", to_str(plan.weights.planes) + " x " + to_str(plan.weights.rows) + " x " + to_str(plan.weights.cols),
           "used components x rows x cols = " + to_str(plan.used.size()) + " x " + to_str(plan.rows) + " x " + to_str(plan.cols));
  if (plan.mode == VaryingMode::Depth && plan.rank != 0)
    reject("plan.rank", plan.rank, "0 in a depth plan (the low-rank form is the field grid's)");
  if (plan.rank > plan.used.size()) reject("plan.rank", plan.rank, "0 or an integer in [1, " + to_str(plan.used.size()) + "]");
  if (plan.mode == VaryingMode::Field && plan.shifts.size() != plan.used.size())
    reject("plan.shifts", plan.shifts.size(), "one shift per used point (" + to_str(plan.used.size()) + ")");
}

}  // namespace

VaryingCaptureResult run_varying_capture(Runtime& rt, const VaryingPlan& plan, const Map2D& heights_m, const RealStack& scene,
                                         Precision precision, const std::function<void(const std::string&)>& say) {
  check_run_inputs(plan, scene);
  const SystemConfig& cfg = plan.cfg;
  nlohmann::json info = nlohmann::json::parse(plan.info_json);
  VaryingCaptureResult r;
  r.summary = plan.summary;
  const auto t0 = std::chrono::steady_clock::now();
  Simulator sim(rt, plan.psf_cfg, precision);
  sim.set_keep_field(false);
  sim.set_heights(heights_m);
  sim.compute_psf();
  r.psfs = sim.psf_sensor();  // (used * bands) x S x S, point-major
  r.psf_seconds = seconds_since(t0);
  if (say) {
    char line[256];
    std::snprintf(line, sizeof line, "%zu PSF stack%s of %zu bands computed (%.1f s); imaging %zu x %zu", plan.used.size(),
                  plan.used.size() == 1 ? "" : "s", cfg.bands, seconds_since(t0), plan.rows, plan.cols);
    say(line);
  }
  if (plan.rank > 0) {
    // Low rank: the recentred field PSFs' R principal components, weights u_r = sum_k a_{k,r} w_k.
    RealStack eff(r.psfs.planes, r.psfs.rows, r.psfs.cols);
    for (std::size_t k = 0; k < plan.used.size(); ++k) {
      const RealStack part = shift_planes(point_planes(r.psfs, k, cfg.bands), plan.shifts[k].first, plan.shifts[k].second);
      std::copy(part.data.begin(), part.data.end(), eff.plane(k * cfg.bands));
    }
    const LowRankPsf lr = low_rank_psf(eff, cfg.bands, plan.rank);
    SystemConfig one = plan.psf_cfg;
    one.object_points.clear();
    VaryingCamera v(rt, one, precision, plan.rank);
    v.set_psfs(lr.psfs);
    r.rgb = v.images(scene, combine_weights(plan.weights, lr.coeff), plan.placement);
    r.report = v.last_report();
    info["rank"] = plan.rank;
    info["truncation_error"] = lr.truncation_error;
    info["singular_values"] = lr.singular;
    r.summary += "; rank " + to_str(plan.rank) + " (relative truncation error " + to_str(lr.truncation_error) + ")";
  } else {
    VaryingCamera v(sim);
    if (!plan.shifts.empty()) v.set_shifts(plan.shifts);
    r.rgb = v.images(scene, plan.weights, plan.placement);
    r.report = v.last_report();
  }
  ref::add_noise(r.rgb, cfg.read_noise_sigma, cfg.full_well_photons, cfg.noise_seed, 0);
  r.seconds = seconds_since(t0);
  r.sampling_summary = sim.sampling().summary();
  info["report"] = nlohmann::json::parse(r.report.to_json());
  info["seconds"] = r.seconds;
  info["psf_seconds"] = r.psf_seconds;
  r.clip = clip_to_full_scale(r.rgb, "sensor image");
  info["clipped_fraction"] = r.clip.fraction();
  r.info_json = info.dump();
  return r;
}

void write_varying_outputs(const std::string& dir, const VaryingPlan& plan, const VaryingCaptureResult& result,
                           const Map2D& heights_m, const RealStack& scene, const std::string& provenance) {
  const SystemConfig& cfg = plan.cfg;
  const RealStack& psfs = result.psfs;
  const std::vector<double> wl = cfg.wavelengths_nm();
  write_rgb(dir + "/sensor.h5", result.rgb, {{"clipped_fraction", result.clip.fraction()}, {"max_before_clip", result.clip.max_before}});
  write_rgb_png(dir + "/sensor.png", result.rgb);
  write_rgb_png(dir + "/scene.png", ref::sensor_integrate(scene, sensor_response(cfg)));
  {
    // The computed PSFs: (points * bands) x S x S, with each point's inverse distance and angles.
    std::vector<double> inv_d, fx, fy;
    for (const ObjectPoint& q : plan.psf_cfg.points()) {
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
             {{"config", config_to_json_text(plan.psf_cfg)}, {"source", provenance}});
    // Figure: each computed point's PSF at the middle band (field points recentred on the axis, as imaged).
    const std::size_t mid = cfg.bands / 2;
    RealStack fig(np, psfs.rows, psfs.cols);
    for (std::size_t k = 0; k < np; ++k) {
      RealStack one(1, psfs.rows, psfs.cols);
      std::copy(psfs.plane(k * cfg.bands + mid), psfs.plane(k * cfg.bands + mid) + psfs.plane_size(), one.plane(0));
      if (!plan.shifts.empty()) one = shift_planes(one, plan.shifts[k].first, plan.shifts[k].second);
      std::copy(one.data.begin(), one.data.end(), fig.plane(k));
    }
    std::vector<std::string> titles;
    for (std::size_t k = 0; k < np; ++k) titles.push_back("point " + to_str(k));
    write_psf_panels(dir + "/psf.png", "PSF of each computed point at " + to_str(wl[mid]) + " nm (recentred; psf.h5 lists the points)",
                     fig, titles, cfg.sensor_pitch_m, 96);
  }
  write_height_figure(dir + "/design.png", "DOE height map", heights_m, cfg.pitch_m);
  if (plan.mode == VaryingMode::Depth) {
    ImagePlot dp;
    dp.title = "Depth layer each pixel was imaged at";
    dp.x_label = "x (pixels)";
    dp.y_label = "y (pixels)";
    dp.value_label = "1 / depth (1/m; 0 = infinity)";
    dp.values = plan.layer_map;
    write_image_plot(dir + "/depth.png", dp);
    h5_write(dir + "/depth.h5",
             {{"/inverse_depth_per_m", {plan.rows, plan.cols}, plan.depth_diopters.data, {},
               {{"units", "1/m (diopters), 0 = infinity: the depth map read"}}},
              {"/layer_inverse_depth_per_m", {plan.rows, plan.cols}, plan.layer_map.data, {},
               {{"units", "1/m, the layer each pixel was imaged at"}}}},
             {{"source", provenance + " " + plan.depth_source}});
  }
  write_text_atomic(dir + "/varying.json", nlohmann::json::parse(result.info_json).dump(2) + "\n");
}

}  // namespace qdo
