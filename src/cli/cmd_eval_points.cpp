// qdo eval-points RUN: a design's quality against object distance and field angle, its depth of
// field and its valid field of view (eval_points.hpp) -> OUT/points.json, points.csv and figures.
#include <cmath>
#include <cstdio>
#include <limits>

#include "cli.hpp"
#include "options.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/evaluate/eval_points.hpp"
#include "qdo/runtime/runtime.hpp"

namespace qdo::cli {
namespace {

std::string metres(double d) { return std::isinf(d) ? std::string("inf") : to_str(d); }

}  // namespace

static int cmd_eval_points(const Args& a) {
  EvalPointsOptions o;
  o.run = a.positional;
  o.design_file = a.get("design");
  if (a.has("distances")) {
    o.distances_m.clear();
    for (const std::string& v : split_items(a.get("distances"))) {
      if (v == "inf") {
        o.distances_m.push_back(std::numeric_limits<double>::infinity());
        continue;
      }
      const double d = parse_double("--distances", v);
      if (!(d > 0)) reject("--distances", v + " m", "distances in metres > 0, or inf");
      o.distances_m.push_back(d);
    }
    if (o.distances_m.empty()) reject("--distances", a.get("distances"), "a comma-separated list of distances in metres (or inf)");
  }
  if (a.has("angles")) {
    for (const std::string& v : split_items(a.get("angles"))) {
      const double t = parse_double("--angles", v);
      if (t < 0) reject("--angles", v + " degrees", "field angles >= 0 degrees (along x)");
      o.angles_deg.push_back(t);
    }
    if (o.angles_deg.empty()) reject("--angles", a.get("angles"), "a comma-separated list of angles in degrees");
  }
  if (a.has("nominal")) {
    const std::string v = a.get("nominal");
    o.nominal_m = v == "inf" ? std::numeric_limits<double>::infinity() : parse_double("--nominal", v);
    if (!(o.nominal_m > 0)) reject("--nominal", v + " m", "a distance in metres > 0, or inf");
  }
  o.angle_steps = std::size_t(parse_int("--angle-steps", a.get("angle-steps"), 1, 1000));
  o.data = scene_paths(a, "data");
  o.synthetic_scenes = std::size_t(parse_int("--synthetic-scenes", a.get("synthetic-scenes"), 1, 100000));
  o.fov_tolerance = parse_double("--fov-tolerance", a.get("fov-tolerance"), 0, 10, "", true);
  o.dof_margin_db = parse_double("--dof-margin-db", a.get("dof-margin-db"), 0, 100, "dB", true);
  o.noise_sigma = a.has("noise-sigma") ? parse_double("--noise-sigma", a.get("noise-sigma"), 0, 10, "(units of full scale)") : -1;
  if (a.has("decoder-kind")) o.decoder_kind = decoder_spec_from_string(a.get("decoder-kind"));
  o.precision = precision_from_string(a.get("precision"));
  o.out = a.get("out");
  if (o.out.empty()) reject("--out", "(missing)", "an output folder");
  check_eval_points(o);  // every value, the run and the design before the folder is claimed or the device opened
  claim_out(a, o.out);
  Runtime rt(a.get("device"));
  const EvalPointsResult r = evaluate_points(rt, o);
  std::printf("%-10s %14s %14s\n", "distance", "PSNR mismatch", "PSNR matched");
  for (const DistanceRow& d : r.distances)
    std::printf("%-10s %14.2f %14.2f\n", (metres(d.distance_m) + " m").c_str(), d.mismatch.psnr_db.mean, d.matched.psnr_db.mean);
  std::printf("depth of field (mismatch PSNR within %g dB of %.2f dB at %s m): %s%s m .. %s%s m\n", o.dof_margin_db, r.nominal_psnr_db,
              metres(r.nominal_distance_m).c_str(), r.dof_near_open ? "<= " : "", metres(r.dof_near_m).c_str(), r.dof_far_open ? ">= " : "",
              metres(r.dof_far_m).c_str());
  std::printf("%-10s %12s %12s %10s\n", "angle", "model error", "PSNR", "lost");
  for (const AngleRow& t : r.angles)
    std::printf("%-10.4g %12.4g %12.2f %10.3g\n", t.angle_deg, t.model_error, t.on_axis_decoder.psnr_db.mean, t.energy_lost);
  std::printf("field edge %.4g degrees (sensor window %.4g, sampling %.4g: %s binds)%s\n", r.field_edge_deg, r.window_edge_deg,
              r.sampling_edge_deg, r.field_edge_binds.c_str(),
              r.switched_to_asm ? "; field angles computed with the asm propagator (the run's is Fresnel)" : "");
  std::printf("valid field of view (model error <= %g): %.4g degrees half-angle, %.4g full; limited by %s\n", o.fov_tolerance,
              r.fov_half_deg, r.fov_full_deg, r.fov_limited_by.c_str());
  std::printf("wrote %s/ (points.json points.csv quality_vs_distance.png quality_vs_angle.png psf_vs_distance.png psf_vs_angle.png)\n",
              o.out.c_str());
  return 0;
}

namespace {
// qdo eval-points: its entry in the command table (help order 130).
const RegisterCommand registered_eval_points(130, [] {
  using namespace opts;
  CommandSpec c{"eval-points", "a run's design against object distance and field angle: quality, depth of field and valid field of view",
                   "RUN", "run folder written by qdo design",
                   {opt("design", "a design .h5 (N x N at the run's pitch) evaluated in place of RUN/design.h5"),
                    opt("distances", "object distances in metres, comma-separated, each > 0 or inf (a point at infinity); the "
                                     "nominal distance (--nominal) is always added", "0.3,0.5,0.7,1,1.5,2,3,5,10,inf"),
                    opt("nominal", "the distance the camera is focused at, metres > 0 or inf: the mismatch decoder is built for "
                                   "the PSF there and the field angles are evaluated there (default: the run's one object point, "
                                   "else its scene_distance_m)"),
                    opt("angles", "field angles along x in degrees, comma-separated, each in [0, the sampling limit at the nominal "
                                  "distance] (default: 0 to the field edge, min(atan(half the sensor window / z), that limit), in "
                                  "--angle-steps steps); 0 is always added"),
                    opt("angle-steps", "steps of the default angle grid, an integer in [1, 1000]", "8"),
                    data("test scenes (default: synthetic held-out scenes, as qdo eval)"), data_root(), synthetic_scenes("6"),
                    opt("fov-tolerance", "largest model error ||I_theta - I_0|| / ||I_0|| (field-dependent image against the "
                                         "shift-invariant model's) inside the valid field of view, a number in (0, 10]; 0.05: a 5 % "
                                         "relative image error, about 26 dB of model PSNR", "0.05"),
                    opt("dof-margin-db", "depth of field: the distances where the mismatch PSNR stays within this many dB of the "
                                         "nominal's, a number in (0, 100]", "1"),
                    noise_sigma("sensor noise std, in units of full scale, in [0, 10] (default: the run's)", ""),
                    opt("decoder-kind", "decoder built from the PSF: wiener (default) or cg[:tolerance=T,max_iterations=N]", DecoderSpec{}.to_string()),
                    precision(), device(), out_dir_opt()},
                   cmd_eval_points};
  return c;
});
}  // namespace

}  // namespace qdo::cli
