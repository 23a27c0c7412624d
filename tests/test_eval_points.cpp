// qdo eval-points (eval_points.hpp): a design against object distance and field angle.
//   - closed forms: a thin lens focused at 1 m is best matched there and degrades monotonically away
//     from it without a refit; e(0) = 0 exactly; e grows with the angle for a DOE; the valid FOV lies
//     between the last sample within the tolerance and the first beyond;
//   - the per-distance numbers equal qdo eval's (evaluate_run) for a run configured at that distance;
//   - refusals name the value and the limit, before any work; outputs exist and parse.
#include <doctest/doctest.h>

#include <nlohmann/json.hpp>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>

#include "common.hpp"
#include "qdo/design/design_run.hpp"
#include "qdo/evaluate/eval.hpp"
#include "qdo/evaluate/eval_points.hpp"
#include "qdo/data/io.hpp"
#include "qdo/data/materials.hpp"

using namespace qdo;
using namespace qdo::test;
namespace fs = std::filesystem;

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

// 3 bands around 550 nm, N = 128 at 8 µm (aperture radius ~0.5 mm), z = 30 mm, sensor 8 µm
// (S = 128): a thin lens focused at 1 m blurs by ~30 µm (4 px) at infinity and ~70 µm at 0.3 m.
SystemConfig points_config() {
  SystemConfig c = preset_config("small");
  c.n = 128;
  c.padding_px = 32;
  c.pitch_m = 8e-6;
  c.sensor_pitch_m = 8e-6;
  c.bands = 3;
  c.wavelength_start_nm = 530;
  c.wavelength_step_nm = 20;
  c.sensor_distance_m = 0.03;
  c.scene_distance_m = 1.0;
  c.srf_interpolate = true;
  c.validate();
  return c;
}

// The exact thin lens at 550 nm imaging a point at d_m onto the sensor at z: the phase cancels the
// point's spherical wave and converges it to the axis at z, wrapped to one 2π of height.
Map2D lens_at(const SystemConfig& c, double d_m) {
  const double wl = 550, k = 2 * M_PI / (wl * 1e-9), z = c.sensor_distance_m;
  const double nm1 = material_by_name(c.material).index(wl) - 1;
  Map2D h(c.n, c.n);
  for (std::size_t i = 0; i < c.n; ++i)
    for (std::size_t j = 0; j < c.n; ++j) {
      const double y = (double(i) - double(c.n / 2)) * c.pitch_m, x = (double(j) - double(c.n / 2)) * c.pitch_m;
      const double r2 = x * x + y * y;
      double phi = std::fmod(-k * (r2 / (std::sqrt(r2 + d_m * d_m) + d_m) + r2 / (std::sqrt(r2 + z * z) + z)), 2 * M_PI);
      if (phi < 0) phi += 2 * M_PI;
      h(i, j) = phi / (k * nm1);
    }
  return h;
}

// A Wiener run of points_config (2 steps): its prior, config and a DOE design.
const std::string& points_run() {
  static const std::string run = [] {
    const auto dir = temp_dir("eval_points_run");
    DesignRunOptions o;
    o.cfg = points_config();
    o.design.mode = DesignMode::DO;
    o.design.quantizer.levels = 4;
    o.design.steps_per_epoch = 1;
    o.design.t0_epochs = 0.5;
    o.design.t1_epochs = 1;
    o.design.seed = 5;
    o.epochs = 2;
    o.synthetic_scenes = 2;
    o.precision = Precision::F32;
    o.out = (dir / "run").string();
    o.quiet = true;
    run_design(runtime(), o, false);
    return o.out;
  }();
  return run;
}

EvalPointsOptions base_options() {
  EvalPointsOptions o;
  o.run = points_run();
  o.synthetic_scenes = 2;
  o.progress = false;
  return o;
}

std::string lens_file(const fs::path& dir) {
  const SystemConfig c = points_config();
  Design d;
  d.height_m = lens_at(c, 1.0);
  d.pitch_m = c.pitch_m;
  const std::string path = (dir / "lens.h5").string();
  write_design(path, d);
  return path;
}

}  // namespace

TEST_SUITE("eval-points") {
  TEST_CASE("the valid field of view and the depth of field from sampled curves") {
    bool exceeded = true;
    CHECK(valid_fov_deg({0, 1, 2}, {0, 0.01, 0.02}, 0.05, &exceeded) == 2);
    CHECK_FALSE(exceeded);
    // crosses 0.05 between 1 (0.04) and 2 (0.08): at 1.25
    CHECK(valid_fov_deg({0, 1, 2, 3}, {0, 0.04, 0.08, 0.01}, 0.05, &exceeded) == doctest::Approx(1.25).epsilon(1e-12));
    CHECK(exceeded);
    CHECK(input_error_of([] { valid_fov_deg({0, 2, 1}, {0, 0, 0}, 0.1); }).find("ascending") != std::string::npos);
    // 1/d: 2, 1, 0.5, 0 (inf); nominal 1 m at 30 dB, margin 1 dB.
    const DepthOfField a = depth_of_field({0.5, 1, 2, kInf}, {28, 30, 29.5, 29}, 1, 1.0);
    CHECK(a.near_m == doctest::Approx(1.0 / 1.5).epsilon(1e-12));  // 29 dB halfway between 1/d = 1 and 2
    CHECK_FALSE(a.near_open);
    CHECK(std::isinf(a.far_m));  // still within at infinity: nothing lies beyond
    CHECK_FALSE(a.far_open);
    const DepthOfField b = depth_of_field({0.5, 1, 2}, {29.5, 30, 27}, 1, 1.0);
    CHECK(b.near_m == 0.5);
    CHECK(b.near_open);
    CHECK(b.far_m == doctest::Approx(1.0 / (1.0 - 0.5 / 3.0)).epsilon(1e-12));
  }

  TEST_CASE("a thin lens focused at 1 m: matched best at 1 m, mismatch falling on both sides; e(0) = 0; the outputs parse") {
    const auto dir = temp_dir("eval_points_lens");
    EvalPointsOptions o = base_options();
    o.design_file = lens_file(dir);
    o.distances_m = {0.3, 0.5, 0.7, 1, 1.5, 3, kInf};
    o.angle_steps = 4;
    o.out = (dir / "out").string();
    const EvalPointsResult r = evaluate_points(runtime(), o);
    REQUIRE(r.distances.size() == 7);
    REQUIRE(r.nominal_index == 3);
    CHECK(r.distances[3].distance_m == 1.0);
    CHECK(r.distances[3].matched.psnr_db.mean == r.distances[3].mismatch.psnr_db.mean);
    for (std::size_t i = 0; i < r.distances.size(); ++i) {
      CAPTURE(i);
      CAPTURE(r.distances[i].mismatch.psnr_db.mean);
      CAPTURE(r.distances[i].matched.psnr_db.mean);
      if (i != 3) CHECK(r.distances[i].matched.psnr_db.mean < r.distances[3].matched.psnr_db.mean);
      CHECK(r.distances[i].mismatch.psnr_db.min <= r.distances[i].mismatch.psnr_db.mean);
      CHECK(r.distances[i].mismatch.psnr_db.max >= r.distances[i].mismatch.psnr_db.mean);
    }
    for (std::size_t i = 0; i < 3; ++i) CHECK(r.distances[i].mismatch.psnr_db.mean < r.distances[i + 1].mismatch.psnr_db.mean);
    for (std::size_t i = 3; i + 1 < r.distances.size(); ++i)
      CHECK(r.distances[i + 1].mismatch.psnr_db.mean < r.distances[i].mismatch.psnr_db.mean);
    CHECK(r.dof_near_m < 1.0);
    CHECK(r.dof_far_m > 1.0);

    REQUIRE(r.angles.size() == 5);
    CHECK(r.angles[0].angle_deg == 0);
    CHECK(r.angles[0].model_error == 0.0);  // exactly: the same PSF
    CHECK(r.angles.back().angle_deg == doctest::Approx(r.field_edge_deg).epsilon(1e-12));
    CHECK(r.switched_to_asm);
    CHECK(r.field_edge_deg <= r.window_edge_deg);
    CHECK(r.field_edge_deg <= r.sampling_edge_deg);
    CHECK(r.fov_full_deg == 2 * r.fov_half_deg);

    // outputs exist and parse
    for (const char* f : {"points.json", "points.csv", "quality_vs_distance.png", "quality_vs_angle.png", "psf_vs_distance.png",
                          "psf_vs_angle.png"})
      CHECK(fs::file_size(fs::path(o.out) / f) > 0);
    const nlohmann::json j = nlohmann::json::parse(slurp(fs::path(o.out) / "points.json"));
    CHECK(j.at("distances").size() == 7);
    CHECK(j.at("distances").back().at("distance_m") == "inf");
    CHECK(j.at("angles").size() == 5);
    CHECK(j.at("field").at("fov_half_deg").get<double>() == r.fov_half_deg);
    CHECK(j.at("depth_of_field").at("nominal_psnr_db").get<double>() == r.nominal_psnr_db);
    const CsvTable csv = read_csv((fs::path(o.out) / "points.csv").string());
    CHECK(csv.column("psnr_db").size() == 7 * 2 + 5);
    fs::remove_all(dir);
  }

  TEST_CASE("a DOE is not shift-invariant: e grows with the angle, and the FOV lies between the samples around the tolerance") {
    EvalPointsOptions o = base_options();
    o.distances_m = {1};
    o.angle_steps = 4;
    const EvalPointsResult r = evaluate_points(runtime(), o);
    REQUIRE(r.angles.size() == 5);
    CHECK(r.angles[0].model_error == 0.0);
    for (std::size_t q = 1; q < r.angles.size(); ++q) {
      CAPTURE(q);
      CAPTURE(r.angles[q].model_error);
      CHECK(r.angles[q].model_error > r.angles[q - 1].model_error);
    }
    // A tolerance between the second and third samples' errors: the FOV lies between their angles.
    o.fov_tolerance = 0.5 * (r.angles[2].model_error + r.angles[3].model_error);
    const EvalPointsResult t = evaluate_points(runtime(), o);
    CHECK(t.fov_limited_by == "tolerance");
    CHECK(t.fov_half_deg > t.angles[2].angle_deg);
    CHECK(t.fov_half_deg < t.angles[3].angle_deg);
    // A tolerance above every error: the field edge limits it, and says which edge.
    o.fov_tolerance = 10;
    const EvalPointsResult u = evaluate_points(runtime(), o);
    CHECK(u.fov_half_deg == doctest::Approx(u.field_edge_deg).epsilon(1e-12));
    CHECK(u.fov_limited_by == u.field_edge_binds);
  }

  TEST_CASE("the per-distance numbers are qdo eval's for the run configured at that distance") {
    EvalPointsOptions o = base_options();
    o.distances_m = {0.5, kInf};
    o.angles_deg = {0};
    const EvalPointsResult r = evaluate_points(runtime(), o);
    REQUIRE(r.distances.size() == 3);  // with the nominal 1 m
    const auto dir = temp_dir("eval_points_eval");
    for (std::size_t i = 0; i < r.distances.size(); ++i) {
      CAPTURE(i);
      // a copy of the run whose configuration puts the scene at this distance
      const fs::path run = dir / ("run_" + std::to_string(i));
      fs::create_directories(run);
      for (const auto& e : fs::directory_iterator(o.run))
        if (e.is_regular_file()) fs::copy_file(e.path(), run / e.path().filename());
      nlohmann::json cj = nlohmann::json::parse(slurp(run / "config.json"));
      nlohmann::json& sys = cj.contains("system") ? cj["system"] : cj;
      if (std::isinf(r.distances[i].distance_m))
        sys["scene_distance_m"] = "inf";
      else
        sys["scene_distance_m"] = r.distances[i].distance_m;
      std::ofstream(run / "config.json") << cj.dump(2);
      EvalOptions e;
      e.run = run.string();
      e.synthetic_scenes = 2;
      e.renders = 0;
      e.out = (dir / ("eval_" + std::to_string(i))).string();
      const EvalResult ev = evaluate_run(runtime(), e);
      CHECK(ev.mean.psnr == r.distances[i].matched.psnr_db.mean);
      CHECK(ev.mean.ssim == r.distances[i].matched.ssim.mean);
      CHECK(ev.mean.sam_rad == r.distances[i].matched.sam_rad.mean);
    }
    fs::remove_all(dir);
  }

  TEST_CASE("the nominal distance: a run's one object point, or --nominal; the points themselves are dropped") {
    EvalPointsOptions o = base_options();
    o.distances_m = {0.5, 2};
    o.angles_deg = {0, 0.3};
    o.nominal_m = 2;
    const EvalPointsResult a = evaluate_points(runtime(), o);
    CHECK(a.nominal_distance_m == 2.0);
    REQUIRE(a.distances.size() == 2);  // 0.5, 2: the run's scene distance (1 m) is not the nominal, not added
    CHECK(a.distances[a.nominal_index].distance_m == 2.0);
    // the same run trained for one object point at 2 m: that point is the nominal
    const auto dir = temp_dir("eval_points_nominal");
    const fs::path run = dir / "run";
    fs::create_directories(run);
    for (const auto& e : fs::directory_iterator(base_options().run))
      if (e.is_regular_file()) fs::copy_file(e.path(), run / e.path().filename());
    nlohmann::json cj = nlohmann::json::parse(slurp(run / "config.json"));
    cj["system"]["object_points"] = nlohmann::json::array({nlohmann::json::array({2, 0, 0})});
    std::ofstream(run / "config.json") << cj.dump(2);
    o.run = run.string();
    o.nominal_m = std::numeric_limits<double>::quiet_NaN();
    const EvalPointsResult b = evaluate_points(runtime(), o);
    CHECK(b.nominal_distance_m == 2.0);
    REQUIRE(b.distances.size() == a.distances.size());
    for (std::size_t i = 0; i < a.distances.size(); ++i) {
      CHECK(b.distances[i].mismatch.psnr_db.mean == a.distances[i].mismatch.psnr_db.mean);
      CHECK(b.distances[i].matched.psnr_db.mean == a.distances[i].matched.psnr_db.mean);
    }
    // the mismatch decoder is the one for 2 m: at 0.5 m it differs from the matched one
    CHECK(a.distances[0].mismatch.psnr_db.mean != a.distances[0].matched.psnr_db.mean);
    REQUIRE(b.angles.size() == 2);
    CHECK(b.angles[1].model_error == a.angles[1].model_error);
    CHECK(b.angles[1].model_error > 0);
    fs::remove_all(dir);
  }

  TEST_CASE("refusals name the value and the limit, before any output") {
    const auto dir = temp_dir("eval_points_refuse");
    EvalPointsOptions o = base_options();
    o.out = (dir / "out").string();
    o.distances_m = {0.5, -1};
    CHECK(input_error_of([&] { check_eval_points(o); }).find("'distances' = -1") != std::string::npos);
    o.distances_m = {0.5, 0.5};
    CHECK(input_error_of([&] { check_eval_points(o); }).find("distinct") != std::string::npos);
    o.distances_m = {};
    o.angles_deg = {0, 80};
    const std::string msg = input_error_of([&] { evaluate_points(runtime(), o); });
    CHECK(msg.find("'angles' = 80") != std::string::npos);
    CHECK(msg.find("sampling limit") != std::string::npos);
    CHECK_FALSE(fs::exists(o.out));  // refused before the folder was made
    o.angles_deg = {};
    o.fov_tolerance = 0;
    CHECK(input_error_of([&] { check_eval_points(o); }).find("fov-tolerance") != std::string::npos);

    // The command: exit 2, naming the value; no folder left.
    const std::string out = (dir / "cli").string();
    Run r = qdo_run("eval-points " + o.run + " --angles 0,80 --out " + out, "QDO_DEVICE=cpu");
    CHECK(r.code == 2);
    CHECK(r.out.find("80") != std::string::npos);
    CHECK(r.out.find("sampling limit") != std::string::npos);
    CHECK_FALSE(fs::exists(out));
    r = qdo_run("eval-points " + o.run + " --distances 0.5,0 --out " + out, "QDO_DEVICE=cpu");
    CHECK(r.code == 2);
    CHECK(r.out.find("--distances") != std::string::npos);
    CHECK_FALSE(fs::exists(out));
    r = qdo_run("eval-points " + o.run + " --fov-tolerance -1 --out " + out, "QDO_DEVICE=cpu");
    CHECK(r.code == 2);
    CHECK(r.out.find("--fov-tolerance") != std::string::npos);
    // an --out it did not make is refused
    fs::create_directories(dir / "user");
    std::ofstream(dir / "user" / "keep.txt") << "mine";
    r = qdo_run("eval-points " + o.run + " --distances 1 --angles 0 --out " + (dir / "user").string(), "QDO_DEVICE=cpu");
    CHECK(r.code == 2);
    CHECK(slurp(dir / "user" / "keep.txt") == "mine");
    fs::remove_all(dir);
  }
}
