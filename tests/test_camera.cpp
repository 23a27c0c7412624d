// The camera operator (include/qdo/physics/camera.hpp, kernels/camera.cl, src/physics/camera.cpp):
// per-band convolution -> sensor integration on the device, its blur, and its adjoints to the
// PSF stack and to the scenes. The adjoint ladder (tests/adjoint_ladder.hpp) runs over a table of
// stages, device (float64) and CPU reference alike; then every device result is compared with
// the double-precision CPU reference (ref::convolve, ref::sensor_integrate, ref::convolve_vjp_psf,
// ref::convolve_vjp_scene, ref::sensor_integrate_vjp) in float32 and float64, and so are the
// Simulator's per-band convolution and its batched sensor images (noise counters included).
#include <cmath>
#include <random>

#include "adjoint_ladder.hpp"
#include "common.hpp"
#include "qdo/physics/adjoint.hpp"
#include "qdo/physics/camera.hpp"
#include "qdo/physics/cpu_reference.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/decode/testset.hpp"
#include "qdo/decode/wiener.hpp"

using namespace qdo;
using namespace qdo::test;

namespace {

// 3 bands, sensor PSF S = 16 (n = 32); scenes 20 x 18 (7-smooth: circular mode runs on them).
constexpr std::size_t kRows = 20, kCols = 18, kScenes = 2;

SystemConfig camera_config(ConvolutionMode mode) {
  SystemConfig c = tiny_config(32, 3);
  c.convolution = mode;
  c.read_noise_sigma = 0;
  c.full_well_photons = 0;
  c.validate();
  return c;
}

RealStack random_psf(const SystemConfig& c, unsigned seed) {
  const std::size_t s = c.sensor_size_px();
  RealStack p = random_cube(c.bands, s, s, seed);
  for (std::size_t b = 0; b < c.bands; ++b) {  // non-negative, each band sums to 1
    double sum = 0;
    for (std::size_t i = 0; i < s * s; ++i) sum += p.plane(b)[i];
    for (std::size_t i = 0; i < s * s; ++i) p.plane(b)[i] /= sum;
  }
  return p;
}

std::vector<double> flat(const std::vector<RealStack>& v) {
  std::vector<double> out;
  for (const auto& s : v) out.insert(out.end(), s.data.begin(), s.data.end());
  return out;
}
std::vector<RealStack> unflat(const std::vector<double>& x, std::size_t n, std::size_t p, std::size_t r, std::size_t c) {
  std::vector<RealStack> out(n, RealStack(p, r, c));
  for (std::size_t k = 0; k < n; ++k) std::copy(x.begin() + long(k * p * r * c), x.begin() + long((k + 1) * p * r * c), out[k].data.begin());
  return out;
}
RealStack as_stack(const std::vector<double>& x, std::size_t p, std::size_t r, std::size_t c) { return unflat(x, 1, p, r, c)[0]; }


// CPU reference of the noiseless camera and its adjoints.
std::vector<RealStack> ref_images(const std::vector<RealStack>& cubes, const RealStack& psf, const Eigen::MatrixXd& srf,
                                  ConvolutionMode mode) {
  std::vector<RealStack> out;
  for (const auto& c : cubes) out.push_back(ref::sensor_integrate(ref::convolve(c, psf, mode), srf));
  return out;
}
RealStack ref_vjp_psf(const std::vector<RealStack>& cubes, const std::vector<RealStack>& g, const Eigen::MatrixXd& srf,
                      std::size_t s, ConvolutionMode mode) {
  RealStack out(cubes[0].planes, s, s);
  for (std::size_t k = 0; k < cubes.size(); ++k) {
    const RealStack part = ref::convolve_vjp_psf(cubes[k], ref::sensor_integrate_vjp(g[k], srf), s, mode);
    for (std::size_t i = 0; i < out.size(); ++i) out.data[i] += part.data[i];
  }
  return out;
}
std::vector<RealStack> ref_vjp_scene(const RealStack& psf, const std::vector<RealStack>& g, const Eigen::MatrixXd& srf,
                                     ConvolutionMode mode) {
  std::vector<RealStack> out;
  for (const auto& gk : g) out.push_back(ref::convolve_vjp_scene(psf, ref::sensor_integrate_vjp(gk, srf), mode));
  return out;
}

const char* mode_name(ConvolutionMode m) { return m == ConvolutionMode::Linear ? "linear" : "circular"; }

}  // namespace

TEST_SUITE("camera") {

TEST_CASE("adjoint ladder over the camera stages (device float64 and CPU reference)") {
  const bool f64 = runtime().has_fp64();
  for (ConvolutionMode mode : {ConvolutionMode::Linear, ConvolutionMode::Circular}) {
    const SystemConfig cfg = camera_config(mode);
    const std::size_t s = cfg.sensor_size_px(), nb = cfg.bands;
    const Eigen::MatrixXd srf = sensor_response(cfg);
    const RealStack psf0 = random_psf(cfg, 3);
    const std::vector<RealStack> cubes0{random_cube(nb, kRows, kCols, 4), random_cube(nb, kRows, kCols, 5)};
    const std::size_t n_psf = psf0.size(), n_scene = kScenes * nb * kRows * kCols, n_img = kScenes * 3 * kRows * kCols;
    const std::string m = mode_name(mode);
    std::vector<Stage> stages;

    // CPU reference: the same two linear maps, in double.
    Stage rp("reference " + m + ": PSF -> images", n_psf, n_img);
    rp.forward = [&](const std::vector<double>& x) { return flat(ref_images(cubes0, as_stack(x, nb, s, s), srf, mode)); };
    rp.vjp = [&](const std::vector<double>&, const std::vector<double>& g) {
      return ref_vjp_psf(cubes0, unflat(g, kScenes, 3, kRows, kCols), srf, s, mode).data;
    };
    rp.jvp = [f = rp.forward](const std::vector<double>&, const std::vector<double>& d) { return f(d); };
    stages.push_back(rp);
    Stage rs("reference " + m + ": scenes -> images", n_scene, n_img);
    rs.forward = [&](const std::vector<double>& x) { return flat(ref_images(unflat(x, kScenes, nb, kRows, kCols), psf0, srf, mode)); };
    rs.vjp = [&](const std::vector<double>&, const std::vector<double>& g) {
      return flat(ref_vjp_scene(psf0, unflat(g, kScenes, 3, kRows, kCols), srf, mode));
    };
    rs.jvp = [f = rs.forward](const std::vector<double>&, const std::vector<double>& d) { return f(d); };
    stages.push_back(rs);

    // The device camera in float64 (the ladder's finite differences need double).
    std::unique_ptr<Camera> cam;
    SkipOptions exact;
    exact.exact = true;
    if (skip_unless(f64, "device float64 camera ladder: the device has no float64")) {
      cam = std::make_unique<Camera>(runtime(), cfg, Precision::F64);
      Camera* cp = cam.get();
      Stage dp("device f64 " + m + ": PSF -> images", n_psf, n_img);
      dp.forward = [&, cp](const std::vector<double>& x) {
        Camera& c = *cp;
        c.set_psf(as_stack(x, nb, s, s));
        return flat(c.images(cubes0, exact));
      };
      dp.vjp = [&, cp](const std::vector<double>& x, const std::vector<double>& g) {
        Camera& c = *cp;
        c.set_psf(as_stack(x, nb, s, s));
        c.images(cubes0, exact);
        return c.vjp(unflat(g, kScenes, 3, kRows, kCols), false).psf.data;
      };
      dp.jvp = [f = dp.forward](const std::vector<double>&, const std::vector<double>& d) { return f(d); };
      dp.dot_tol = 1e-12;
      stages.push_back(dp);
      Stage ds("device f64 " + m + ": scenes -> images", n_scene, n_img);
      ds.forward = [&, cp](const std::vector<double>& x) {
        Camera& c = *cp;
        c.set_psf(psf0);
        return flat(c.images(unflat(x, kScenes, nb, kRows, kCols), exact));
      };
      ds.vjp = [&, cp](const std::vector<double>& x, const std::vector<double>& g) {
        Camera& c = *cp;
        c.set_psf(psf0);
        c.images(unflat(x, kScenes, nb, kRows, kCols), exact);
        return flat(c.vjp(unflat(g, kScenes, 3, kRows, kCols), true).scenes);
      };
      ds.jvp = [f = ds.forward](const std::vector<double>&, const std::vector<double>& d) { return f(d); };
      stages.push_back(ds);
    }
    std::uint64_t seed = 100;
    for (const Stage& st : stages) check_ladder(st, seed += 10);
  }
}

TEST_CASE("device camera, blur and both adjoints against the CPU reference (float32, float64; linear, circular)") {
  for (Precision p : device_precisions(runtime())) {
    for (ConvolutionMode mode : {ConvolutionMode::Linear, ConvolutionMode::Circular}) {
      CAPTURE(to_string(p));
      CAPTURE(std::string(mode_name(mode)));
      const SystemConfig cfg = camera_config(mode);
      const std::size_t s = cfg.sensor_size_px(), nb = cfg.bands;
      Camera cam(runtime(), cfg, p);
      const RealStack psf = random_psf(cfg, 11);
      cam.set_psf(psf);
      const std::vector<RealStack> cubes{random_cube(nb, kRows, kCols, 12), random_cube(nb, kRows, kCols, 13)};
      std::vector<RealStack> g{random_cube(3, kRows, kCols, 14), random_cube(3, kRows, kCols, 15)};
      for (auto& gk : g)
        for (double& v : gk.data) v -= 0.5;
      // Rounding tolerance: an FFT convolution of O(1) values on a grid of a few hundred points,
      // relative to the largest value compared.
      const double tol = 64.0 * eps(p) * std::log2(double(4 * kRows * kCols));
      SkipOptions exact;
      exact.exact = true;
      const auto imgs = flat(cam.images(cubes, exact));
      const auto want_imgs = flat(ref_images(cubes, psf, cam.srf(), mode));
      CHECK(max_abs_diff(imgs, want_imgs) <= tol * max_abs(want_imgs));
      const Camera::Gradient gr = cam.vjp(g, true);
      const auto want_psf = ref_vjp_psf(cubes, g, cam.srf(), s, mode).data;
      const auto want_scene = flat(ref_vjp_scene(psf, g, cam.srf(), mode));
      const double e_psf = max_abs_diff(gr.psf.data, want_psf), e_scene = max_abs_diff(flat(gr.scenes), want_scene);
      MESSAGE(to_string(p) << " " << mode_name(mode) << ": |vjp_psf - ref| = " << e_psf << ", |vjp_scene - ref| = " << e_scene);
      CHECK(e_psf <= tol * max_abs(want_psf));
      CHECK(e_scene <= tol * max_abs(want_scene));
      // want_scenes = false gives the same PSF gradient and no scenes.
      const Camera::Gradient gp = cam.vjp(g, false);
      CHECK(gp.scenes.empty());
      CHECK(max_abs_diff(gp.psf.data, gr.psf.data) <= tol * max_abs(want_psf));
      // The vjp read the scene spectra images() left on the device; transforming the scenes again
      // gives the same numbers (the same transforms of the same data).
      CHECK(cam.spectra_reused());
      cam.forget_spectra();
      CHECK_FALSE(cam.spectra_reused());
      const Camera::Gradient ga = cam.vjp(g, true);
      CHECK(ga.psf.data == gr.psf.data);
      CHECK(flat(ga.scenes) == flat(gr.scenes));
      // The blur alone.
      const auto blurred = cam.blur(cubes);
      for (std::size_t k = 0; k < cubes.size(); ++k) {
        const auto want = ref::convolve(cubes[k], psf, mode).data;
        CHECK(max_abs_diff(blurred[k].data, want) <= tol * max_abs(want));
      }
    }
  }
}

TEST_CASE("the adjoint of a skipped call is the adjoint of what it computed (bands and crop)") {
  // Band 0 unseen by the camera (zero response): skipped, so its gradients are exactly zero;
  // a crop keeps offsets |t| <= r only, so the PSF gradient is zero outside that square.
  SystemConfig cfg = camera_config(ConvolutionMode::Linear);
  const Precision p = runtime().has_fp64() ? Precision::F64 : Precision::F32;
  Camera cam(runtime(), cfg, p);
  const std::size_t s = cfg.sensor_size_px(), c = s / 2, nb = cfg.bands;
  // A PSF concentrated near the axis: the crop rule has energy to drop only far out.
  RealStack psf(nb, s, s);
  for (std::size_t b = 0; b < nb; ++b)
    for (std::size_t y = 0; y < s; ++y)
      for (std::size_t x = 0; x < s; ++x) {
        const double r2 = double((y - c) * (y - c) + (x - c) * (x - c));
        psf(b, y, x) = std::exp(-r2 / 2.0);
      }
  cam.set_psf(psf);
  const std::vector<RealStack> cubes{random_cube(nb, kRows, kCols, 21)};
  const std::vector<RealStack> g{random_cube(3, kRows, kCols, 22)};
  SkipOptions o;
  o.band_tolerance = 0;
  o.tile_tolerance = 0;
  o.crop_tolerance = 1e-3;
  cam.images(cubes, o);
  const SkipReport& r = cam.last_report();
  REQUIRE(r.cropped);
  const Camera::Gradient gr = cam.vjp(g, true);
  // Reference: the cropped PSF's adjoint, masked to the crop.
  RealStack cropped = psf;
  for (std::size_t b = 0; b < nb; ++b)
    for (std::size_t y = 0; y < s; ++y)
      for (std::size_t x = 0; x < s; ++x)
        if (std::max(std::labs(long(y) - long(c)), std::labs(long(x) - long(c))) > long(r.crop_radius_px)) cropped(b, y, x) = 0;
  RealStack want_psf = ref_vjp_psf(cubes, g, cam.srf(), s, ConvolutionMode::Linear);
  for (std::size_t i = 0; i < want_psf.size(); ++i)
    if (cropped.data[i] == 0) want_psf.data[i] = 0;
  const auto want_scene = flat(ref_vjp_scene(cropped, g, cam.srf(), ConvolutionMode::Linear));
  const double tol = 64.0 * eps(p) * std::log2(double(4 * kRows * kCols));
  CHECK(max_abs_diff(gr.psf.data, want_psf.data) <= tol * max_abs(want_psf.data));
  CHECK(max_abs_diff(flat(gr.scenes), want_scene) <= tol * max_abs(want_scene));
  std::size_t outside_nonzero = 0;
  for (std::size_t i = 0; i < want_psf.size(); ++i) outside_nonzero += cropped.data[i] == 0 && gr.psf.data[i] != 0;
  CHECK(outside_nonzero == 0);
}

TEST_CASE("camera vjp refuses what it cannot differentiate") {
  const SystemConfig cfg = camera_config(ConvolutionMode::Linear);
  const Precision p = Precision::F32;
  Camera cam(runtime(), cfg, p);
  cam.set_psf(random_psf(cfg, 31));
  const std::vector<RealStack> cubes{random_cube(cfg.bands, kRows, kCols, 32)};
  const std::vector<RealStack> g{random_cube(3, kRows, kCols, 33)};
  CHECK_THROWS_AS(cam.vjp(g), InputError);  // no images() yet
  SkipOptions exact;
  exact.exact = true;
  cam.images(cubes, exact);
  CHECK_THROWS_AS(cam.vjp({g[0], g[0]}), InputError);                       // one gradient per scene
  CHECK_THROWS_AS(cam.vjp({random_cube(3, kRows + 1, kCols, 34)}), InputError);  // shape
  std::vector<RealStack> bad = g;
  bad[0].data[5] = std::nan("");
  CHECK_THROWS_AS(cam.vjp(bad), InputError);
  CHECK_NOTHROW(cam.vjp(g));
  cam.set_psf(random_psf(cfg, 35));  // the PSF changed since images()
  CHECK_THROWS_AS(cam.vjp(g), Error);
  cam.images(cubes, exact);
  (void)cam.blur(cubes);  // blur() replaces the batch on the device
  CHECK_THROWS_AS(cam.vjp(g), InputError);
  SkipOptions tiled;
  tiled.tiles = TileMode::On;
  tiled.tile_px = 8;
  cam.images(cubes, tiled);
  REQUIRE(cam.last_report().tiled);
  CHECK_THROWS_AS(cam.vjp(g), InputError);
}

TEST_CASE("the test-set camera of eval and tolerance: device, circular on the patch grid, equal to the host reference") {
  // S = 15 (7-smooth: the camera runs circular) and S = 11 (not: the linear camera on the
  // periodic extension); the host reference is the OTF camera wiener::simulate_measurement.
  for (std::size_t n : {30u, 22u}) {
    const SystemConfig cfg = tiny_config(n, 3);
    const std::size_t s = cfg.sensor_size_px();
    CAPTURE(s);
    testset::PatchCamera cam(runtime(), cfg);
    CHECK(cam.periodic_extension() == (fast_fft_size(s) != s));
    const RealStack psf = random_psf(cfg, 41);
    std::vector<testset::Patch> patches;
    for (unsigned k = 0; k < 3; ++k) patches.push_back({"p", random_cube(cfg.bands, s, s, 42 + k)});
    const auto got = cam.measure(psf, patches);
    REQUIRE(got.size() == patches.size());
    const Eigen::MatrixXd srf = sensor_response(cfg);
    const ComplexStack otf = wiener::psf_to_otf(psf, s, s);
    const double tol = 64.0 * eps(cam.precision()) * std::log2(double(4 * s * s));
    for (std::size_t k = 0; k < patches.size(); ++k) {
      const auto want = wiener::simulate_measurement(patches[k].cube, otf, srf).data;
      CHECK(max_abs_diff(got[k].data, want) <= tol * max_abs(want));
    }
    std::vector<testset::Patch> wrong{{"p", random_cube(cfg.bands, s + 1, s, 50)}};
    CHECK_THROWS_AS(cam.measure(psf, wrong), InputError);
  }
}

TEST_CASE("per-band convolution (linear and circular) matches the CPU reference") {
  for (Precision p : device_precisions(runtime())) {
    for (ConvolutionMode mode : {ConvolutionMode::Linear, ConvolutionMode::Circular}) {
      CAPTURE(to_string(p));
      CAPTURE(int(mode));
      SystemConfig c = tiny_config(32, 3);  // sensor PSF 16 x 16
      c.convolution = mode;
      const Map2D h = random_heights(c.n, c.h_max_m(), 14);
      Simulator sim(runtime(), c, p);
      Camera cam(sim);
      sim.set_heights(h);
      sim.compute_psf();
      const RealStack psf = sim.psf_sensor();
      // Two scene shapes (non-square, and smaller than the PSF for circular folding).
      for (auto shape : {std::pair<std::size_t, std::size_t>{20, 30}, {12, 10}}) {
        const RealStack cube = random_cube(c.bands, shape.first, shape.second, 15);
        const RealStack got = cam.blur({cube}).front();
        const RealStack want = ref::convolve(cube, psf, mode);
        const auto d = diff(got.data, want.data);
        // Three FFTs over P = PY*PX points (P <= 4 H W here): rel. L2 <= 16 eps * 3 log2(P).
        const double tol = 16 * eps(p) * 3 * std::log2(double(shape.first * shape.second) * 4);
        CAPTURE(d.rel_l2);
        CHECK(d.rel_l2 <= tol);
      }
    }
  }
}

TEST_CASE("a batch of scenes gives the per-scene results, noise counters included") {
  SystemConfig c = tiny_config(32, 3);
  c.read_noise_sigma = 0.02;
  c.noise_seed = 99;
  const Precision p = runtime().has_fp64() ? Precision::F64 : Precision::F32;
  Simulator sim(runtime(), c, p);
  Camera cam(sim);
  sim.set_heights(random_heights(c.n, c.h_max_m(), 17));
  sim.compute_psf();
  const RealStack psf = sim.psf_sensor();
  std::vector<RealStack> cubes;
  for (unsigned k = 0; k < 3; ++k) cubes.push_back(random_cube(c.bands, 20, 18, 100 + k));
  const auto got = cam.images(cubes, no_skipping());
  REQUIRE(got.size() == 3);
  for (std::size_t k = 0; k < 3; ++k) {
    RealStack want = ref::sensor_integrate(ref::convolve(cubes[k], psf, c.convolution), sim.srf());
    ref::add_noise(want, c.read_noise_sigma, c.full_well_photons, c.noise_seed, k);
    CHECK(diff(got[k].data, want.data).max_abs <= 1e3 * eps(p));
  }
  // Batch size does not change a scene's result.
  const auto single = cam.images({cubes[0]}, no_skipping());
  CHECK(diff(single[0].data, got[0].data).max_abs <= 1e3 * eps(p));
}

TEST_CASE("a batch whose rows take more than one kernel launch gives each scene's own images and gradients") {
  // 11 scenes x 16 band pairs x 100 grid rows = 17,600 rows of the scene placement, over the
  // 16,384 rows of one launch (src/physics/row_launch.hpp): the second launch runs with a global
  // offset. Each scene must come out as it does alone (one launch).
  SystemConfig c = tiny_config(32, 31);
  c.convolution = ConvolutionMode::Circular;
  c.read_noise_sigma = 0;
  c.full_well_photons = 0;
  c.validate();
  const Precision p = Precision::F32;
  Camera cam(runtime(), c, p);
  cam.set_psf(random_psf(c, 41));
  std::vector<RealStack> cubes, g;
  for (unsigned k = 0; k < 11; ++k) {
    cubes.push_back(random_cube(c.bands, 100, 100, 200 + k));
    g.push_back(random_cube(3, 100, 100, 300 + k));
  }
  const auto batch = cam.images(cubes, no_skipping());
  const Camera::Gradient gb = cam.vjp(g, true);
  RealStack psf_sum(c.bands, c.sensor_size_px(), c.sensor_size_px(), 0.0);
  for (std::size_t k = 0; k < cubes.size(); ++k) {
    CAPTURE(k);
    const auto one = cam.images({cubes[k]}, no_skipping());
    const Camera::Gradient g1 = cam.vjp({g[k]}, true);
    CHECK(diff(one[0].data, batch[k].data).max_abs <= 1e3 * eps(p) * max_abs(one[0].data));
    CHECK(diff(g1.scenes[0].data, gb.scenes[k].data).max_abs <= 1e3 * eps(p) * max_abs(g1.scenes[0].data));
    for (std::size_t i = 0; i < psf_sum.size(); ++i) psf_sum.data[i] += g1.psf.data[i];
  }
  CHECK(diff(psf_sum.data, gb.psf.data).max_abs <= 1e3 * eps(p) * max_abs(gb.psf.data));
}

}  // TEST_SUITE
