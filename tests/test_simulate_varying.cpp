// qdo simulate with a depth map (--depth) or a field-dependent PSF (--field-grid) (suite
// `simulate-varying`; src/asbuilt/simulate_varying.cpp): the command run as a user would, its sensor
// image against plain `qdo simulate` and against the library (Simulator + ref::varying_images in
// double), the skipping of unused depth layers and of field points off the crop, and the refusals.
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "common.hpp"
#include "qdo/data/config.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/data/io.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/point_psf.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/physics/varying.hpp"
#include "qdo/physics/varying_reference.hpp"

using namespace qdo;
using namespace qdo::test;
namespace fs = std::filesystem;

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

struct Removed {
  fs::path dir;
  ~Removed() {
    std::error_code ec;
    fs::remove_all(dir, ec);
  }
};

// The tiny system (N = 32, 3 bands, S = 16), noiseless unless told.
SystemConfig depth_config(double scene_distance_m = 1.0) {
  SystemConfig c = tiny_config(32, 3);
  c.read_noise_sigma = 0;
  c.full_well_photons = 0;
  c.scene_distance_m = scene_distance_m;
  c.validate();
  return c;
}

// N = 64, 4 bands, S = 16 (16 um pixels), angular spectrum: off-axis field points up to ~2.3 deg.
SystemConfig field_config() {
  SystemConfig c = tiny_config(64, 4);
  c.sensor_pitch_m = 16e-6;
  c.propagator = Propagator::AngularSpectrum;
  c.read_noise_sigma = 0;
  c.full_well_photons = 0;
  c.validate();
  return c;
}

std::string write_config(const fs::path& dir, const std::string& name, const SystemConfig& c) {
  const fs::path p = dir / name;
  std::ofstream(p) << config_to_json_text(c) << "\n";
  return p.string();
}

std::string write_scene(const fs::path& dir, const SystemConfig& c, std::size_t h, std::size_t w, unsigned seed) {
  const fs::path p = dir / "scene.h5";
  write_cube(p.string(), random_cube(c.bands, h, w, seed), c.wavelengths_nm());
  return p.string();
}

std::string write_depth(const fs::path& dir, const std::string& name, const Map2D& d, const std::string& key = "/depth_m") {
  const fs::path p = dir / name;
  h5_write_unchecked(p.string(), {{key, {d.rows, d.cols}, d.data, {}, {{"units", "m"}}}});
  return p.string();
}

RealStack read_rgb(const fs::path& out) {
  const H5Dataset d = h5_read((out / "sensor.h5").string(), "/rgb");
  REQUIRE(d.shape.size() == 3);
  RealStack s(d.shape[0], d.shape[1], d.shape[2]);
  s.data = d.data;
  return s;
}


nlohmann::json read_json(const fs::path& p) {
  std::ifstream f(p);
  return nlohmann::json::parse(f);
}

// Mean |a - b| over the rows y0 .. y0+n-1, columns x0 .. x0+n-1 of every plane.
double window_diff(const RealStack& a, const RealStack& b, std::size_t y0, std::size_t x0, std::size_t n) {
  double s = 0;
  for (std::size_t c = 0; c < a.planes; ++c)
    for (std::size_t y = y0; y < y0 + n; ++y)
      for (std::size_t x = x0; x < x0 + n; ++x) s += std::fabs(a(c, y, x) - b(c, y, x));
  return s / double(a.planes * n * n);
}

// A refused command: exit 2, nothing written, the message holding every one of `want`.
void check_refused(const std::string& args, const fs::path& out, const std::vector<std::string>& want) {
  CAPTURE(args);
  const Run r = qdo_run(args + " --out " + out.string(), "QDO_DEVICE=cpu");
  CAPTURE(r.out);
  CHECK(r.code == 2);
  for (const std::string& w : want) CHECK_MESSAGE(r.out.find(w) != std::string::npos, "missing: " << w);
  CHECK(!fs::exists(out));
}

}  // namespace

TEST_SUITE("simulate-varying") {
  TEST_CASE("--depth at one depth equals plain qdo simulate at that scene_distance_m; HDF5 and 16-bit PNG depth maps agree") {
    const fs::path dir = temp_dir("simvar1");
    const Removed removed{dir};
    const double d = 0.02;
    const std::string cfg_near = write_config(dir, "near.json", depth_config(d));
    const std::string cfg_far = write_config(dir, "far.json", depth_config(1.0));
    const std::size_t h = 20, w = 24;
    const std::string scene = write_scene(dir, depth_config(), h, w, 7);
    const std::string depth = write_depth(dir, "depth.h5", Map2D(h, w, d));
    // One design for both (lens:550 focuses at the configuration's scene_distance_m, which differs).
    Design lens;
    lens.height_m = lens_design(depth_config(1.0), 550);
    lens.pitch_m = depth_config().pitch_m;
    const std::string design = (dir / "lens.h5").string();
    write_design(design, lens);
    Run r = qdo_run("simulate --config " + cfg_near + " --design " + design + " --scene " + scene + " --out " + (dir / "plain").string(),
                    "QDO_DEVICE=cpu");
    REQUIRE_MESSAGE(r.code == 0, r.out);
    // The far configuration's own scene distance does not enter: the depth map's does.
    r = qdo_run("simulate --config " + cfg_far + " --design " + design + " --scene " + scene + " --depth " + depth + " --out " +
                    (dir / "depth").string(),
                "QDO_DEVICE=cpu");
    REQUIRE_MESSAGE(r.code == 0, r.out);
    CHECK(r.out.find("1 of 1 used") != std::string::npos);
    const RealStack plain = read_rgb(dir / "plain"), one = read_rgb(dir / "depth");
    REQUIRE(plain.size() == one.size());
    const double top = max_abs(plain.data);
    CHECK(top > 0.05);
    CHECK(max_abs_diff(plain.data, one.data) <= 1e-5 * top);  // float32 rounding of two FFT paths
    for (const char* f : {"sensor.png", "scene.png", "psf.png", "psf_points.h5", "design.png", "depth.png", "varying.json"})
      CHECK_MESSAGE(fs::exists(dir / "depth" / f), f);
    // The same depth as a 16-bit PNG (20 codes of 1 mm).
    Map2D codes(h, w, 20.0);
    write_png16_gray((dir / "depth.png").string(), codes);
    r = qdo_run("simulate --config " + cfg_far + " --design " + design + " --scene " + scene + " --depth " + (dir / "depth.png").string() +
                    " --depth-scale 0.001 --out " + (dir / "png").string(),
                "QDO_DEVICE=cpu");
    REQUIRE_MESSAGE(r.code == 0, r.out);
    // The same computation in another process: equal to the rounding of the FFT plans, which
    // FFTW_MEASURE may choose differently while two CTest entries fill a cold wisdom cache.
    CHECK(max_abs_diff(read_rgb(dir / "png").data, one.data) <= 1e-6 * top);
    // The configuration's noise is added as the camera adds it (Gaussian read noise, same counters).
    SystemConfig noisy = depth_config(d);
    noisy.read_noise_sigma = 0.01;
    noisy.noise_seed = 5;
    const std::string cfg_noisy = write_config(dir, "noisy.json", noisy);
    r = qdo_run("simulate --config " + cfg_noisy + " --design " + design + " --scene " + scene + " --out " + (dir / "plain_noisy").string(),
                "QDO_DEVICE=cpu");
    REQUIRE_MESSAGE(r.code == 0, r.out);
    r = qdo_run("simulate --config " + cfg_noisy + " --design " + design + " --scene " + scene + " --depth " + depth + " --out " +
                    (dir / "depth_noisy").string(),
                "QDO_DEVICE=cpu");
    REQUIRE_MESSAGE(r.code == 0, r.out);
    CHECK(r.out.find("noise: the configuration's") != std::string::npos);
    const RealStack pn = read_rgb(dir / "plain_noisy"), dn = read_rgb(dir / "depth_noisy");
    CHECK(max_abs_diff(pn.data, plain.data) > 0.005);  // the noise is there
    CHECK(max_abs_diff(pn.data, dn.data) <= 1e-4 * top);
  }

  TEST_CASE("two depths: the image is the library's (Simulator PSFs, ref::varying_images in double) in both placements; unused layers skipped") {
    const fs::path dir = temp_dir("simvar2");
    const Removed removed{dir};
    const SystemConfig cfg = depth_config();
    const std::string cfg_file = write_config(dir, "cfg.json", cfg);
    const std::size_t h = 22, w = 26;
    const std::string scene = write_scene(dir, cfg, h, w, 11);
    // Left: 5 mm (out of focus for z = 1.56 mm), right: infinity.
    Map2D depth(h, w);
    for (std::size_t y = 0; y < h; ++y)
      for (std::size_t x = 0; x < w; ++x) depth(y, x) = x < 11 ? 0.005 : kInf;
    const std::string depth_file = write_depth(dir, "depth.h5", depth, "/d");
    const std::string base = "simulate --config " + cfg_file + " --design lens:550 --scene " + scene + " --depth " + depth_file +
                             ":/d --depth-layers 0.005,0.02,inf";
    // The library: PSFs at the two used layers, the one-hot weights, the double reference.
    SystemConfig two = cfg;
    two.object_points = {ObjectPoint{0.005, 0, 0}, ObjectPoint{kInf, 0, 0}};
    two.validate();
    const Precision p = runtime().has_fp64() ? Precision::F64 : Precision::F32;
    Simulator sim(runtime(), two, p);
    sim.set_heights(lens_design(cfg, 550));
    sim.compute_psf();
    const RealStack psfs = sim.psf_sensor();
    REQUIRE(psfs.planes == 2 * cfg.bands);
    CHECK(max_abs_diff(point_planes(psfs, 0, cfg.bands).data, point_planes(psfs, 1, cfg.bands).data) > 1e-3);
    const RealStack wts = depth_layer_weights(depth, {0.005, kInf}, h, w);
    RealStack cube(cfg.bands, h, w);
    cube.data = h5_read(scene, "/cube").data;
    const Eigen::MatrixXd srf = sensor_response(cfg);
    RealStack img[2];
    const PsfPlacement placements[2] = {PsfPlacement::Source, PsfPlacement::Output};
    for (int i = 0; i < 2; ++i) {
      const std::string pl = to_string(placements[i]);
      CAPTURE(pl);
      const fs::path out = dir / pl;
      const Run r = qdo_run(base + " --psf-placement " + pl + " --out " + out.string(), "QDO_DEVICE=cpu");
      REQUIRE_MESSAGE(r.code == 0, r.out);
      CHECK(r.out.find("2 of 3 used") != std::string::npos);
      CHECK(r.out.find("skipped (no pixel at that depth): 0.02 m") != std::string::npos);
      img[i] = read_rgb(out);
      const RealStack want = ref::varying_images(cube, psfs, wts, srf, placements[i]);
      const double top = max_abs(want.data);
      CHECK(top > 0.05);
      CHECK(max_abs_diff(img[i].data, want.data) <= 1e-5 * top);
      const nlohmann::json v = read_json(out / "varying.json");
      CHECK(v.at("mode") == "depth");
      CHECK(v.at("computed") == nlohmann::json({0, 2}));
      CHECK(v.at("skipped") == nlohmann::json({1}));
      CHECK(v.at("layers").at(1).at("distance_m") == "0.02");
      CHECK(v.at("layers").at(1).at("pixels") == 0);
      CHECK(v.at("layers").at(2).at("distance_m") == "inf");
      CHECK(v.at("layers").at(0).at("pixels") == h * 11);
      CHECK(v.at("report").at("components") == 2);
      CHECK(v.at("report").at("placement") == pl);
      const H5Dataset ps = h5_read((out / "psf_points.h5").string(), "/psf_sensor");
      CHECK(ps.shape[0] == 2 * cfg.bands);
    }
    // The placements differ at the depth edge only.
    CHECK(max_abs_diff(img[0].data, img[1].data) > 1e-3);
    CHECK(window_diff(img[0], img[1], 0, 0, 3) < 1e-6);  // columns 0 .. 2: beyond the reach (8 px) of the edge at column 11
    // Default layers: the map's two distinct values, nothing skipped.
    const Run r = qdo_run("simulate --config " + cfg_file + " --design lens:550 --scene " + scene + " --depth " + depth_file +
                              ":/d --out " + (dir / "default").string(),
                          "QDO_DEVICE=cpu");
    REQUIRE_MESSAGE(r.code == 0, r.out);
    CHECK(r.out.find("the depth map's 2 distinct values") != std::string::npos);
    // Another process (see the PNG depth above): equal to the FFT plans' rounding.
    CHECK(max_abs_diff(read_rgb(dir / "default").data, img[0].data) <= 1e-6 * max_abs(img[0].data));
    // Many distinct values (a ramp from 0.01 m to 0.1 m): 8 layers evenly spaced in diopters, near to far.
    Map2D ramp(h, w);
    for (std::size_t y = 0; y < h; ++y)
      for (std::size_t x = 0; x < w; ++x) ramp(y, x) = 0.01 + 0.09 * double(x) / double(w - 1);
    const Run rr = qdo_run("simulate --config " + cfg_file + " --design lens:550 --scene " + scene + " --depth " +
                               write_depth(dir, "ramp.h5", ramp) + " --out " + (dir / "ramp").string(),
                           "QDO_DEVICE=cpu");
    REQUIRE_MESSAGE(rr.code == 0, rr.out);
    CHECK(rr.out.find("8 layers evenly spaced in diopters between the map's nearest (0.01 m) and farthest (0.1 m)") != std::string::npos);
    const nlohmann::json vr = read_json(dir / "ramp" / "varying.json");
    REQUIRE(vr.at("layers").size() == 8);
    for (std::size_t k = 0; k < 8; ++k)
      CHECK(vr.at("layers").at(k).at("diopters").get<double>() == doctest::Approx(100.0 - 90.0 * double(k) / 7.0));
  }

  TEST_CASE("--depth builtin: the built-in chart's layered depth (patch rows at 4z .. 32z, background at infinity); depth.h5 read back") {
    const fs::path dir = temp_dir("simvar5");
    const Removed removed{dir};
    SystemConfig cfg = depth_config();
    cfg.scene_size_px = 40;
    const std::string cfg_file = write_config(dir, "cfg.json", cfg);
    const std::string base = "simulate --config " + cfg_file + " --design lens:550";
    Run r = qdo_run(base + " --depth builtin --out " + (dir / "a").string(), "QDO_DEVICE=cpu");
    REQUIRE_MESSAGE(r.code == 0, r.out);
    CHECK(r.out.find("5 of 5 used") != std::string::npos);
    const nlohmann::json v = read_json(dir / "a" / "varying.json");
    CHECK(v.at("layers").at(0).at("distance_m").get<std::string>() == to_str(4 * cfg.sensor_distance_m));
    CHECK(v.at("layers").at(3).at("distance_m").get<std::string>() == to_str(32 * cfg.sensor_distance_m));
    CHECK(v.at("layers").at(4).at("distance_m") == "inf");
    const H5Dataset inv = h5_read((dir / "a" / "depth.h5").string(), "/inverse_depth_per_m");
    REQUIRE(inv.shape == std::vector<std::size_t>{40, 40});
    CHECK(inv.data[0] == 0.0);  // the background corner is at infinity
    // Unused --depth-layers are skipped; the map written is read back (diopters) to the same image.
    r = qdo_run(base + " --depth " + (dir / "a" / "depth.h5").string() + ":/inverse_depth_per_m --out " + (dir / "b").string(),
                "QDO_DEVICE=cpu");
    REQUIRE_MESSAGE(r.code == 0, r.out);
    CHECK(max_abs_diff(read_rgb(dir / "b").data, read_rgb(dir / "a").data) <= 1e-6);
    // Not for a scene file.
    const std::string scene = write_scene(dir, cfg, 40, 40, 5);
    check_refused(base + " --scene " + scene + " --depth builtin", dir / "c", {"--depth", "built-in chart"});
  }

  TEST_CASE("--field-grid: 1 point is the plain image; 3 x 3 differs from it near the corners more than at the centre; points off the crop skipped") {
    const fs::path dir = temp_dir("simvar3");
    const Removed removed{dir};
    const SystemConfig cfg = field_config();
    const std::string cfg_file = write_config(dir, "cfg.json", cfg);
    const std::size_t n = 32;
    // Five point sources: the centre and one near each corner (a random scene would show the
    // integer recentring of every PSF as large differences everywhere).
    const std::vector<std::pair<std::size_t, std::size_t>> dots{{16, 16}, {3, 3}, {3, 28}, {28, 3}, {28, 28}};
    RealStack dotted(cfg.bands, n, n);
    for (const auto& [y, x] : dots)
      for (std::size_t b = 0; b < cfg.bands; ++b) dotted(b, y, x) = 1.0;
    const std::string scene = (dir / "dots.h5").string();
    write_cube(scene, dotted, cfg.wavelengths_nm());
    const std::string base = "simulate --config " + cfg_file + " --design lens:550 --scene " + scene;
    Run r = qdo_run(base + " --out " + (dir / "plain").string(), "QDO_DEVICE=cpu");
    REQUIRE_MESSAGE(r.code == 0, r.out);
    const RealStack plain = read_rgb(dir / "plain");
    const double top = max_abs(plain.data);
    r = qdo_run(base + " --field-grid 1 --out " + (dir / "g1").string(), "QDO_DEVICE=cpu");
    REQUIRE_MESSAGE(r.code == 0, r.out);
    CHECK(max_abs_diff(read_rgb(dir / "g1").data, plain.data) <= 1e-5 * top);
    r = qdo_run(base + " --field-grid 3 --out " + (dir / "g3").string(), "QDO_DEVICE=cpu");
    REQUIRE_MESSAGE(r.code == 0, r.out);
    CHECK(r.out.find("9 of 9 points computed") != std::string::npos);
    const RealStack g3 = read_rgb(dir / "g3");
    const double limit = max_field_angle_deg(cfg, kInf);
    const nlohmann::json v = read_json(dir / "g3" / "varying.json");
    // The scene (16 px from the axis) reaches beyond half the window's half-width (4 px): the default edge stops there.
    const double half_window = std::atan(0.25 * double(cfg.n) * cfg.pitch_m / cfg.sensor_distance_m) * 180.0 / M_PI;
    REQUIRE(half_window < limit);
    CHECK(v.at("edge_deg").at(0).get<double>() == doctest::Approx(half_window));
    CHECK(v.at("points").at(0).at("image_col_px").get<double>() == doctest::Approx(4.0));
    CHECK(v.at("points").size() == 9);
    CHECK(v.at("points").at(0).at("shift_px").at(0).get<long>() != 0);
    // 7 x 7 windows around the dots: the centre dot weighs the on-axis PSF alone.
    const double centre = window_diff(g3, plain, 13, 13, 7);
    double corners = 0;
    for (std::size_t i = 1; i < dots.size(); ++i) corners += window_diff(g3, plain, dots[i].first - 3, dots[i].second - 3, 7) / 4;
    MESSAGE("3 x 3 field grid: mean |varying - plain| corners " << corners << ", centre " << centre);
    CHECK(corners > 1e-4);
    CHECK(corners > 100 * centre);
    // Full rank reproduces the 9-point image; rank 1 differs.
    r = qdo_run(base + " --field-grid 3 --field-rank 9 --out " + (dir / "r9").string(), "QDO_DEVICE=cpu");
    REQUIRE_MESSAGE(r.code == 0, r.out);
    CHECK(max_abs_diff(read_rgb(dir / "r9").data, g3.data) <= 1e-4 * top);
    CHECK(read_json(dir / "r9" / "varying.json").at("truncation_error").get<double>() < 1e-6);
    r = qdo_run(base + " --field-grid 3 --field-rank 1 --out " + (dir / "r1").string(), "QDO_DEVICE=cpu");
    REQUIRE_MESSAGE(r.code == 0, r.out);
    CHECK(read_json(dir / "r1" / "varying.json").at("truncation_error").get<double>() > 1e-3);
    // A 6 x 6 crop with a 5 x 5 grid reaching 7 px: the outer ring's hats miss the crop.
    const double edge = std::atan(7.0 * cfg.sensor_pitch_m / cfg.sensor_distance_m) * 180.0 / M_PI;
    REQUIRE(edge < limit);
    write_cube((dir / "crop.h5").string(), random_cube(cfg.bands, 6, 6, 17), cfg.wavelengths_nm());
    r = qdo_run("simulate --config " + cfg_file + " --design lens:550 --scene " + (dir / "crop.h5").string() +
                    " --field-grid 5 --field-edge-deg " + to_str(edge) + " --out " + (dir / "crop").string(),
                "QDO_DEVICE=cpu");
    REQUIRE_MESSAGE(r.code == 0, r.out);
    CHECK(r.out.find("9 of 25 points computed (16 points' hats miss the scene)") != std::string::npos);
    const nlohmann::json vc = read_json(dir / "crop" / "varying.json");
    CHECK(vc.at("skipped").size() == 16);
    CHECK(vc.at("points").at(0).at("computed") == false);
    CHECK(vc.at("points").at(12).at("computed") == true);
    CHECK(read_json(dir / "crop" / "varying.json").at("report").at("components") == 9);
    // The small preset (Fresnel, N = 256): its Fresnel refuses the grid's corners, asm computes them, the output says so.
    const SystemConfig small = preset_config("small");
    SystemConfig small_asm = small;
    small_asm.propagator = Propagator::AngularSpectrum;
    const double e = 0.99 * max_field_angle_deg(small_asm, small.scene_distance_m);
    CHECK(!object_point_limit(small, ObjectPoint{small.scene_distance_m, e, e}).empty());
    write_cube((dir / "small.h5").string(), random_cube(31, 24, 24, 19), small.wavelengths_nm());
    r = qdo_run("simulate --preset small --design lens:550 --scene " + (dir / "small.h5").string() + " --field-grid 3 --field-edge-deg " +
                    to_str(e) + " --out " + (dir / "small").string(),
                "QDO_DEVICE=cpu");
    REQUIRE_MESSAGE(r.code == 0, r.out);
    CHECK(r.out.find("propagator: \"asm\" (band-limited angular spectrum) instead of the configuration's Fresnel") != std::string::npos);
    CHECK(read_json(dir / "small" / "varying.json").at("propagator") == "asm");
    // A Fresnel configuration whose Fresnel error stays below a tenth of a pixel at these angles
    // (z (tan - sin) ~ 0.1 um here): computed with Fresnel, no switch to asm.
    SystemConfig fresnel = cfg;
    fresnel.propagator = Propagator::Fresnel;
    r = qdo_run("simulate --config " + write_config(dir, "fresnel.json", fresnel) + " --design lens:550 --scene " + scene +
                    " --field-grid 3 --out " + (dir / "fresnel").string(),
                "QDO_DEVICE=cpu");
    REQUIRE_MESSAGE(r.code == 0, r.out);
    CHECK(r.out.find("propagator: \"asm\"") == std::string::npos);
    CHECK(read_json(dir / "fresnel" / "varying.json").at("propagator") == "fresnel");
  }

  TEST_CASE("refusals before any work: depth map size and values, layers, field edge beyond the sampling limit, incompatible options") {
    const fs::path dir = temp_dir("simvar4");
    const Removed removed{dir};
    const SystemConfig cfg = depth_config();
    const std::string cfg_file = write_config(dir, "cfg.json", cfg);
    const std::size_t h = 12, w = 14;
    const std::string scene = write_scene(dir, cfg, h, w, 3);
    const std::string base = "simulate --config " + cfg_file + " --design lens:550 --scene " + scene;
    const fs::path out = dir / "out";
    check_refused(base + " --depth " + write_depth(dir, "small.h5", Map2D(h, w - 1, 1.0)), out,
                  {"--depth", "12 x 14", "the map is 12 x 13"});
    for (const double bad : {0.0, -0.5, std::nan("")}) {
      Map2D d(h, w, 1.0);
      d(3, 5) = bad;
      check_refused(base + " --depth " + write_depth(dir, "bad.h5", d), out, {"--depth", "pixel (3, 5) = " + to_str(bad), "> 0 or +inf"});
    }
    {
      Map2D codes(h, w, 20.0);
      write_png16_gray((dir / "d.png").string(), codes);
      check_refused(base + " --depth " + (dir / "d.png").string() + " --depth-scale 0", out, {"--depth-scale", "m per code"});
      check_refused(base + " --depth " + write_depth(dir, "ok.h5", Map2D(h, w, 1.0)) + " --depth-scale 0.001", out,
                    {"--depth-scale", "only with a 16-bit PNG"});
    }
    const std::string ok = write_depth(dir, "ok.h5", Map2D(h, w, 1.0));
    check_refused(base + " --depth " + ok + ":/nothing", out, {"/nothing"});
    check_refused(base + " --depth " + ok + " --depth-layers 0,inf", out, {"--depth-layers", "= 0:", "> 0, or inf"});
    check_refused(base + " --depth " + ok + " --depth-layers -1", out, {"--depth-layers", "= -1:"});
    check_refused(base + " --depth " + ok + " --depth-layers 1,1", out, {"--depth-layers", "listed twice"});
    check_refused(base + " --depth " + ok + " --psf-placement middle", out, {"middle"});
    check_refused("simulate --config " + cfg_file + " --psf " + ok + " --scene " + scene + " --depth " + ok, out,
                  {"--psf", "no depth or field dependence"});
    check_refused(base + " --depth " + ok + " --field-grid 3", out, {"--field-grid", "not together with --depth for now"});
    check_refused(base + " --depth " + ok + " --raw", out, {"--raw", "not with --depth"});
    check_refused(base + " --depth-layers 1,inf", out, {"--depth-layers", "only with --depth"});
    check_refused(base + " --depth " + ok + " --field-rank 2", out, {"--field-rank", "only with --field-grid"});
    check_refused(base + " --depth " + ok + " --formation release", out, {"--formation", "qdo with --depth"});
    // The field edge against the sampling limit (the asm limit of this configuration).
    SystemConfig asm_cfg = cfg;
    asm_cfg.propagator = Propagator::AngularSpectrum;
    const double limit = max_field_angle_deg(asm_cfg, cfg.scene_distance_m);
    REQUIRE(limit > 0);
    REQUIRE(limit < 30);
    check_refused(base + " --field-grid 3 --field-edge-deg 30", out,
                  {"--field-edge-deg", "30 deg", "sampling limit", to_str(limit) + " deg"});
    check_refused(base + " --field-grid 0", out, {"--field-grid", "[1, 31]"});
    check_refused(base + " --field-grid 3x", out, {"--field-grid", "= 3x:", "NXxNY"});  // the whole value named, not an empty part
    check_refused(base + " --field-grid 3 --field-rank 10", out, {"--field-rank", "[1, 9]"});
    check_refused(base + " --field-grid 3 --depth-layers 1", out, {"--depth-layers", "only with --depth"});
  }
}
