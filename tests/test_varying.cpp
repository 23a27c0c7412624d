// Depth-layered and spatially varying imaging (include/qdo/physics/varying.hpp,
// kernels/varying.cl, src/physics/varying.cpp, the CPU references in varying_reference.hpp): the
// device operator against the double reference (both placements, float32 and float64, shifted
// PSFs), the adjoint ladder of the scene and PSF adjoints, the shift-invariant Camera as the K = 1
// case, the release's per-depth rule with real Simulator PSFs, overlap-add of real off-axis PSFs
// against the brute-force per-pixel model, the low-rank decomposition, the skipping of components
// that weigh nothing, and the refusals.
#include <algorithm>
#include <cmath>
#include <limits>
#include <random>

#include "adjoint_ladder.hpp"
#include "common.hpp"
#include "qdo/physics/camera.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/point_psf.hpp"
#include "qdo/physics/sensor_reference.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/physics/varying.hpp"
#include "qdo/physics/varying_reference.hpp"

using namespace qdo;
using namespace qdo::test;

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

// 5 bands (odd: the last band pair is half empty), S = 16 (n = 32).
SystemConfig varying_config(std::size_t bands = 5) {
  SystemConfig c = tiny_config(32, bands);
  c.read_noise_sigma = 0;
  c.full_well_photons = 0;
  c.validate();
  return c;
}

// K components of non-negative PSFs, each band summing to 1: (K * bands) x S x S.
RealStack random_psfs(std::size_t k, const SystemConfig& c, unsigned seed) {
  const std::size_t s = c.sensor_size_px();
  RealStack p = random_cube(k * c.bands, s, s, seed);
  for (std::size_t q = 0; q < p.planes; ++q) {
    double sum = 0;
    for (std::size_t i = 0; i < s * s; ++i) sum += p.plane(q)[i];
    for (std::size_t i = 0; i < s * s; ++i) p.plane(q)[i] /= sum;
  }
  return p;
}

// Component-wise shift_planes (the device's set_shifts on the host).
RealStack shifted(const RealStack& psfs, std::size_t bands, const std::vector<std::pair<long, long>>& sh) {
  RealStack out(psfs.planes, psfs.rows, psfs.cols);
  for (std::size_t k = 0; k < sh.size(); ++k) {
    const RealStack part = shift_planes(point_planes(psfs, k, bands), sh[k].first, sh[k].second);
    std::copy(part.data.begin(), part.data.end(), out.plane(k * bands));
  }
  return out;
}

RealStack as_stack(const std::vector<double>& x, std::size_t p, std::size_t r, std::size_t c) {
  RealStack s(p, r, c);
  REQUIRE(x.size() == s.size());
  s.data = x;
  return s;
}

// Thin-lens relief focusing a plane wave at the sensor (wrapped to one wave of h_max).
Map2D lens_heights(const SystemConfig& c) {
  const double wl = c.base_wavelength_nm * 1e-9, k = 2 * M_PI / wl, f = c.sensor_distance_m;
  Map2D h(c.n, c.n);
  for (std::size_t i = 0; i < c.n; ++i)
    for (std::size_t j = 0; j < c.n; ++j) {
      const double y = (double(i) - double(c.n / 2)) * c.pitch_m, x = (double(j) - double(c.n / 2)) * c.pitch_m;
      double phi = std::fmod(-k * (x * x + y * y) / (2 * f), 2 * M_PI);
      if (phi < 0) phi += 2 * M_PI;
      h(i, j) = phi / (2 * M_PI) * c.h_max_m();
    }
  return h;
}

// 4 bands, N = 64 at the small preset's pitch, sensor pixels 16 µm (S = 16), the band-limited
// angular spectrum (exact for tilted waves).
SystemConfig field_config() {
  SystemConfig c = tiny_config(64, 4);
  c.sensor_pitch_m = 16e-6;
  c.propagator = Propagator::AngularSpectrum;
  c.read_noise_sigma = 0;
  c.full_well_photons = 0;
  c.validate();
  return c;
}

template <typename F>
std::string refusal(F&& f) {
  try {
    f();
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

}  // namespace

TEST_SUITE("varying") {

TEST_CASE("device operator, scene, PSF and weight adjoints against the CPU reference (float32, float64; source, output; shifted PSFs; a skipped component)") {
  const SystemConfig cfg = varying_config();
  const std::size_t nb = cfg.bands, s = cfg.sensor_size_px(), kk = 3, h = 24, w = 20;
  const RealStack psfs = random_psfs(kk, cfg, 21);
  const std::vector<std::pair<long, long>> sh{{0, 0}, {2, -3}, {-1, 4}};
  const RealStack eff = shifted(psfs, nb, sh);
  const RealStack scene = random_cube(nb, h, w, 22);
  RealStack wts = random_cube(kk, h, w, 23);
  std::fill(wts.plane(2), wts.plane(2) + h * w, 0.0);  // component 2 is skipped (its weight gradient is not)
  RealStack g = uniform_stack(3, h, w, 24);
  for (Precision p : device_precisions(runtime()))
    for (PsfPlacement pl : {PsfPlacement::Source, PsfPlacement::Output}) {
      CAPTURE(to_string(p));
      CAPTURE(to_string(pl));
      VaryingCamera cam(runtime(), cfg, p, kk);
      cam.set_psfs(psfs);
      cam.set_shifts(sh);
      const RealStack img = cam.images(scene, wts, pl);
      const RealStack want = ref::varying_images(scene, eff, wts, cam.srf(), pl);
      // FFT convolution rounding of O(1) values on a grid of ~1000 points, summed over K components.
      const double tol = 64.0 * eps(p) * std::log2(double(4 * h * w)) * double(kk);
      const double e_img = max_abs_diff(img.data, want.data);
      const VaryingCamera::Gradient gr = cam.vjp(g, true, true, true);
      const ref::VaryingGradient wg = ref::varying_vjp(scene, eff, wts, cam.srf(), pl, g);
      const RealStack want_psf = shifted(wg.psfs, nb, [&] {
        std::vector<std::pair<long, long>> neg;
        for (const auto& d : sh) neg.emplace_back(-d.first, -d.second);
        return neg;
      }());
      const double e_scene = max_abs_diff(gr.scene.data, wg.scene.data), e_psf = max_abs_diff(gr.psfs.data, want_psf.data);
      const double e_w = max_abs_diff(gr.weights.data, wg.weights.data);
      MESSAGE(to_string(p) << " " << to_string(pl) << ": |img - ref| = " << e_img << ", |vjp_scene - ref| = " << e_scene
                           << ", |vjp_psf - ref| = " << e_psf << ", |vjp_weights - ref| = " << e_w);
      CHECK(e_img <= tol * max_abs(want.data));
      CHECK(e_scene <= tol * max_abs(wg.scene.data));
      CHECK(e_psf <= tol * max_abs(want_psf.data));
      CHECK(e_w <= tol * max_abs(wg.weights.data));
      CHECK(max_abs(want.data) > 0.1);
      // The skipped component: no PSF gradient, but a weight gradient.
      CHECK(max_abs(point_planes(gr.psfs, 2, nb).data) == 0.0);
      CHECK(max_abs(point_planes(gr.weights, 2, 1).data) > 1e-3);
      const VaryingReport& rep = cam.last_report();
      CHECK(rep.kept == std::vector<std::size_t>{0, 1});
      CHECK(rep.skipped == std::vector<std::size_t>{2});
      CHECK(rep.grid_rows >= h + s / 2);
      CHECK(rep.grid_cols >= w + s / 2);
      const std::size_t pairs = (nb + 1) / 2;
      // Source: Pb forward per component, accumulated in frequency: 2 inverse for the image.
      // Output: Pb forward once, 2 inverse per component.
      CHECK(rep.forward_ffts == (pl == PsfPlacement::Source ? 2 * pairs : pairs));
      CHECK(rep.inverse_ffts == (pl == PsfPlacement::Source ? 2 : 2 * 2));
      CHECK(cam.otf_builds() == kk);  // 2 by images(), the skipped one's by the weight gradient
      cam.images(scene, wts, pl);
      CHECK(cam.last_report().otf_builds == 0);  // reused
      CHECK(cam.otf_builds() == kk);
    }
}

TEST_CASE("adjoint ladder: scene, PSF and weight adjoints, both placements (device float64 and CPU reference)") {
  const SystemConfig cfg = varying_config(4);
  const std::size_t nb = cfg.bands, s = cfg.sensor_size_px(), kk = 3, h = 20, w = 18;
  const RealStack psf0 = random_psfs(kk, cfg, 31);
  const RealStack scene0 = random_cube(nb, h, w, 32);
  const RealStack wts = random_cube(kk, h, w, 33);
  const std::vector<std::pair<long, long>> sh{{1, 0}, {0, 0}, {-2, 3}};
  const Eigen::MatrixXd srf = sensor_response(cfg);
  const std::size_t n_psf = psf0.size(), n_scene = scene0.size(), n_w = wts.size(), n_img = 3 * h * w;
  const bool f64 = runtime().has_fp64();
  std::unique_ptr<VaryingCamera> cam;
  if (skip_unless(f64, "device float64 varying ladder: the device has no float64")) {
    cam = std::make_unique<VaryingCamera>(runtime(), cfg, Precision::F64, kk);
    cam->set_shifts(sh);
  }
  std::uint64_t seed = 300;
  for (PsfPlacement pl : {PsfPlacement::Source, PsfPlacement::Output}) {
    const std::string m = to_string(pl);
    std::vector<Stage> stages;
    Stage rp("reference " + m + ": PSFs -> image", n_psf, n_img);
    rp.forward = [&](const std::vector<double>& x) { return ref::varying_images(scene0, as_stack(x, kk * nb, s, s), wts, srf, pl).data; };
    rp.vjp = [&](const std::vector<double>& x, const std::vector<double>& g) {
      return ref::varying_vjp(scene0, as_stack(x, kk * nb, s, s), wts, srf, pl, as_stack(g, 3, h, w)).psfs.data;
    };
    rp.jvp = [f = rp.forward](const std::vector<double>&, const std::vector<double>& d) { return f(d); };
    stages.push_back(rp);
    Stage rs("reference " + m + ": scene -> image", n_scene, n_img);
    rs.forward = [&](const std::vector<double>& x) { return ref::varying_images(as_stack(x, nb, h, w), psf0, wts, srf, pl).data; };
    rs.vjp = [&](const std::vector<double>&, const std::vector<double>& g) {
      return ref::varying_vjp(scene0, psf0, wts, srf, pl, as_stack(g, 3, h, w)).scene.data;
    };
    rs.jvp = [f = rs.forward](const std::vector<double>&, const std::vector<double>& d) { return f(d); };
    stages.push_back(rs);
    Stage rw("reference " + m + ": weights -> image", n_w, n_img);
    rw.forward = [&](const std::vector<double>& x) { return ref::varying_images(scene0, psf0, as_stack(x, kk, h, w), srf, pl).data; };
    rw.vjp = [&](const std::vector<double>& x, const std::vector<double>& g) {
      return ref::varying_vjp(scene0, psf0, as_stack(x, kk, h, w), srf, pl, as_stack(g, 3, h, w)).weights.data;
    };
    rw.jvp = [f = rw.forward](const std::vector<double>&, const std::vector<double>& d) { return f(d); };
    stages.push_back(rw);
    if (cam) {
      VaryingCamera* cp = cam.get();
      Stage dp("device f64 " + m + ": PSFs -> image", n_psf, n_img);
      dp.forward = [&, cp](const std::vector<double>& x) {
        cp->set_psfs(as_stack(x, kk * nb, s, s));
        return cp->images(scene0, wts, pl).data;
      };
      dp.vjp = [&, cp](const std::vector<double>& x, const std::vector<double>& g) {
        cp->set_psfs(as_stack(x, kk * nb, s, s));
        cp->images(scene0, wts, pl);
        const auto gr = cp->vjp(as_stack(g, 3, h, w), false, true);
        CHECK(gr.scene.size() == 0);
        return gr.psfs.data;
      };
      dp.jvp = [f = dp.forward](const std::vector<double>&, const std::vector<double>& d) { return f(d); };
      stages.push_back(dp);
      Stage ds("device f64 " + m + ": scene -> image", n_scene, n_img);
      ds.forward = [&, cp](const std::vector<double>& x) {
        cp->set_psfs(psf0);
        return cp->images(as_stack(x, nb, h, w), wts, pl).data;
      };
      ds.vjp = [&, cp](const std::vector<double>& x, const std::vector<double>& g) {
        cp->set_psfs(psf0);
        cp->images(as_stack(x, nb, h, w), wts, pl);
        const auto gr = cp->vjp(as_stack(g, 3, h, w), true, false);
        CHECK(gr.psfs.size() == 0);
        return gr.scene.data;
      };
      ds.jvp = [f = ds.forward](const std::vector<double>&, const std::vector<double>& d) { return f(d); };
      stages.push_back(ds);
      Stage dw("device f64 " + m + ": weights -> image", n_w, n_img);
      dw.forward = [&, cp](const std::vector<double>& x) {
        cp->set_psfs(psf0);
        return cp->images(scene0, as_stack(x, kk, h, w), pl).data;
      };
      dw.vjp = [&, cp](const std::vector<double>& x, const std::vector<double>& g) {
        cp->set_psfs(psf0);
        cp->images(scene0, as_stack(x, kk, h, w), pl);
        const auto gr = cp->vjp(as_stack(g, 3, h, w), false, false, true);
        CHECK(gr.scene.size() == 0);
        return gr.weights.data;
      };
      dw.jvp = [f = dw.forward](const std::vector<double>&, const std::vector<double>& d) { return f(d); };
      stages.push_back(dw);
    }
    for (Stage& st : stages) {
      st.dot_tol = 1e-12;
      st.fd_tol = 1e-8;  // linear maps: the central difference is exact up to rounding
      check_ladder(st, seed += 10);
    }
  }
}

TEST_CASE("K = 1 with w = 1 is the shift-invariant Camera; a depth map at one depth is the Camera with that depth's PSF") {
  for (Precision p : device_precisions(runtime())) {
    CAPTURE(to_string(p));
    const SystemConfig cfg = varying_config(4);
    const std::size_t nb = cfg.bands, h = 22, w = 26;
    const RealStack scene = random_cube(nb, h, w, 41);
    const double tol = 64.0 * eps(p) * std::log2(double(4 * h * w));
    Camera cam(runtime(), cfg, p);
    // K = 1, w = 1.
    const RealStack psf1 = random_psfs(1, cfg, 42);
    cam.set_psf(psf1);
    const RealStack want1 = cam.images({scene}, no_skipping())[0];
    for (PsfPlacement pl : {PsfPlacement::Source, PsfPlacement::Output}) {
      VaryingCamera v(runtime(), cfg, p, 1);
      v.set_psfs(psf1);
      const RealStack got = v.images(scene, RealStack(1, h, w), pl);  // all-zero weights: skipped
      CHECK(max_abs(got.data) == 0.0);
      CHECK(v.last_report().skipped == std::vector<std::size_t>{0});
      CHECK(v.last_report().forward_ffts == 0);
      RealStack ones(1, h, w);
      std::fill(ones.data.begin(), ones.data.end(), 1.0);
      const RealStack img = v.images(scene, ones, pl);
      CHECK(max_abs_diff(img.data, want1.data) <= tol * max_abs(want1.data));
    }
    // Three layers, every pixel at the middle one's depth.
    const std::vector<double> layers{0.5, 2.0, kInf};
    const RealStack psf3 = random_psfs(3, cfg, 43);
    cam.set_psf(point_planes(psf3, 1, nb));
    const RealStack want = cam.images({scene}, no_skipping())[0];
    const RealStack wts = depth_layer_weights(Map2D(h, w, 1.9), layers, h, w);
    for (PsfPlacement pl : {PsfPlacement::Source, PsfPlacement::Output}) {
      VaryingCamera v(runtime(), cfg, p, 3);
      v.set_psfs(psf3);
      const RealStack img = v.images(scene, wts, pl);
      CHECK(v.last_report().kept == std::vector<std::size_t>{1});
      CHECK(max_abs_diff(img.data, want.data) <= tol * max_abs(want.data));
    }
  }
}

TEST_CASE("depth layers from a Simulator (object points on axis): the output placement is the release's rule from Camera::blur per depth") {
  SystemConfig cfg = varying_config(4);
  // z = 1.56 mm, NA ~ 0.04: a point at 5 mm or 20 mm is well out of focus, infinity in focus.
  const std::vector<double> layers{0.005, 0.02, kInf};
  for (double d : layers) cfg.object_points.push_back(ObjectPoint{d, 0, 0});
  cfg.validate();
  const std::size_t nb = cfg.bands, h = 24, w = 24;
  const Precision p = runtime().has_fp64() ? Precision::F64 : Precision::F32;
  Simulator sim(runtime(), cfg, p);
  sim.set_heights(lens_heights(cfg));
  sim.compute_psf();
  const RealStack stack = sim.psf_sensor();
  REQUIRE(stack.planes == 3 * nb);
  // The depths' PSFs differ (otherwise the test could not tell layers apart).
  CHECK(max_abs_diff(point_planes(stack, 0, nb).data, point_planes(stack, 2, nb).data) > 1e-3);
  // Depth map: three vertical bands of depth, with values between the layers.
  Map2D depth(h, w);
  for (std::size_t y = 0; y < h; ++y)
    for (std::size_t x = 0; x < w; ++x) depth(y, x) = x < 8 ? 0.006 : x < 16 ? 0.015 : 40.0;
  const RealStack wts = depth_layer_weights(depth, layers, h, w);
  CHECK(wts(0, 3, 2) == 1.0);
  CHECK(wts(1, 3, 10) == 1.0);
  CHECK(wts(1, 3, 10) + wts(0, 3, 10) + wts(2, 3, 10) == 1.0);
  CHECK(wts(2, 3, 20) == 1.0);  // 1/40 m is nearer 0 diopters than 1/0.02 m
  const RealStack scene = random_cube(nb, h, w, 51);
  VaryingCamera v(sim);
  CHECK(v.components() == 3);
  const RealStack img = v.images(scene, wts, PsfPlacement::Output);
  // By hand: each depth's blurred cube (Camera::blur), each pixel taken from its own depth's.
  Camera cam(runtime(), point_config(cfg, 0), p);
  RealStack blur(nb, h, w);
  for (std::size_t k = 0; k < 3; ++k) {
    cam.set_psf(point_planes(stack, k, nb));
    const RealStack bk = cam.blur({scene})[0];
    for (std::size_t b = 0; b < nb; ++b)
      for (std::size_t i = 0; i < h * w; ++i) blur.plane(b)[i] += wts.plane(k)[i] * bk.plane(b)[i];
  }
  const RealStack want = ref::sensor_integrate(blur, cam.srf());
  const double tol = 64.0 * eps(p) * std::log2(double(4 * h * w)) * 3;
  CHECK(max_abs_diff(img.data, want.data) <= tol * max_abs(want.data));
  // The source placement differs from the output placement at the depth edges only.
  const RealStack src = v.images(scene, wts, PsfPlacement::Source);
  CHECK(max_abs_diff(src.data, img.data) > 1e-4);
}

TEST_CASE("field: overlap-add of real off-axis PSFs (asm, 3 x 3 angle grid) against the brute-force per-pixel reference") {
  SystemConfig cfg = field_config();
  const double amax = max_field_angle_deg(cfg, kInf);
  REQUIRE(amax > 0);
  const double a = 0.8 * amax;
  const FieldGrid fg = field_grid(cfg, kInf, {-a, 0, a}, {-a, 0, a});
  REQUIRE(fg.points.size() == 9);
  cfg.object_points = fg.points;
  cfg.validate();
  // The grid's image offsets: inverted (-z tan θ), symmetric, several pixels.
  CHECK(fg.cols_px[0] > 1.0);
  CHECK(fg.cols_px[2] == doctest::Approx(-fg.cols_px[0]));
  CHECK(fg.rows_px[1] == 0.0);
  CHECK(fg.shifts_px[0].first == std::lround(fg.rows_px[0]));
  CHECK(fg.shifts_px[0].second == std::lround(fg.cols_px[0]));
  const std::size_t nb = cfg.bands, h = 28, w = 24;
  const Precision p = runtime().has_fp64() ? Precision::F64 : Precision::F32;
  Simulator sim(runtime(), cfg, p);
  sim.set_heights(lens_heights(cfg));
  sim.compute_psf();
  const RealStack stack = sim.psf_sensor();
  // Hats: non-negative, summing to 1 at every pixel.
  const RealStack wts = field_grid_weights(h, w, fg.rows_px, fg.cols_px);
  for (std::size_t i = 0; i < h * w; ++i) {
    double sum = 0;
    for (std::size_t k = 0; k < 9; ++k) {
      CHECK(wts.plane(k)[i] >= 0);
      sum += wts.plane(k)[i];
    }
    CHECK(sum == doctest::Approx(1.0).epsilon(1e-12));
  }
  // Recentring: the host recentre_on_chief_ray is the device's shift.
  RealStack eff(9 * nb, stack.rows, stack.cols);
  for (std::size_t k = 0; k < 9; ++k) {
    const RealStack r = recentre_on_chief_ray(point_planes(stack, k, nb), cfg, fg.points[k]);
    std::copy(r.data.begin(), r.data.end(), eff.plane(k * nb));
  }
  // The recentred corner PSF's energy centroid lies near the axis.
  {
    const RealStack c0 = point_planes(eff, 0, nb);
    double sy = 0, sx = 0, sw = 0;
    for (std::size_t y = 0; y < c0.rows; ++y)
      for (std::size_t x = 0; x < c0.cols; ++x) {
        sw += c0(1, y, x);
        sy += c0(1, y, x) * double(y);
        sx += c0(1, y, x) * double(x);
      }
    CHECK(std::fabs(sy / sw - double(c0.rows / 2)) < 1.5);
    CHECK(std::fabs(sx / sw - double(c0.cols / 2)) < 1.5);
  }
  VaryingCamera v(sim);
  v.set_shifts(fg.shifts_px);
  const RealStack scene = random_cube(nb, h, w, 61);
  for (PsfPlacement pl : {PsfPlacement::Source, PsfPlacement::Output}) {
    CAPTURE(to_string(pl));
    const RealStack img = v.images(scene, wts, pl);
    const RealStack brute = ref::varying_images_brute_force(scene, eff, wts, v.srf(), pl);
    const double tol = 64.0 * eps(p) * std::log2(double(4 * h * w)) * 9;
    const double e = max_abs_diff(img.data, brute.data);
    MESSAGE("field " << to_string(pl) << ": |overlap-add - brute force| = " << e << " (max " << max_abs(brute.data) << ")");
    CHECK(e <= tol * max_abs(brute.data));
    CHECK(max_abs(brute.data) > 0.05);
  }
  // The field matters: the shift-invariant on-axis image differs from the varying one.
  Camera cam(runtime(), point_config(cfg, 4), p);
  cam.set_psf(point_planes(eff, 4, nb));
  const RealStack inv = cam.images({scene}, no_skipping())[0];
  CHECK(max_abs_diff(inv.data, v.images(scene, wts, PsfPlacement::Source).data) > 1e-3);
}

TEST_CASE("low rank: full rank reproduces overlap-add, the error falls as the rank grows") {
  const SystemConfig cfg = varying_config(4);
  const std::size_t nb = cfg.bands, kk = 6, h = 20, w = 22;
  // Smoothly varying field PSFs: blends of two random stacks (rank 2 plus a small random part).
  const RealStack a = random_psfs(1, cfg, 71), b = random_psfs(1, cfg, 72), noise = random_psfs(kk, cfg, 73);
  RealStack psfs(kk * nb, a.rows, a.cols);
  for (std::size_t k = 0; k < kk; ++k) {
    const double t = double(k) / double(kk - 1);
    for (std::size_t i = 0; i < a.size(); ++i)
      psfs.plane(k * nb)[i] = (1 - t) * a.data[i] + t * b.data[i] + 0.05 * noise.plane(k * nb)[i];
  }
  const RealStack wts = field_grid_weights(h, w, {0.0}, {-8, -5, -2, 1, 4, 7});
  REQUIRE(wts.planes == kk);
  const RealStack scene = random_cube(nb, h, w, 74);
  const Precision p = runtime().has_fp64() ? Precision::F64 : Precision::F32;
  for (PsfPlacement pl : {PsfPlacement::Source, PsfPlacement::Output}) {
    CAPTURE(to_string(pl));
    VaryingCamera full(runtime(), cfg, p, kk);
    full.set_psfs(psfs);
    const RealStack ola = full.images(scene, wts, pl);
    // The PSF truncation error falls with the rank (an SVD); the image error, not a projection of
    // its own, falls from rank 1 to rank 2 (the PSFs are rank 2 plus 5 % noise) and vanishes at K.
    double err1 = 0, prev_trunc = kInf;
    for (std::size_t r = 1; r <= kk; ++r) {
      const LowRankPsf lr = low_rank_psf(psfs, nb, r);
      REQUIRE(lr.psfs.planes == r * nb);
      VaryingCamera v(runtime(), cfg, p, r);
      v.set_psfs(lr.psfs);
      const RealStack img = v.images(scene, combine_weights(wts, lr.coeff), pl);
      const double err = max_abs_diff(img.data, ola.data) / max_abs(ola.data);
      MESSAGE(to_string(pl) << " rank " << r << ": image error " << err << ", PSF truncation " << lr.truncation_error);
      CHECK(lr.truncation_error <= prev_trunc);
      if (r == 1) {
        err1 = err;
        CHECK(err > 1e-3);
      } else {
        CHECK(err <= 0.25 * err1);
      }
      if (r == 2) CHECK(lr.truncation_error < 0.2 * prev_trunc);
      if (r == kk) {
        CHECK(lr.truncation_error < 1e-6);
        CHECK(err <= 64.0 * eps(p) * std::log2(double(4 * h * w)) * double(kk));
      }
      prev_trunc = lr.truncation_error;
    }
  }
}

TEST_CASE("skipping: absent depth layers and field points off the crop are not computed, the output unchanged") {
  const SystemConfig cfg = varying_config(4);
  const std::size_t nb = cfg.bands, h = 16, w = 18, pairs = (nb + 1) / 2;
  const Precision p = runtime().has_fp64() ? Precision::F64 : Precision::F32;
  const double tol = 64.0 * eps(p) * std::log2(double(4 * h * w)) * 4;
  const RealStack scene = random_cube(nb, h, w, 81);
  // A depth map using 2 of 4 layers.
  const RealStack psf4 = random_psfs(4, cfg, 82);
  Map2D depth(h, w);
  for (std::size_t y = 0; y < h; ++y)
    for (std::size_t x = 0; x < w; ++x) depth(y, x) = (x + y) % 3 ? 0.1 : kInf;
  const std::vector<double> layers{0.1, 0.5, 2.0, kInf};
  const RealStack wts = depth_layer_weights(depth, layers, h, w);
  for (PsfPlacement pl : {PsfPlacement::Source, PsfPlacement::Output}) {
    CAPTURE(to_string(pl));
    VaryingCamera v(runtime(), cfg, p, 4);
    v.set_psfs(psf4);
    const RealStack img = v.images(scene, wts, pl);
    const VaryingReport& rep = v.last_report();
    CHECK(rep.kept == std::vector<std::size_t>{0, 3});
    CHECK(rep.skipped == std::vector<std::size_t>{1, 2});
    CHECK(rep.otf_builds == 2);
    CHECK(rep.forward_ffts == (pl == PsfPlacement::Source ? 2 * pairs : pairs));
    CHECK(rep.inverse_ffts == (pl == PsfPlacement::Source ? 2 : 4));
    CHECK(rep.to_json().find("\"skipped\":[1,2]") != std::string::npos);
    // Without skipping: the reference sums all four components.
    const RealStack want = ref::varying_images(scene, psf4, wts, v.srf(), pl);
    CHECK(max_abs_diff(img.data, want.data) <= tol * max_abs(want.data));
    // The gradient of a skipped component's PSF is exactly zero, a kept one's is not.
    const auto gr = v.vjp(uniform_stack(3, h, w, 83), false, true);
    CHECK(max_abs(point_planes(gr.psfs, 1, nb).data) == 0.0);
    CHECK(max_abs(point_planes(gr.psfs, 0, nb).data) > 0.0);
  }
  // Field points whose hat support misses the crop: a 5 x 5 grid of offsets +-30, +-15, 0 around a
  // 16 x 18 crop (pixels -8 .. 7, -9 .. 8 from the axis) keeps the 3 x 3 inner points.
  const std::vector<double> off{-30, -15, 0, 15, 30};
  const RealStack fw = field_grid_weights(h, w, off, off);
  const RealStack psf25 = random_psfs(25, cfg, 84);
  VaryingCamera v(runtime(), cfg, p, 25);
  v.set_psfs(psf25);
  const RealStack img = v.images(scene, fw, PsfPlacement::Source);
  const VaryingReport& rep = v.last_report();
  CHECK(rep.kept == std::vector<std::size_t>{6, 7, 8, 11, 12, 13, 16, 17, 18});
  CHECK(rep.skipped.size() == 16);
  CHECK(rep.forward_ffts == 9 * pairs);
  CHECK(rep.otf_builds == 9);
  const RealStack want = ref::varying_images(scene, psf25, fw, v.srf(), PsfPlacement::Source);
  CHECK(max_abs_diff(img.data, want.data) <= tol * max_abs(want.data));
}

TEST_CASE("refusals before any work: depth map size, distances, weight shapes, K mismatch, shifts, rank, offsets") {
  const SystemConfig cfg = varying_config(4);
  const std::size_t nb = cfg.bands, h = 12, w = 10;
  // Depth maps and distances.
  std::string e = refusal([&] { depth_layer_weights(Map2D(h, w + 1, 1.0), {1.0}, h, w); });
  CHECK(e.find("12 x 11") != std::string::npos);
  CHECK(e.find("12 x 10") != std::string::npos);
  Map2D depth(h, w, 1.0);
  depth(3, 4) = -2.0;
  e = refusal([&] { depth_layer_weights(depth, {1.0}, h, w); });
  CHECK(e.find("depth(3, 4)") != std::string::npos);
  CHECK(e.find("-2") != std::string::npos);
  CHECK(e.find("> 0") != std::string::npos);
  depth(3, 4) = 0.0;
  CHECK(refusal([&] { depth_layer_weights(depth, {1.0}, h, w); }).find("depth(3, 4)") != std::string::npos);
  depth(3, 4) = std::nan("");
  CHECK(refusal([&] { depth_layer_weights(depth, {1.0}, h, w); }).find("nan") != std::string::npos);
  depth(3, 4) = kInf;  // infinity is a distance
  CHECK(refusal([&] { depth_layer_weights(depth, {1.0, kInf}, h, w); }).empty());
  e = refusal([&] { depth_layer_weights(Map2D(h, w, 1.0), {1.0, 0.0}, h, w); });
  CHECK(e.find("depth layer[1]") != std::string::npos);
  CHECK(refusal([&] { depth_layer_weights(Map2D(h, w, 1.0), {}, h, w); }).find("at least one") != std::string::npos);
  // The camera's inputs.
  VaryingCamera v(runtime(), cfg, Precision::F32, 2);
  const RealStack scene = random_cube(nb, h, w, 91);
  CHECK_THROWS_AS(v.images(scene, RealStack(2, h, w), PsfPlacement::Source), Error);  // no PSF yet
  e = refusal([&] { v.set_psfs(random_psfs(3, cfg, 92)); });
  CHECK(e.find("12 x 16 x 16") != std::string::npos);
  CHECK(e.find("8 x 16 x 16") != std::string::npos);
  v.set_psfs(random_psfs(2, cfg, 92));
  e = refusal([&] { v.images(scene, RealStack(3, h, w), PsfPlacement::Source); });
  CHECK(e.find("weights") != std::string::npos);
  CHECK(e.find("2 x 12 x 10") != std::string::npos);
  e = refusal([&] { v.images(scene, RealStack(2, h + 1, w), PsfPlacement::Output); });
  CHECK(e.find("13 x 10") != std::string::npos);
  RealStack bad = scene;
  bad(1, 2, 3) = kInf;
  CHECK(refusal([&] { v.images(bad, RealStack(2, h, w), PsfPlacement::Source); }).find("scene(1, 2, 3)") != std::string::npos);
  CHECK(refusal([&] { v.images(random_cube(nb + 1, h, w, 1), RealStack(2, h, w), PsfPlacement::Source); }).find("scene bands") != std::string::npos);
  CHECK(refusal([&] { v.vjp(RealStack(3, h, w)); }).find("without a preceding images()") != std::string::npos);
  CHECK(refusal([&] { v.set_shifts({{0, 0}}); }).find("one (dy, dx) per component") != std::string::npos);
  CHECK(refusal([&] { v.set_shifts({{0, 0}, {16, 0}}); }).find("(16, 0)") != std::string::npos);
  v.images(scene, RealStack(2, h, w), PsfPlacement::Source);
  CHECK(refusal([&] { v.vjp(RealStack(3, h, w + 2)); }).find("g_rgb") != std::string::npos);
  CHECK(refusal([&] { psf_placement_from_string("middle"); }).find("middle") != std::string::npos);
  // A one-design PSF source is one component.
  StackPsfSource src(runtime(), cfg, Precision::F32, random_psfs(1, cfg, 93), "test stack");
  CHECK(VaryingCamera(src).components() == 1);
  // Circular convolution is not this operator's.
  SystemConfig circ = cfg;
  circ.convolution = ConvolutionMode::Circular;
  CHECK(refusal([&] { VaryingCamera(runtime(), circ, Precision::F32, 1); }).find("linear") != std::string::npos);
  // Low rank and offsets.
  CHECK(refusal([&] { low_rank_psf(random_psfs(3, cfg, 94), nb, 4); }).find("1 .. K = 3") != std::string::npos);
  CHECK(refusal([&] { low_rank_psf(random_psfs(3, cfg, 94), 5, 1); }).find("divisor") != std::string::npos);
  CHECK(refusal([&] { field_grid_weights(h, w, {0, 5, 5}, {0}); }).find("rows_px[2]") != std::string::npos);
  CHECK(refusal([&] { field_grid_weights(h, w, {0}, {1, std::nan("")}); }).find("cols_px[1]") != std::string::npos);
  CHECK(refusal([&] { field_grid(cfg, -1.0, {0}, {0}); }).find("-1") != std::string::npos);
}

}  // TEST_SUITE
