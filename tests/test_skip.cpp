// Camera (include/qdo/physics/camera.hpp): sensor images with skipping rules and error bounds.
#include <cmath>
#include <fstream>
#include <random>
#include <sstream>
#include <sys/wait.h>

#include "common.hpp"
#include "qdo/physics/cpu_reference.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/physics/camera.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/simulator.hpp"

using namespace qdo;
using namespace qdo::test;

namespace {

// One scene shape for every case that does not need its own (tiling, alignment), so each FFT
// grid is planned and compiled once: PoCL compiles the FFT kernels per size, and one-off shapes
// made this suite a third of the cold default run. Non-square, neither side a power of two, both
// 7-smooth (circular mode runs the FFT on the scene grid), and each side such that cropping the
// 64-pixel PSF by one ring already shrinks the linear grid (36 + 63 -> 100 vs 98, 50 + 63 -> 120
// vs 112), so the crop rule has something to gain.
constexpr std::size_t kSceneRows = 36, kSceneCols = 50;

// "small" physics at N = 128 (sensor PSF S = 64), 31 bands on the FLIR response.
SystemConfig skip_config(std::size_t n = 128) {
  SystemConfig c = preset_config("small");
  c.n = n;
  c.padding_px = n / 4;
  c.sensor_distance_m = 0.0125 * double(n) / 256.0;
  c.read_noise_sigma = 0;  // noise-free: errors are measured against the unskipped images
  c.full_well_photons = 0;
  c.validate();
  return c;
}

double max_abs_diff(const std::vector<RealStack>& a, const std::vector<RealStack>& b) {
  REQUIRE(a.size() == b.size());
  double m = 0;
  for (std::size_t k = 0; k < a.size(); ++k) {
    REQUIRE(a[k].size() == b[k].size());
    for (std::size_t i = 0; i < a[k].size(); ++i) m = std::max(m, std::fabs(a[k].data[i] - b[k].data[i]));
  }
  return m;
}

// Rounding tolerance of an FFT convolution of values in [0, 1] on a grid of `points` samples.
double fft_tol(Precision p, double points) { return 32.0 * eps(p) * std::log2(points); }

// A scene with structure: smooth spectra times random patches, values in [0, 1].
RealStack textured_cube(std::size_t bands, std::size_t h, std::size_t w, unsigned seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  RealStack c(bands, h, w);
  const double c1 = u(rng), c2 = u(rng);
  for (std::size_t y = 0; y < h; ++y)
    for (std::size_t x = 0; x < w; ++x) {
      const double a = u(rng);
      for (std::size_t b = 0; b < bands; ++b) {
        const double t = double(b) / double(bands);
        c(b, y, x) = a * (0.5 + 0.5 * std::sin(6.0 * t + c1 + 3.0 * c2 * double(x) / double(w)));
      }
    }
  return c;
}

struct Rig {
  SystemConfig cfg;
  std::unique_ptr<Simulator> sim;
  Rig(const SystemConfig& c, Precision p, const Map2D& heights) : cfg(c) {
    sim = std::make_unique<Simulator>(runtime(), cfg, p);
    sim->set_heights(heights);
    sim->compute_psf();
  }
};

void check_bound_parts(const SkipReport& r) {
  CHECK(r.total_bound <= r.band_bound + r.crop_bound + r.tile_bound + 1e-18);
  CHECK(r.total_bound >= std::max({r.band_bound, r.crop_bound, r.tile_bound}));
}

}  // namespace

TEST_SUITE("skip") {

TEST_CASE("exact mode equals the CPU reference (convolution, sensor integration) in float32 and float64") {
  const SystemConfig cfg = skip_config();
  const Map2D lens = lens_design(cfg, 550);
  const std::vector<RealStack> cubes{random_cube(31, kSceneRows, kSceneCols, 1), textured_cube(31, kSceneRows, kSceneCols, 2)};
  for (Precision p : {Precision::F64, Precision::F32}) {
    CAPTURE(to_string(p));
    Rig rig(cfg, p, lens);
    Camera im(*rig.sim);
    SkipOptions o;
    o.exact = true;
    const auto got = im.images(cubes, o);
    const RealStack psf = rig.sim->psf_sensor();
    std::vector<RealStack> want;
    for (const auto& c : cubes) want.push_back(ref::sensor_integrate(ref::convolve(c, psf, ConvolutionMode::Linear), rig.sim->srf()));
    const std::size_t s = rig.sim->sensor_size();
    const double tol = fft_tol(p, double(fast_fft_size(kSceneRows + s - 1) * fast_fft_size(kSceneCols + s - 1)));
    const double err = max_abs_diff(got, want);
    MESSAGE("exact vs CPU reference, " << to_string(p) << ": max |diff| = " << err << " (tol " << tol << ")");
    CHECK(err <= tol);
    const SkipReport& r = im.last_report();
    CHECK(r.bands_skipped.empty());
    CHECK(r.crop_radius_px == s / 2);
    CHECK_FALSE(r.cropped);
    CHECK_FALSE(r.tiled);
    CHECK(r.total_bound == 0.0);
    CHECK(r.inverse_ffts == 2 * cubes.size());
    CHECK(r.forward_ffts == 16 * cubes.size());  // 31 bands in 16 pairs per scene
  }
}

TEST_CASE("exact mode reproduces the reference noise and circular convolution") {
  SystemConfig cfg = skip_config();
  cfg.read_noise_sigma = 0.01;
  cfg.noise_seed = 77;
  const Map2D h = random_heights(cfg.n, cfg.h_max_m(), 5);
  const std::vector<RealStack> cubes{random_cube(31, kSceneRows, kSceneCols, 3), random_cube(31, kSceneRows, kSceneCols, 4)};
  SkipOptions o;
  o.exact = true;
  auto reference = [](const SystemConfig& c, const RealStack& psf, const Eigen::MatrixXd& srf,
                      const std::vector<RealStack>& batch) {
    std::vector<RealStack> out;
    for (std::size_t k = 0; k < batch.size(); ++k) {
      out.push_back(ref::sensor_integrate(ref::convolve(batch[k], psf, c.convolution), srf));
      ref::add_noise(out.back(), c.read_noise_sigma, c.full_well_photons, c.noise_seed, k);
    }
    return out;
  };
  {
    Rig rig(cfg, Precision::F64, h);
    Camera im(*rig.sim);
    const double err = max_abs_diff(im.images(cubes, o), reference(cfg, rig.sim->psf_sensor(), rig.sim->srf(), cubes));
    CHECK(err <= 1e-12);
  }
  cfg.read_noise_sigma = 0;
  cfg.convolution = ConvolutionMode::Circular;
  const std::vector<RealStack> sq{random_cube(31, kSceneRows, kSceneCols, 6)};
  Rig rig(cfg, Precision::F64, h);
  Camera im(*rig.sim);
  const auto want = reference(cfg, rig.sim->psf_sensor(), rig.sim->srf(), sq);
  CHECK(max_abs_diff(im.images(sq, o), want) <= 1e-12);
  // In circular mode the grid is the scene: cropping cannot save work, so no rule crops.
  (void)im.images(sq, SkipOptions::split(1e-2));
  CHECK_FALSE(im.last_report().cropped);
  CHECK(max_abs_diff(im.images(sq, SkipOptions::split(0)), want) <= 1e-12);
}

TEST_CASE("crop rule: matches the CPU reference of the cropped computation and stays within its bound") {
  const SystemConfig cfg = skip_config();
  const Map2D lens = lens_design(cfg, 550);
  const std::vector<RealStack> cubes{textured_cube(31, kSceneRows, kSceneCols, 11), random_cube(31, kSceneRows, kSceneCols, 12)};
  Rig ref64(cfg, Precision::F64, lens);
  const auto unskipped = Camera(*ref64.sim).images(cubes, no_skipping());
  const RealStack psf = ref64.sim->psf_sensor();
  SkipOptions o;
  o.band_tolerance = 0;
  o.tile_tolerance = 0;
  o.crop_tolerance = 2e-3;
  for (Precision p : {Precision::F64, Precision::F32}) {
    CAPTURE(to_string(p));
    Rig rig(cfg, p, lens);
    Camera im(*rig.sim);
    const auto got = im.images(cubes, o);
    const SkipReport& r = im.last_report();
    REQUIRE(r.cropped);
    CHECK(r.crop_radius_px < rig.sim->sensor_size() / 2);
    CHECK(r.crop_bound > 0);
    CHECK(r.crop_bound <= o.crop_tolerance);
    CHECK(r.min_kept_energy < 1.0);
    check_bound_parts(r);
    const auto cpu = skipped_images_reference(cubes, psf, ref64.sim->srf(), r);
    const double tol = fft_tol(p, double(r.grid_rows * r.grid_cols));
    const double dev = max_abs_diff(got, cpu), err = max_abs_diff(got, unskipped);
    MESSAGE(to_string(p) << ": r = " << r.crop_radius_px << " grid " << r.grid_rows << "x" << r.grid_cols
                         << " |device - cpu ref| = " << dev << ", error vs unskipped = " << err
                         << ", bound = " << r.crop_bound);
    CHECK(dev <= tol);
    CHECK(err <= r.total_bound + tol);
    if (p == Precision::F64) CHECK(err > 0.01 * r.crop_bound);  // the bound is not vacuous
  }
}

TEST_CASE("band rule: zero-response and dark bands are skipped within the bound") {
  // A camera that does not see 400-430 nm, and a scene almost dark at 670-700 nm.
  SystemConfig cfg = skip_config();
  const auto dir = temp_dir("skip_srf");
  const std::string csv = (dir / "srf.csv").string();
  {
    std::ofstream f(csv);
    f << "wavelength_nm,R,G,B\n";
    for (int b = 0; b < 31; ++b) {
      const double l = 400 + 10 * b;
      auto g = [&](double mu) { return b < 4 ? 0.0 : std::exp(-0.5 * std::pow((l - mu) / 40.0, 2)); };
      f << l << "," << g(620) << "," << g(540) << "," << g(460) << "\n";
    }
  }
  cfg.camera = csv;
  const Map2D h = random_heights(cfg.n, cfg.h_max_m(), 21);
  std::vector<RealStack> cubes{textured_cube(31, kSceneRows, kSceneCols, 22)};
  for (std::size_t b = 27; b < 31; ++b)
    for (std::size_t i = 0; i < cubes[0].plane_size(); ++i) cubes[0].plane(b)[i] *= 1e-5;
  Rig r64(cfg, Precision::F64, h);
  const auto unskipped = Camera(*r64.sim).images(cubes, no_skipping());
  SkipOptions o;
  o.crop_tolerance = 0;
  o.tile_tolerance = 0;
  o.band_tolerance = 1e-5;
  for (Precision p : {Precision::F64, Precision::F32}) {
    CAPTURE(to_string(p));
    Rig rig(cfg, p, h);
    Camera im(*rig.sim);
    const auto got = im.images(cubes, o);
    const SkipReport& r = im.last_report();
    for (std::size_t b = 0; b < 4; ++b)
      CHECK(std::find(r.bands_skipped.begin(), r.bands_skipped.end(), b) != r.bands_skipped.end());
    CHECK(r.bands_skipped.size() > 4);  // some of the dark bands too
    CHECK(r.band_bound > 0);
    CHECK(r.band_bound <= o.band_tolerance);
    CHECK(r.forward_ffts == (r.bands_kept.size() + 1) / 2);
    const double tol = fft_tol(p, double(r.grid_rows * r.grid_cols));
    const double err = max_abs_diff(got, unskipped);
    MESSAGE(to_string(p) << ": skipped " << r.bands_skipped.size() << " bands, error " << err << " bound " << r.band_bound);
    CHECK(err <= r.total_bound + tol);
    CHECK(max_abs_diff(got, skipped_images_reference(cubes, r64.sim->psf_sensor(), r64.sim->srf(), r)) <= tol);
    if (p == Precision::F64) CHECK(err > 0.01 * r.band_bound);
  }
  // With a zero budget only bands contributing exactly nothing go.
  Rig rig(cfg, Precision::F64, h);
  Camera im(*rig.sim);
  (void)im.images(cubes, SkipOptions::split(0));
  CHECK(im.last_report().bands_skipped.size() == 4);
  CHECK(im.last_report().total_bound == 0.0);
  std::filesystem::remove_all(dir);
}

TEST_CASE("tile rule: empty tiles skipped by overlap-add within the bound") {
  const SystemConfig cfg = skip_config();
  const Map2D lens = lens_design(cfg, 600);
  // 70 x 90 scene: zero except a textured block crossing tile borders and a faint patch.
  RealStack tex = textured_cube(31, 70, 90, 31);
  std::vector<RealStack> cubes(2, RealStack(31, 70, 90));
  for (std::size_t b = 0; b < 31; ++b)
    for (std::size_t y = 0; y < 70; ++y)
      for (std::size_t x = 0; x < 90; ++x) {
        if (y >= 20 && y < 45 && x >= 10 && x < 37) cubes[0](b, y, x) = tex(b, y, x);
        if (y >= 50 && x >= 60) cubes[0](b, y, x) = 2e-6 * tex(b, y, x);
        if (y < 8 && x >= 70) cubes[1](b, y, x) = tex(b, y, x);
      }
  Rig r64(cfg, Precision::F64, lens);
  const auto unskipped = Camera(*r64.sim).images(cubes, no_skipping());
  SkipOptions o;
  o.band_tolerance = 0;
  o.crop_tolerance = 0;
  o.tile_tolerance = 1e-5;
  o.tiles = TileMode::On;
  o.tile_px = 16;
  for (Precision p : {Precision::F64, Precision::F32}) {
    CAPTURE(to_string(p));
    Rig rig(cfg, p, lens);
    Camera im(*rig.sim);
    const auto got = im.images(cubes, o);
    const SkipReport& r = im.last_report();
    REQUIRE(r.tiled);
    CHECK(r.tiles_y == 5);
    CHECK(r.tiles_x == 6);
    CHECK(r.tiles_total == 60);
    CHECK(r.tiles_skipped > 30);
    CHECK(r.tile_bound > 0);  // the faint patch was skipped
    CHECK(r.tile_bound <= o.tile_tolerance);
    check_bound_parts(r);
    const double tol = fft_tol(p, double(r.grid_rows * r.grid_cols));
    const double err = max_abs_diff(got, unskipped);
    const double dev = max_abs_diff(got, skipped_images_reference(cubes, r64.sim->psf_sensor(), r64.sim->srf(), r));
    MESSAGE(to_string(p) << ": skipped " << r.tiles_skipped << "/" << r.tiles_total << " tiles, error " << err
                         << " bound " << r.tile_bound << ", |device - cpu ref| " << dev);
    CHECK(dev <= tol);
    CHECK(err <= r.total_bound + tol);
    if (p == Precision::F64) CHECK(err > 0.01 * r.tile_bound);
  }
  // Tiling with nothing skipped is still the exact linear convolution (overlap-add check).
  Rig rig(cfg, Precision::F64, lens);
  Camera im(*rig.sim);
  SkipOptions on;
  on.band_tolerance = on.crop_tolerance = on.tile_tolerance = 0;
  on.tiles = TileMode::On;
  on.tile_px = 24;
  const std::vector<RealStack> dense{textured_cube(31, 50, 61, 33)};
  CHECK(max_abs_diff(im.images(dense, on), Camera(*rig.sim).images(dense, no_skipping())) <= 1e-12);
  CHECK(im.last_report().tiles_skipped == 0);
}

TEST_CASE("all rules together: total bound within the total tolerance") {
  const SystemConfig cfg = skip_config();
  const Map2D lens = lens_design(cfg, 550);
  std::vector<RealStack> cubes{textured_cube(31, 64, 64, 41)};
  for (std::size_t b = 0; b < 31; ++b)
    for (std::size_t y = 0; y < 64; ++y)
      for (std::size_t x = 0; x < 64; ++x) cubes[0](b, y, x) *= (b < 3 ? 1e-4 : 1.0) * (x >= 32 ? 1e-6 : 1.0);
  Rig r64(cfg, Precision::F64, lens);
  const auto unskipped = Camera(*r64.sim).images(cubes, no_skipping());
  const SkipOptions o = SkipOptions::split(3e-2, TileMode::On, 16);
  Camera im(*r64.sim);
  const auto got = im.images(cubes, o);
  const SkipReport& r = im.last_report();
  CHECK(r.total_bound <= o.total_tolerance());
  CHECK(r.band_bound <= o.band_tolerance);
  CHECK(r.crop_bound <= o.crop_tolerance);
  CHECK(r.tile_bound <= o.tile_tolerance);
  CHECK(r.cropped);
  CHECK(r.tiles_skipped > 0);
  CHECK_FALSE(r.bands_skipped.empty());
  check_bound_parts(r);
  const double err = max_abs_diff(got, unskipped);
  MESSAGE("all rules: error " << err << " bound " << r.total_bound << " (bands " << r.band_bound << ", crop "
                              << r.crop_bound << ", tiles " << r.tile_bound << ")");
  CHECK(err <= r.total_bound + 1e-12);
  CHECK(max_abs_diff(got, skipped_images_reference(cubes, r64.sim->psf_sensor(), r64.sim->srf(), r)) <= 1e-12);
  // The JSON report carries the bound.
  CHECK(r.to_json().find("\"total\"") != std::string::npos);
}

TEST_CASE("alignment: off-centre point PSFs shift the scene exactly as the unskipped convention") {
  const SystemConfig cfg = skip_config();
  const std::size_t s = cfg.sensor_size_px(), c = s / 2, bands = cfg.bands;
  // Band b: a unit point at offset (dy_b, dx_b), including the extreme offsets -S/2 and S/2 - 1.
  std::mt19937_64 rng(51);
  std::uniform_int_distribution<int> off(-int(c), int(c) - 1);
  std::vector<int> dy(bands), dx(bands);
  for (std::size_t b = 0; b < bands; ++b) {
    dy[b] = off(rng);
    dx[b] = off(rng);
  }
  dy[0] = -int(c);
  dx[0] = int(c) - 1;
  dy[1] = 5;
  dx[1] = -3;
  RealStack psf(bands, s, s);
  for (std::size_t b = 0; b < bands; ++b) psf(b, std::size_t(int(c) + dy[b]), std::size_t(int(c) + dx[b])) = 1.0;
  const RealStack cube = random_cube(bands, kSceneRows, kSceneCols, 52);
  const Eigen::MatrixXd srf = sensor_response(cfg);
  // Expected: I_c(y, x) = sum_b srf(c, b) cube_b(y - dy_b, x - dx_b), zero outside.
  RealStack want(3, kSceneRows, kSceneCols);
  for (std::size_t ch = 0; ch < 3; ++ch)
    for (int y = 0; y < int(kSceneRows); ++y)
      for (int x = 0; x < int(kSceneCols); ++x) {
        double v = 0;
        for (std::size_t b = 0; b < bands; ++b) {
          const int yy = y - dy[b], xx = x - dx[b];
          if (yy >= 0 && yy < int(kSceneRows) && xx >= 0 && xx < int(kSceneCols)) v += srf(Eigen::Index(ch), Eigen::Index(b)) * cube(b, std::size_t(yy), std::size_t(xx));
        }
        want(ch, std::size_t(y), std::size_t(x)) = v;
      }
  // The unskipped convention (ref::convolve, which the Simulator's convolution is tested against).
  const RealStack conv = ref::sensor_integrate(ref::convolve(cube, psf, ConvolutionMode::Linear), srf);
  CHECK(max_abs_diff({conv}, {want}) <= 1e-12);
  // Only bands 0 and 1 shifted (small radius, for the crop and tile variants).
  RealStack psf2(bands, s, s);
  for (std::size_t b = 0; b < bands; ++b) psf2(b, c + 2, c - 1) = 1.0;
  psf2(0, c + 2, c - 1) = 0;
  psf2(0, c - 4, c + 6) = 1.0;
  RealStack want2(3, kSceneRows, kSceneCols);
  for (std::size_t ch = 0; ch < 3; ++ch)
    for (int y = 0; y < int(kSceneRows); ++y)
      for (int x = 0; x < int(kSceneCols); ++x) {
        double v = 0;
        for (std::size_t b = 0; b < bands; ++b) {
          const int yy = y - (b == 0 ? -4 : 2), xx = x - (b == 0 ? 6 : -1);
          if (yy >= 0 && yy < int(kSceneRows) && xx >= 0 && xx < int(kSceneCols)) v += srf(Eigen::Index(ch), Eigen::Index(b)) * cube(b, std::size_t(yy), std::size_t(xx));
        }
        want2(ch, std::size_t(y), std::size_t(x)) = v;
      }
  for (Precision p : {Precision::F64, Precision::F32}) {
    CAPTURE(to_string(p));
    Camera im(runtime(), cfg, p);
    im.set_psf(psf);
    const double tol = 64 * eps(p);
    SkipOptions exact;
    exact.exact = true;
    CHECK(max_abs_diff(im.images({cube}, exact), {want}) <= tol);
    // Crop with a zero budget: the radius shrinks to the points (nothing dropped).
    SkipOptions crop = SkipOptions::split(0);
    im.set_psf(psf2);
    CHECK(max_abs_diff(im.images({cube}, crop), {want2}) <= tol);
    CHECK(im.last_report().crop_radius_px >= 6);
    CHECK(im.last_report().crop_radius_px < c);
    CHECK(im.last_report().total_bound == 0.0);
    // Tiles of 8 px (the point spreads content across tile borders).
    crop.tiles = TileMode::On;
    crop.tile_px = 8;
    CHECK(max_abs_diff(im.images({cube}, crop), {want2}) <= tol);
    CHECK(im.last_report().tiled);
    // A crop radius below the point's offset drops it, and the bound says so.
    SkipOptions loose;
    loose.band_tolerance = loose.tile_tolerance = 0;
    loose.crop_tolerance = 0.5;  // band 0 (one of 31, small weight) may be dropped whole
    const auto got = im.images({cube}, loose);
    const double err = max_abs_diff(got, {want2});
    CHECK(err <= im.last_report().total_bound + tol);
  }
}

TEST_CASE("reuse: OTFs built once per PSF generation and shared across calls and batches") {
  const SystemConfig cfg = skip_config();
  Rig rig(cfg, Precision::F32, lens_design(cfg, 550));
  Camera im(*rig.sim);
  const std::vector<RealStack> one{random_cube(31, kSceneRows, kSceneCols, 61)}, two{random_cube(31, kSceneRows, kSceneCols, 62), random_cube(31, kSceneRows, kSceneCols, 61)};
  const SkipOptions o = SkipOptions::split(1e-4);
  const auto a = im.images(one, o);
  CHECK(im.otf_builds() == 1);
  CHECK_FALSE(im.last_report().otf_reused);
  const auto b = im.images(two, o);
  CHECK(im.otf_builds() == 1);
  CHECK(im.last_report().otf_reused);
  CHECK(max_abs_diff({b[1]}, a) == 0.0);  // same scene, same result, batch or not
  rig.sim->set_heights(random_heights(cfg.n, cfg.h_max_m(), 63));
  rig.sim->compute_psf();
  const auto c = im.images(one, o);
  CHECK(im.otf_builds() == 2);
  CHECK(im.last_report().psf_generation == rig.sim->psf_generation());
  CHECK(max_abs_diff(c, a) > 1e-3);
}

TEST_CASE("bad options and inputs are rejected before any work") {
  const SystemConfig cfg = skip_config();
  const std::vector<RealStack> cubes{random_cube(31, kSceneRows, kSceneCols, 71)};
  {
    Simulator sim(runtime(), cfg, Precision::F32);
    Camera im(sim);
    CHECK_THROWS_AS((void)im.images(cubes), Error);  // compute_psf() has not run
    CHECK_THROWS_WITH_AS(im.set_psf(RealStack(31, 64, 64)), doctest::Contains("set_psf"), InputError);
  }
  Rig rig(cfg, Precision::F32, lens_design(cfg, 550));
  Camera im(*rig.sim);
  auto bad = [&](SkipOptions o, const char* name) {
    CHECK_THROWS_WITH_AS((void)im.images(cubes, o), doctest::Contains(name), InputError);
  };
  SkipOptions o;
  o.band_tolerance = -1e-6;
  bad(o, "band_tolerance");
  o = {};
  o.crop_tolerance = std::nan("");
  bad(o, "crop_tolerance");
  o = {};
  o.tile_tolerance = INFINITY;
  bad(o, "tile_tolerance");
  o = {};
  o.tile_px = 4;
  bad(o, "tile_px");
  o.tile_px = 5000;
  bad(o, "tile_px");
  CHECK_THROWS_WITH_AS(tile_mode_from_string("sometimes"), doctest::Contains("tiles"), InputError);
  CHECK_THROWS_WITH_AS(SkipOptions::split(-1), doctest::Contains("tolerance"), InputError);
  CHECK_THROWS_WITH_AS((void)im.images({}), doctest::Contains("cubes"), InputError);
  CHECK_THROWS_WITH_AS((void)im.images({random_cube(30, kSceneRows, kSceneCols, 1)}), doctest::Contains("bands"), InputError);
  CHECK_THROWS_WITH_AS((void)im.images({cubes[0], random_cube(31, kSceneRows, kSceneCols + 1, 1)}), doctest::Contains("cubes[1]"), InputError);
  RealStack nan_cube = cubes[0];
  nan_cube(3, 2, 1) = std::nan("");
  CHECK_THROWS_WITH_AS((void)im.images({nan_cube}), doctest::Contains("finite"), InputError);
  // Exact calls check the values while uploading them: the same refusal, naming the same value,
  // for a NaN and for an infinity, and no batch is left for vjp() to differentiate.
  SkipOptions exact_opt;
  exact_opt.exact = true;
  CHECK_THROWS_WITH_AS((void)im.images({cubes[0], nan_cube}, exact_opt), doctest::Contains("cubes[1](3, 2, 1)"), InputError);
  RealStack inf_cube = cubes[0];
  inf_cube(30, kSceneRows - 1, kSceneCols - 1) = -INFINITY;
  const std::string where = "cubes[0](30, " + std::to_string(kSceneRows - 1) + ", " + std::to_string(kSceneCols - 1) + ")";
  CHECK_THROWS_WITH_AS((void)im.images({inf_cube}, exact_opt), doctest::Contains(where.c_str()), InputError);
  CHECK_THROWS_AS((void)im.vjp({RealStack(3, kSceneRows, kSceneCols)}), InputError);
  Camera standalone(runtime(), cfg, Precision::F32);
  CHECK_THROWS_WITH_AS(standalone.set_psf(RealStack(31, 63, 63)), doctest::Contains("psf_sensor"), InputError);
  CHECK_THROWS_AS((void)standalone.images(cubes), Error);  // no PSF yet
  SystemConfig circ = cfg;
  circ.convolution = ConvolutionMode::Circular;
  Camera ci(runtime(), circ, Precision::F32);
  ci.set_psf(RealStack(31, 64, 64, 1.0 / 4096));
  SkipOptions t;
  t.tiles = TileMode::On;
  CHECK_THROWS_WITH_AS((void)ci.images(cubes, t), doctest::Contains("tiles"), InputError);
  CHECK_THROWS_WITH_AS((void)ci.images({random_cube(31, 11, 16, 1)}), doctest::Contains("factors"), InputError);
}

TEST_CASE("qdo image writes the sensor PNG and the skip report; bad options exit 2") {
  const auto dir = temp_dir("skip_cli");
  const std::string cfg = (dir / "cfg.json").string();
  {
    std::ofstream f(cfg);
    f << R"({"preset": "small", "n": 128, "padding_px": 32, "sensor_distance_m": 0.00625, "scene_size_px": 64,
             "read_noise_sigma": 0})";
  }
  auto run = [&](const std::string& args) {
    const std::string log = (dir / "log.txt").string();
    const int st = std::system((std::string(QDO_QDO_BINARY) + " image --config " + cfg + " " + args + " > " + log + " 2>&1").c_str());
    std::ifstream f(log);
    std::stringstream ss;
    ss << f.rdbuf();
    return std::pair<int, std::string>(WIFEXITED(st) ? WEXITSTATUS(st) : -1, ss.str());
  };
  const std::string out = (dir / "img").string();
  const auto ok = run("--design lens:550 --scene builtin --tolerance 1e-3 --tiles auto --out " + out);
  CAPTURE(ok.second);
  CHECK(ok.first == 0);
  CHECK(std::filesystem::exists(out + "/sensor.png"));
  std::ifstream j(out + "/skip.json");
  std::stringstream js;
  js << j.rdbuf();
  CHECK(js.str().find("\"total\"") != std::string::npos);
  CHECK(js.str().find("\"tolerance\": 0.001") != std::string::npos);
  const auto bad = run("--design lens:550 --tolerance -1 --out " + out);
  CHECK(bad.first == 2);
  CHECK(bad.second.find("tolerance") != std::string::npos);
  const auto bad_tiles = run("--design lens:550 --tiles maybe --out " + out);
  CHECK(bad_tiles.first == 2);
  std::filesystem::remove_all(dir);
}

}  // TEST_SUITE
