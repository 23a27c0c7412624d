// `qdo eval-points`: a design's quality against object distance and field angle, its depth of
// field and its valid field of view (eval_points.hpp).
#include "qdo/evaluate/eval_points.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <memory>

#include "qdo/decode/decoder_registry.hpp"
#include "qdo/design/design_run.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/hash.hpp"
#include "evaluate/eval_points_figures.hpp"
#include "qdo/data/io.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/point_psf.hpp"
#include "qdo/design/psf_spec.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/decode/testset.hpp"

namespace fs = std::filesystem;

namespace qdo {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kDeg = M_PI / 180.0;

std::string metres(double d) { return std::isinf(d) ? std::string("inf") : to_str(d); }
nlohmann::json metres_json(double d) { return std::isinf(d) ? nlohmann::json("inf") : nlohmann::json(d); }

// The configuration the points are evaluated with: the run's system with its object points
// dropped (each evaluated point is its own).
SystemConfig base_config(const SystemConfig& run_cfg) {
  SystemConfig c = run_cfg;
  c.object_points.clear();
  return c;
}
// The nominal distance (EvalPointsOptions::nominal_m's rule).
double nominal_of(const SystemConfig& run_cfg, double given) {
  if (!std::isnan(given)) {
    if (!(given > 0)) reject("nominal", metres(given), "a distance in metres > 0, or inf");
    return given;
  }
  if (run_cfg.object_points.size() == 1) return run_cfg.object_points[0].distance_m;
  return run_cfg.scene_at_infinity ? kInf : run_cfg.scene_distance_m;
}
SystemConfig asm_config(const SystemConfig& c) {
  SystemConfig a = c;
  a.propagator = Propagator::AngularSpectrum;
  return a;
}

struct Resolved {
  SystemConfig cfg, cfg_asm;
  double nominal = 1;
  std::vector<double> distances;  // ascending, inf last, with the nominal
  std::vector<double> angles;     // ascending, with 0
  double window_deg = 0, sampling_deg = 0, edge_deg = 0;
  std::string binds;
};

Resolved resolve(const EvalPointsOptions& o, const SystemConfig& run_cfg) {
  Resolved r;
  r.cfg = base_config(run_cfg);
  r.cfg_asm = asm_config(r.cfg);
  r.nominal = nominal_of(run_cfg, o.nominal_m);
  if (!(o.fov_tolerance > 0 && o.fov_tolerance <= 10)) reject("fov-tolerance", o.fov_tolerance, "a number in (0, 10] (relative image error)");
  if (!(o.dof_margin_db > 0 && o.dof_margin_db <= 100)) reject("dof-margin-db", o.dof_margin_db, "a number in (0, 100] dB");
  if (o.angle_steps < 1 || o.angle_steps > 1000) reject("angle-steps", o.angle_steps, "an integer in [1, 1000]");
  if (std::isnan(o.noise_sigma) || o.noise_sigma > 10) reject("noise-sigma", o.noise_sigma, "in [0, 10] (units of full scale), or < 0 for the run's");
  std::vector<double> d = o.distances_m.empty() ? default_distances_m() : o.distances_m;
  if (d.size() > 200) reject("distances", to_str(d.size()) + " values", "at most 200 distances");
  for (double v : d)
    if (!(v > 0) || (std::isinf(v) && v < 0)) reject("distances", metres(v), "distances in metres > 0, or inf (a point at infinity)");
  std::vector<double> sorted = d;
  std::sort(sorted.begin(), sorted.end());
  for (std::size_t i = 1; i < sorted.size(); ++i)
    if (sorted[i] == sorted[i - 1]) reject("distances", metres(sorted[i]), "distinct distances (given twice)");
  if (std::find(sorted.begin(), sorted.end(), r.nominal) == sorted.end()) sorted.push_back(r.nominal);
  std::sort(sorted.begin(), sorted.end());
  r.distances = sorted;

  const double half_m = double(r.cfg.n) / 2.0 * r.cfg.pitch_m;
  r.window_deg = std::atan(half_m / r.cfg.sensor_distance_m) / kDeg;
  r.sampling_deg = max_field_angle_deg(r.cfg_asm, r.nominal);
  r.edge_deg = std::min(r.window_deg, r.sampling_deg);
  r.binds = r.sampling_deg >= r.window_deg * (1 - 1e-6) ? "sensor window" : "sampling";
  const auto why = [&](double a) { return object_point_limit(r.cfg_asm, ObjectPoint{r.nominal, a, 0}); };
  std::vector<double> a = o.angles_deg;
  if (a.empty()) {
    for (std::size_t k = 0; k <= o.angle_steps; ++k) a.push_back(r.edge_deg * double(k) / double(o.angle_steps));
    if (!why(a.back()).empty()) a.back() = r.sampling_deg;  // the window's angle rounded past the limit: the limit itself
  } else {
    if (a.size() > 1000) reject("angles", to_str(a.size()) + " values", "at most 1000 angles");
    for (double v : a) {
      if (!(v >= 0) || !std::isfinite(v)) reject("angles", v, "field angles in degrees >= 0 (along x)");
      const std::string w = why(v);
      if (!w.empty())
        reject("angles", v,
               "angles within the sampling limit " + to_str(r.sampling_deg) + " degrees at the nominal distance " + metres(r.nominal) +
                   " m (max_field_angle_deg, angular spectrum; the sensor window alone allows " + to_str(r.window_deg) +
                   " degrees): " + w);
    }
    a.push_back(0.0);
  }
  std::sort(a.begin(), a.end());
  a.erase(std::unique(a.begin(), a.end()), a.end());
  r.angles = a;
  return r;
}

// The design's PSF stacks (bands x S x S each) at `points` of cfg, computed in batches of object
// points (one Simulator pass per batch) small enough that the propagated fields stay within ~1 GiB.
// A batch of one on-axis point is computed in its pre-object-point form (point_config), exactly as
// `qdo eval` computes a configuration at that distance.
std::vector<RealStack> point_psfs(Runtime& rt, const SystemConfig& cfg, const std::vector<ObjectPoint>& points, const Map2D& h,
                                  Precision p, const std::string& what, bool progress) {
  const std::size_t m = cfg.n + 2 * cfg.padding_px;
  const double per_point = double(cfg.bands) * double(m) * double(m) * (p == Precision::F64 ? 16.0 : 8.0);
  const std::size_t chunk = std::max<std::size_t>(1, std::size_t(double(1ull << 30) / per_point));
  std::vector<RealStack> out;
  for (std::size_t base = 0; base < points.size(); base += chunk) {
    const std::size_t end = std::min(points.size(), base + chunk);
    SystemConfig c = cfg;
    c.object_points.assign(points.begin() + long(base), points.begin() + long(end));
    if (c.object_points.size() == 1) c = point_config(c, 0);
    const auto t0 = std::chrono::steady_clock::now();
    Simulator sim(rt, c, p);
    sim.set_heights(h);
    sim.compute_psf();
    const RealStack all = sim.psf_sensor();
    for (std::size_t q = 0; q < end - base; ++q) out.push_back(point_planes(all, q, cfg.bands));
    if (progress) {
      std::printf("[eval-points] %s PSFs %zu..%zu of %zu computed (%.1f s)\n", what.c_str(), base + 1, end, points.size(),
                  std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
      std::fflush(stdout);
    }
  }
  return out;
}

PointQuality quality_of(const testset::Evaluation& ev) {
  PointQuality q;
  auto spread = [&](auto get) {
    Spread s;
    s.mean = get(ev.mean);
    s.min = kInf;
    s.max = -kInf;
    for (const auto& [name, sc] : ev.per_scene) {
      s.min = std::min(s.min, get(sc));
      s.max = std::max(s.max, get(sc));
    }
    return s;
  };
  q.psnr_db = spread([](const testset::Scores& s) { return s.psnr; });
  q.ssim = spread([](const testset::Scores& s) { return s.ssim; });
  q.sam_rad = spread([](const testset::Scores& s) { return s.sam_rad; });
  return q;
}

nlohmann::json spread_json(const Spread& s) { return {{"mean", s.mean}, {"min", s.min}, {"max", s.max}}; }
nlohmann::json quality_json(const PointQuality& q) {
  return {{"psnr_db", spread_json(q.psnr_db)}, {"ssim", spread_json(q.ssim)}, {"sam_rad", spread_json(q.sam_rad)}};
}

}  // namespace

std::vector<double> default_distances_m() { return {0.3, 0.5, 0.7, 1, 1.5, 2, 3, 5, 10, kInf}; }

double valid_fov_deg(const std::vector<double>& a, const std::vector<double>& e, double tol, bool* exceeded) {
  if (a.empty() || a.size() != e.size()) reject("errors", to_str(e.size()) + " values", "one per angle (" + to_str(a.size()) + "), at least one");
  for (std::size_t k = 1; k < a.size(); ++k)
    if (!(a[k] > a[k - 1])) reject("angles", a[k], "ascending angles");
  if (exceeded) *exceeded = false;
  for (std::size_t k = 0; k < a.size(); ++k) {
    if (!(e[k] > tol)) continue;
    if (exceeded) *exceeded = true;
    if (k == 0) return a[0];
    const double t = (tol - e[k - 1]) / (e[k] - e[k - 1]);
    return a[k - 1] + t * (a[k] - a[k - 1]);
  }
  return a.back();
}

DepthOfField depth_of_field(const std::vector<double>& d, const std::vector<double>& psnr, std::size_t nominal, double margin) {
  if (d.size() != psnr.size() || nominal >= d.size())
    reject("psnr_db", to_str(psnr.size()) + " values", "one per distance (" + to_str(d.size()) + "), the nominal among them");
  const double floor_db = psnr[nominal] - margin;
  const auto inv = [](double v) { return std::isinf(v) ? 0.0 : 1.0 / v; };
  // The crossing between sample i (inside) and j (outside), linear in 1/d.
  const auto cross = [&](std::size_t i, std::size_t j) {
    const double t = (psnr[i] - floor_db) / (psnr[i] - psnr[j]);
    const double x = inv(d[i]) + t * (inv(d[j]) - inv(d[i]));
    return x > 0 ? 1.0 / x : kInf;
  };
  DepthOfField r;
  std::size_t i = nominal;
  while (i > 0 && psnr[i - 1] >= floor_db) --i;
  if (i == 0) {
    r.near_m = d[0];
    r.near_open = true;
  } else {
    r.near_m = cross(i, i - 1);
  }
  std::size_t j = nominal;
  while (j + 1 < d.size() && psnr[j + 1] >= floor_db) ++j;
  if (j + 1 == d.size()) {
    r.far_m = d.back();
    r.far_open = !std::isinf(d.back());
  } else {
    r.far_m = cross(j, j + 1);
  }
  return r;
}

namespace {

// The design evaluated, as a PSF spec (psf_spec.hpp): the run's own, or design_file (lens:NM, flat
// or a design .h5 at the run's grid), named "design" in refusals.
PsfSpec design_spec(const EvalPointsOptions& o) {
  return {o.design_file.empty() ? PsfSpec::Kind::Run : PsfSpec::Kind::Design, o.design_file, "design"};
}

}  // namespace

void check_eval_points(const EvalPointsOptions& o) {
  // A run trained over a range of object points (qdo design --object-distances) is evaluated like any other.
  const DesignRunOptions ro = read_run_config(o.run, "run", "a run folder written by qdo design (config.json missing)", true);
  (void)resolve(o, ro.cfg);
  const SystemConfig cfg = base_config(ro.cfg);
  if (!o.design_file.empty()) (void)read_psf_input(design_spec(o), cfg);
  const DecoderSpec spec = o.decoder_kind ? *o.decoder_kind : DecoderSpec{};
  if (decoder_entry(spec.kind_name()).trained)
    reject("decoder-kind", spec.to_string(), "a decoder built from the PSF (wiener, cg): it is refit for every distance");
}

EvalPointsResult evaluate_points(Runtime& rt, const EvalPointsOptions& o) {
  check_eval_points(o);
  const RunFolder folder(o.run);
  // A run trained over a range of object points (qdo design --object-distances) is evaluated like any other.
  const DesignRunOptions ro = read_run_config(o.run, "run", "a run folder written by qdo design (config.json missing)", true);
  const Resolved rs = resolve(o, ro.cfg);
  const SystemConfig& cfg = rs.cfg;
  const Map2D run_h = o.design_file.empty() ? folder.design().height_m : Map2D{};
  const Map2D h = read_psf_input(design_spec(o), cfg, &run_h).heights;
  if (h.rows != cfg.n || h.cols != cfg.n)
    reject("run", folder.design_path(), "a design of N x N = " + to_str(cfg.n) + " x " + to_str(cfg.n) + " samples (the run's grid)");
  const std::size_t s = cfg.sensor_size_px();
  const wiener::SpectralPrior prior = folder.prior(s);
  const DecoderSpec spec = o.decoder_kind ? *o.decoder_kind : DecoderSpec{};
  const double sigma = o.noise_sigma >= 0 ? o.noise_sigma : ro.decoder_noise_sigma;
  const std::vector<testset::Patch> patches = testset::patches(cfg, s, o.data, o.data_format, o.synthetic_scenes, ro.design.seed);
  if (!o.out.empty()) make_output_dir(o.out, "out");

  EvalPointsResult res;
  res.nominal_distance_m = rs.nominal;
  res.decoder = spec.to_string();
  res.noise_sigma = sigma;
  res.patches = patches.size();
  res.switched_to_asm = cfg.propagator == Propagator::Fresnel;
  res.window_edge_deg = rs.window_deg;
  res.sampling_edge_deg = rs.sampling_deg;
  res.field_edge_deg = rs.edge_deg;
  res.field_edge_binds = rs.binds;

  testset::PatchCamera camera(rt, cfg);
  const Eigen::MatrixXd srf = sensor_response(cfg);
  auto decoder_for = [&](const RealStack& psf) {
    DecoderInputs in;
    in.spec = spec;
    in.psf = psf;
    in.srf = srf;
    in.prior = prior;
    in.noise_sigma = sigma;
    return make_decoder(in);
  };

  // ---- distances (on axis, the run's propagator)
  std::vector<ObjectPoint> dpts;
  for (double d : rs.distances) dpts.push_back(ObjectPoint{d, 0, 0});
  const std::vector<RealStack> dpsf = point_psfs(rt, cfg, dpts, h, o.precision, "distance", o.progress);
  res.nominal_index = std::size_t(std::find(rs.distances.begin(), rs.distances.end(), rs.nominal) - rs.distances.begin());
  const std::unique_ptr<Decoder> nominal_dec = decoder_for(dpsf[res.nominal_index]);
  for (std::size_t i = 0; i < rs.distances.size(); ++i) {
    const auto t0 = std::chrono::steady_clock::now();
    DistanceRow row;
    row.distance_m = rs.distances[i];
    const testset::Evaluation mis = testset::evaluate(camera, dpsf[i], patches, *nominal_dec, sigma, ro.design.seed);
    row.mismatch = quality_of(mis);
    if (i == res.nominal_index) {
      row.matched = row.mismatch;  // the same decoder, the same images
    } else {
      const std::unique_ptr<Decoder> dec = decoder_for(dpsf[i]);
      row.matched = quality_of(testset::evaluate(camera, dpsf[i], patches, *dec, sigma, ro.design.seed));
    }
    res.scenes = mis.per_scene.size();
    res.distances.push_back(row);
    if (o.progress) {
      std::printf("[eval-points] distance %zu/%zu  d = %s m  PSNR mismatch %.2f dB  matched %.2f dB  (%.1f s)\n", i + 1,
             rs.distances.size(), metres(row.distance_m).c_str(), row.mismatch.psnr_db.mean, row.matched.psnr_db.mean,
             std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
      std::fflush(stdout);
    }
  }
  res.nominal_psnr_db = res.distances[res.nominal_index].mismatch.psnr_db.mean;
  std::vector<double> mis_psnr;
  for (const DistanceRow& r : res.distances) mis_psnr.push_back(r.mismatch.psnr_db.mean);
  const DepthOfField dof = depth_of_field(rs.distances, mis_psnr, res.nominal_index, o.dof_margin_db);
  res.dof_near_m = dof.near_m;
  res.dof_far_m = dof.far_m;
  res.dof_near_open = dof.near_open;
  res.dof_far_open = dof.far_open;

  // ---- field angles (at the nominal distance, angular spectrum)
  if (res.switched_to_asm && o.progress) {
    std::printf("[eval-points] field angles: the run's Fresnel propagator switched to \"asm\" (the on-axis reference too)\n");
    std::fflush(stdout);
  }
  std::vector<ObjectPoint> apts;
  for (double a : rs.angles) apts.push_back(ObjectPoint{rs.nominal, a, 0});
  const std::vector<RealStack> araw = point_psfs(rt, rs.cfg_asm, apts, h, o.precision, "field-angle", o.progress);
  std::vector<RealStack> apsf;
  std::vector<double> lost(apts.size(), 0.0);
  // The field PSF: the off-axis PSF recentred on its chief ray where the simulated window holds it,
  // and the on-axis PSF in the part the recentring moved in from outside the window (nothing is
  // known there): P_θ = R_θ + (P_0 - M_θ P_0), M_θ the window's support after the shift. The model
  // error then measures the change of shape on the simulated part; energy_lost says how much of
  // the off-axis PSF that part misses.
  for (std::size_t q = 0; q < apts.size(); ++q) {
    RealStack r = recentre_on_chief_ray(araw[q], rs.cfg_asm, apts[q], &lost[q]);
    if (q > 0) {
      const auto off = chief_ray_offset_px(rs.cfg_asm, apts[q]);
      const long dy = std::lround(off.first), dx = std::lround(off.second);
      const RealStack& p0 = apsf[0];
      const RealStack masked = shift_planes(shift_planes(p0, -dy, -dx), dy, dx);  // M_θ P_0
      for (std::size_t t = 0; t < r.data.size(); ++t) r.data[t] += p0.data[t] - masked.data[t];
    }
    apsf.push_back(std::move(r));
  }
  const std::vector<RealStack> i0 = camera.measure(apsf[0], patches);
  double n0 = 0;
  for (const RealStack& y : i0)
    for (double v : y.data) n0 += v * v;
  const std::unique_ptr<Decoder> axis_dec = decoder_for(apsf[0]);
  std::vector<double> errors;
  for (std::size_t q = 0; q < apts.size(); ++q) {
    const auto t0 = std::chrono::steady_clock::now();
    AngleRow row;
    row.angle_deg = rs.angles[q];
    row.energy_lost = lost[q];
    if (q > 0) {
      const std::vector<RealStack> iq = camera.measure(apsf[q], patches);
      double num = 0;
      for (std::size_t k = 0; k < iq.size(); ++k)
        for (std::size_t t = 0; t < iq[k].data.size(); ++t) {
          const double dv = iq[k].data[t] - i0[k].data[t];
          num += dv * dv;
        }
      row.model_error = n0 > 0 ? std::sqrt(num / n0) : 0.0;
    }
    row.on_axis_decoder = quality_of(testset::evaluate(camera, apsf[q], patches, *axis_dec, sigma, ro.design.seed));
    errors.push_back(row.model_error);
    res.angles.push_back(row);
    if (o.progress) {
      std::printf("[eval-points] angle %zu/%zu  %.4g deg  model error %.4g  PSNR %.2f dB  lost %.3g  (%.1f s)\n", q + 1, apts.size(),
             row.angle_deg, row.model_error, row.on_axis_decoder.psnr_db.mean, row.energy_lost,
             std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
      std::fflush(stdout);
    }
  }
  bool exceeded = false;
  res.fov_half_deg = valid_fov_deg(rs.angles, errors, o.fov_tolerance, &exceeded);
  res.fov_full_deg = 2 * res.fov_half_deg;
  res.fov_limited_by = exceeded                                              ? "tolerance"
                       : rs.angles.back() >= rs.edge_deg * (1 - 1e-9)         ? rs.binds
                                                                             : "angles sampled";
  if (o.out.empty()) return res;

  // ---- outputs
  const fs::path out(o.out);
  CsvText csv({"sweep", "distance_m", "angle_deg", "decoder", "psnr_db", "psnr_min_db", "psnr_max_db", "ssim", "ssim_min", "ssim_max",
               "sam_rad", "sam_min_rad", "sam_max_rad", "model_error", "energy_lost"});
  auto qrow = [&](const std::string& sweep, double d, double a, const std::string& dec, const PointQuality& q, const std::string& e,
                  const std::string& l) {
    csv.row({sweep, metres(d), csv_number(a), dec, csv_number(q.psnr_db.mean), csv_number(q.psnr_db.min), csv_number(q.psnr_db.max),
             csv_number(q.ssim.mean), csv_number(q.ssim.min), csv_number(q.ssim.max), csv_number(q.sam_rad.mean),
             csv_number(q.sam_rad.min), csv_number(q.sam_rad.max), e, l});
  };
  for (const DistanceRow& r : res.distances) {
    qrow("distance", r.distance_m, 0, "mismatch", r.mismatch, "", "");
    qrow("distance", r.distance_m, 0, "matched", r.matched, "", "");
  }
  for (const AngleRow& r : res.angles)
    qrow("angle", rs.nominal, r.angle_deg, "on-axis", r.on_axis_decoder, csv_number(r.model_error), csv_number(r.energy_lost));
  write_text_atomic((out / "points.csv").string(), csv.str());

  nlohmann::json j;
  j["run"] = o.run;
  j["design"] = o.design_file.empty() ? folder.design_path() : o.design_file;
  Fnv1a64 hh;
  hh.add(h.data.data(), h.data.size() * sizeof(double));
  j["design_hash"] = hh.hex();
  j["config"] = nlohmann::json::parse(config_to_json_text(cfg));
  j["settings"] = {{"distances_m", nlohmann::json::array()},
                   {"angles_deg", rs.angles},
                   {"fov_tolerance", o.fov_tolerance},
                   {"dof_margin_db", o.dof_margin_db},
                   {"noise_sigma", sigma},
                   {"decoder", res.decoder},
                   {"precision", o.precision == Precision::F64 ? "f64" : "f32"},
                   {"data", o.data},
                   {"synthetic_scenes", o.data.empty() ? o.synthetic_scenes : std::size_t(0)},
                   {"seed", ro.design.seed}};
  for (double d : rs.distances) j["settings"]["distances_m"].push_back(metres_json(d));
  j["test_set"] = {{"patches", res.patches}, {"scenes", res.scenes}};
  j["nominal_distance_m"] = metres_json(rs.nominal);
  nlohmann::json dj = nlohmann::json::array();
  for (const DistanceRow& r : res.distances)
    dj.push_back({{"distance_m", metres_json(r.distance_m)}, {"mismatch", quality_json(r.mismatch)}, {"matched", quality_json(r.matched)}});
  j["distances"] = dj;
  j["depth_of_field"] = {{"margin_db", o.dof_margin_db},
                         {"nominal_psnr_db", res.nominal_psnr_db},
                         {"near_m", metres_json(res.dof_near_m)},
                         {"far_m", metres_json(res.dof_far_m)},
                         {"near_open", res.dof_near_open},
                         {"far_open", res.dof_far_open},
                         {"rule", "mismatch PSNR >= nominal - margin; ends interpolated linearly in 1/d; open: the sweep's end was still within"}};
  nlohmann::json aj = nlohmann::json::array();
  for (const AngleRow& r : res.angles)
    aj.push_back({{"angle_deg", r.angle_deg}, {"model_error", r.model_error}, {"energy_lost", r.energy_lost}, {"on_axis_decoder", quality_json(r.on_axis_decoder)}});
  j["angles"] = aj;
  j["field"] = {{"propagator", "asm"},
                {"switched_from_fresnel", res.switched_to_asm},
                {"window_edge_deg", rs.window_deg},
                {"sampling_edge_deg", rs.sampling_deg},
                {"field_edge_deg", rs.edge_deg},
                {"field_edge_binds", rs.binds},
                {"fov_tolerance", o.fov_tolerance},
                {"fov_half_deg", res.fov_half_deg},
                {"fov_full_deg", res.fov_full_deg},
                {"fov_limited_by", res.fov_limited_by},
                {"model_error", "||I_theta - I_0|| / ||I_0||, noiseless RGB images of every patch, I_0 through the on-axis PSF "
                                "(the shift-invariant model), I_theta through the off-axis PSF recentred on its chief ray, the part the shift "
                                "brings in from outside the simulated window taken from the on-axis PSF (energy_lost: the "
                                "fraction of the off-axis PSF outside the window)"}};
  j["conventions"] = {{"psnr_db", "whole cube, peak 1 (qdo eval's)"},
                      {"ssim", "qdo eval's"},
                      {"sam_rad", "mean spectral angle, radians"},
                      {"spread", "min and max over the per-scene means"},
                      {"imaging", "qdo eval's: circular per-band convolution on the S x S patch grid, Gaussian noise sigma per patch, "
                                  "output clipped to [0, 1]"}};
  write_text_atomic((out / "points.json").string(), j.dump(2) + "\n");

  write_points_figures(out, res, o, cfg, dpsf, apsf);
  return res;
}

}  // namespace qdo
