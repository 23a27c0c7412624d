// qdo eval-points' options read from text and its report (eval_points.hpp).
#include "qdo/evaluate/eval_points.hpp"

#include <cmath>
#include <limits>

#include "qdo/design/option_inputs.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/strprintf.hpp"
#include "qdo/runtime/util.hpp"

namespace qdo {

namespace {

std::string metres(double d) { return std::isinf(d) ? std::string("inf") : to_str(d); }

}  // namespace

EvalPointsOptions eval_points_options_from_options(const std::string& run, const TextOptions& a) {
  EvalPointsOptions o;
  o.run = run;
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
    if (o.distances_m.empty())
      reject("--distances", a.get("distances"), "a comma-separated list of distances in metres (or inf)");
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
  o.angle_steps = std::size_t(parse_int("--angle-steps", a.get("angle-steps", "8"), 1, 1000));
  o.data = scene_paths_from_options(a, "data");
  o.synthetic_scenes = std::size_t(parse_int("--synthetic-scenes", a.get("synthetic-scenes", "6"), 1, 100000));
  o.fov_tolerance = parse_double("--fov-tolerance", a.get("fov-tolerance", "0.05"), 0, 10, "", true);
  o.dof_margin_db = parse_double("--dof-margin-db", a.get("dof-margin-db", "1"), 0, 100, "dB", true);
  o.noise_sigma =
      a.has("noise-sigma") ? parse_double("--noise-sigma", a.get("noise-sigma"), 0, 10, "(units of full scale)") : -1;
  if (a.has("decoder-kind")) o.decoder_kind = decoder_spec_from_string(a.get("decoder-kind"));
  o.precision = precision_from_string(a.get("precision", "f32"));
  o.out = a.get("out");
  if (o.out.empty()) reject("--out", "(missing)", "an output folder");
  check_eval_points(o);  // every value, the run and the design before the folder is claimed or the device opened
  return o;
}

std::string eval_points_report(const EvalPointsOptions& o, const EvalPointsResult& r) {
  std::string s = strprintf("%-10s %14s %14s\n", "distance", "PSNR mismatch", "PSNR matched");
  for (const DistanceRow& d : r.distances)
    s += strprintf("%-10s %14.2f %14.2f\n", (metres(d.distance_m) + " m").c_str(), d.mismatch.psnr_db.mean,
                   d.matched.psnr_db.mean);
  s += strprintf("depth of field (mismatch PSNR within %g dB of %.2f dB at %s m): %s%s m .. %s%s m\n", o.dof_margin_db,
                 r.nominal_psnr_db, metres(r.nominal_distance_m).c_str(), r.dof_near_open ? "<= " : "",
                 metres(r.dof_near_m).c_str(), r.dof_far_open ? ">= " : "", metres(r.dof_far_m).c_str());
  s += strprintf("%-10s %12s %12s %10s\n", "angle", "model error", "PSNR", "lost");
  for (const AngleRow& t : r.angles)
    s += strprintf("%-10.4g %12.4g %12.2f %10.3g\n", t.angle_deg, t.model_error, t.on_axis_decoder.psnr_db.mean,
                   t.energy_lost);
  s += strprintf("field edge %.4g degrees (sensor window %.4g, sampling %.4g: %s binds)%s\n", r.field_edge_deg,
                 r.window_edge_deg, r.sampling_edge_deg, r.field_edge_binds.c_str(),
                 r.switched_to_asm ? "; field angles computed with the asm propagator (the run's is Fresnel)" : "");
  s += strprintf("valid field of view (model error <= %g): %.4g degrees half-angle, %.4g full; limited by %s\n",
                 o.fov_tolerance, r.fov_half_deg, r.fov_full_deg, r.fov_limited_by.c_str());
  s += strprintf(
      "wrote %s/ (points.json points.csv quality_vs_distance.png quality_vs_angle.png psf_vs_distance.png "
      "psf_vs_angle.png)\n",
      o.out.c_str());
  return s;
}

}  // namespace qdo
