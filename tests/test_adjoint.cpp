// The adjoint ladder (double precision, CPU reference): a dot-product test for each
// forward/adjoint pair, a directional finite difference of the whole chain, central differences
// on sampled parameters; then the OpenCL adjoint against the CPU reference.
#include <cmath>
#include <random>

#include "common.hpp"
#include "qdo/adjoint.hpp"
#include "qdo/cpu_reference.hpp"
#include "qdo/simulator.hpp"

using namespace qdo;
using namespace qdo::test;

namespace {

double dot(const std::vector<double>& a, const std::vector<double>& b) {
  double s = 0;
  for (std::size_t i = 0; i < a.size(); ++i) s += a[i] * b[i];
  return s;
}
double cdot(const std::vector<cdouble>& a, const std::vector<cdouble>& b) {  // Re <a, b>
  double s = 0;
  for (std::size_t i = 0; i < a.size(); ++i) s += (std::conj(a[i]) * b[i]).real();
  return s;
}
RealStack random_stack(std::size_t p, std::size_t r, std::size_t c, unsigned seed, double lo = -1, double hi = 1) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(lo, hi);
  RealStack s(p, r, c);
  for (auto& v : s.data) v = u(rng);
  return s;
}
Map2D random_map(std::size_t n, unsigned seed, double scale) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> u(0, scale);
  Map2D m(n, n);
  for (auto& v : m.data) v = u(rng);
  return m;
}
// A smooth design well inside (0, h_max) so finite differences never hit the clamp.
Map2D smooth_heights(const SystemConfig& c, unsigned seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0, 2 * M_PI);
  const double a = u(rng), b = u(rng);
  Map2D h(c.n, c.n);
  for (std::size_t i = 0; i < c.n; ++i)
    for (std::size_t j = 0; j < c.n; ++j)
      h(i, j) = c.h_max_m() * (0.5 + 0.3 * std::sin(0.37 * double(i) + a) * std::cos(0.23 * double(j) + b));
  return h;
}
constexpr double kDotTol = 1e-11;  // relative, double precision with O(M² log M) operations

}  // namespace

TEST_SUITE("adjoint") {
  TEST_CASE("dot-product tests: propagation, resampling, normalisation, the whole PSF chain") {
    SystemConfig c = tiny_config(32, 3);
    c.sensor_pitch_m = 10e-6;
    for (Propagator p : {Propagator::Fresnel, Propagator::AngularSpectrum}) {
      CAPTURE(int(p));
      const std::size_t m = 48;
      ComplexStack x(3, m, m), y(3, m, m);
      std::mt19937_64 rng(5);
      std::normal_distribution<double> nd;
      for (auto& v : x.data) v = cdouble(nd(rng), nd(rng));
      for (auto& v : y.data) v = cdouble(nd(rng), nd(rng));
      ComplexStack ax = x, aty = y;
      ref::propagate(ax, c.wavelengths_nm(), c.pitch_m, c.sensor_distance_m, p);
      ref::propagate(aty, c.wavelengths_nm(), c.pitch_m, -c.sensor_distance_m, p);
      const double l = cdot(ax.data, y.data), r = cdot(x.data, aty.data);
      CHECK(std::fabs(l - r) <= kDotTol * std::fabs(l));
    }
    const AreaWeights w = AreaWeights::make(c.n, c.pitch_m, c.sensor_size_px(), c.sensor_pitch_m);
    const RealStack x = random_stack(3, c.n, c.n, 6), y = random_stack(3, w.s, w.s, 7);
    const double l = dot(ref::resample_area(x, w).data, y.data), r = dot(x.data, ref::resample_area_adjoint(y, w).data);
    CHECK(std::fabs(l - r) <= kDotTol * std::fabs(l));
    // The transposed weights describe the same operator.
    const AreaWeights wt = w.transposed();
    CHECK(diff(ref::resample_area(y, wt).data, ref::resample_area_adjoint(y, w).data).max_abs <= 1e-14);
    // Normalisation (a nonlinear stage: its JVP and VJP at a point).
    RealStack pos = random_stack(3, 8, 8, 8, 0.1, 1.0);
    std::vector<double> sums;
    for (std::size_t b = 0; b < 3; ++b) {
      double s = 0;
      for (std::size_t i = 0; i < 64; ++i) s += pos.plane(b)[i];
      sums.push_back(s);
    }
    RealStack yn = pos;
    ref::normalize_planes(yn);
    const RealStack dx = random_stack(3, 8, 8, 9), g = random_stack(3, 8, 8, 10);
    const double ln = dot(ref::normalize_jvp(dx, yn, sums).data, g.data), rn = dot(dx.data, ref::normalize_vjp(g, yn, sums).data);
    CHECK(std::fabs(ln - rn) <= kDotTol * std::fabs(ln));
    // The whole chain H -> sensor PSF.
    const Map2D h = smooth_heights(c, 1), dh = random_map(c.n, 2, 1e-8);
    const RealStack gs = random_stack(c.bands, c.sensor_size_px(), c.sensor_size_px(), 3);
    const double lc = dot(ref::psf_sensor_jvp(c, h, dh).data, gs.data);
    const double rc = dot(dh.data, ref::psf_sensor_vjp(c, h, gs).data);
    CHECK(std::fabs(lc - rc) <= 1e-9 * std::fabs(lc));
  }

  TEST_CASE("directional and central finite differences of the PSF chain") {
    SystemConfig c = tiny_config(32, 3);
    const Map2D h = smooth_heights(c, 4);
    const RealStack g = random_stack(c.bands, c.sensor_size_px(), c.sensor_size_px(), 5);
    auto loss = [&](const Map2D& hh) { return dot(ref::psf_sensor_stack(c, hh).data, g.data); };
    const Map2D grad = ref::psf_sensor_vjp(c, h, g);
    // Directional: (L(h + e d) - L(h - e d)) / 2e against <grad, d>.
    const Map2D d = random_map(c.n, 6, 1.0);
    const double e = 1e-12;  // metres: phase steps ~1e-5 rad
    Map2D hp = h, hm = h;
    for (std::size_t i = 0; i < h.data.size(); ++i) {
      hp.data[i] += e * d.data[i];
      hm.data[i] -= e * d.data[i];
    }
    const double fd = (loss(hp) - loss(hm)) / (2 * e), an = dot(grad.data, d.data);
    CAPTURE(fd);
    CAPTURE(an);
    CHECK(std::fabs(fd - an) <= 1e-6 * std::fabs(an));
    // Central differences on 12 sampled heights (inside the aperture).
    std::mt19937_64 rng(7);
    int checked = 0;
    while (checked < 12) {
      const std::size_t i = rng() % c.n, j = rng() % c.n;
      const double y = (double(i) - 16) * c.pitch_m, x = (double(j) - 16) * c.pitch_m;
      if (x * x + y * y > c.aperture_radius() * c.aperture_radius()) continue;
      Map2D a = h, b = h;
      a(i, j) += 1e-11;
      b(i, j) -= 1e-11;
      const double fdij = (loss(a) - loss(b)) / 2e-11;
      CAPTURE(i);
      CAPTURE(j);
      CHECK(std::fabs(fdij - grad(i, j)) <= 1e-5 * std::fabs(grad(i, j)) + 1e-6 * std::sqrt(dot(grad.data, grad.data) / double(grad.data.size())));
      ++checked;
    }
  }

  TEST_CASE("parameterization and quantizer adjoints") {
    const std::size_t n = 16;
    const double hmax = 1.5e-6;
    for (Parameterization p : {Parameterization::Full2D, Parameterization::Radial, Parameterization::Quad}) {
      CAPTURE(int(p));
      std::vector<double> params(parameter_count(p, n));
      std::mt19937_64 rng(3);
      std::uniform_real_distribution<double> u(0.1 * hmax, 0.9 * hmax);
      for (double& v : params) v = u(rng);
      std::vector<double> dp(params.size());
      for (double& v : dp) v = u(rng);
      const Map2D g = random_map(n, 8, 1.0);
      // Expansion is linear inside the clamp: <E dp, g> = <dp, E^T g>.
      const Map2D edp = expand_parameters(p, dp, n, 1e9);
      const double l = dot(edp.data, g.data), r = dot(dp, ref::expand_parameters_vjp(p, params, n, hmax, g));
      CHECK(std::fabs(l - r) <= 1e-12 * std::fabs(l));
    }
    // Quantizer: the blend passes (1 - alpha) to H_f; offsets get alpha h_max 0.5/denom per sample.
    Quantizer q;
    q.levels = 4;
    q.offsets = {0.0, 0.2, -0.3, 0.1};
    const Map2D hf = random_heights(n, hmax, 9);
    const Map2D g = random_map(n, 10, 1.0);
    const double alpha = 0.7;
    const auto vjp = ref::quantize_vjp(hf, hmax, q, alpha, g);
    for (std::size_t i = 0; i < hf.data.size(); ++i) CHECK(vjp.g_full.data[i] == doctest::Approx(0.3 * g.data[i]));
    CHECK(ref::quantize_vjp(hf, hmax, q, alpha, g, true).g_full.data[5] == g.data[5]);
    for (int l = 1; l < 4; ++l) {
      Quantizer qp = q, qm = q;
      qp.offsets[std::size_t(l)] += 1e-4;
      qm.offsets[std::size_t(l)] -= 1e-4;
      const double fd = (dot(quantize_heights(hf, hmax, qp, alpha).data, g.data) -
                         dot(quantize_heights(hf, hmax, qm, alpha).data, g.data)) / 2e-4;
      CHECK(vjp.g_offsets[std::size_t(l)] == doctest::Approx(fd).epsilon(1e-8));
    }
  }

  TEST_CASE("the OpenCL adjoint matches the CPU reference adjoint") {
    for (Precision p : {Precision::F32, Precision::F64}) {
      if (p == Precision::F64 && !skip_unless(runtime().has_fp64(), "float64 cases: the device has no float64")) continue;
      CAPTURE(to_string(p));
      SystemConfig c = tiny_config(48, 4);
      c.sensor_pitch_m = 10e-6;
      const Map2D h = smooth_heights(c, 11);
      Simulator sim(runtime(), c, p);
      sim.set_heights(h);
      sim.compute_psf();
      const RealStack gs = random_stack(c.bands, sim.sensor_size(), sim.sensor_size(), 12);
      const Map2D got = sim.psf_sensor_vjp(gs);
      const Map2D want = ref::psf_sensor_vjp(c, h, gs);
      const auto d = diff(got.data, want.data);
      // The gradient sums bands x M² terms of both signs: relative L2 within 2e3 eps (f32: 2.4e-4).
      CAPTURE(d.rel_l2);
      CHECK(d.rel_l2 <= 2e3 * eps(p));
      const RealStack gn = random_stack(c.bands, c.n, c.n, 13);
      const auto dn = diff(sim.psf_native_vjp(gn).data, ref::psf_native_vjp(c, h, gn).data);
      CAPTURE(dn.rel_l2);
      CHECK(dn.rel_l2 <= 2e3 * eps(p));
    }
  }
}

TEST_SUITE("adjoint") {
  TEST_CASE("convolution and sensor adjoints: dot-product tests, OpenCL vs CPU, end-to-end differences") {
    SystemConfig c = tiny_config(32, 3);
    const std::size_t s = c.sensor_size_px();
    for (ConvolutionMode mode : {ConvolutionMode::Linear, ConvolutionMode::Circular}) {
      CAPTURE(int(mode));
      const RealStack cube = random_stack(c.bands, 12, 15, 21, 0, 1), psf = random_stack(c.bands, s, s, 22, 0, 1);
      const RealStack g = random_stack(c.bands, 12, 15, 23);
      const double l = dot(ref::convolve(cube, psf, mode).data, g.data);
      const double r = dot(psf.data, ref::convolve_vjp_psf(cube, g, s, mode).data);
      CHECK(std::fabs(l - r) <= kDotTol * std::fabs(l));
    }
    const Eigen::MatrixXd srf = sensor_response(c);
    const RealStack x = random_stack(c.bands, 5, 6, 24), gr = random_stack(3, 5, 6, 25);
    CHECK(std::fabs(dot(ref::sensor_integrate(x, srf).data, gr.data) - dot(x.data, ref::sensor_integrate_vjp(gr, srf).data)) <=
          1e-12 * std::fabs(dot(x.data, ref::sensor_integrate_vjp(gr, srf).data)));
    for (Precision p : {Precision::F32, Precision::F64}) {
      if (p == Precision::F64 && !skip_unless(runtime().has_fp64(), "float64 cases: the device has no float64")) continue;
      for (ConvolutionMode mode : {ConvolutionMode::Linear, ConvolutionMode::Circular}) {
        CAPTURE(to_string(p));
        CAPTURE(int(mode));
        SystemConfig cm = c;
        cm.convolution = mode;
        cm.read_noise_sigma = 0.01;  // additive: no effect on gradients
        Simulator sim(runtime(), cm, p);
        const Map2D h = smooth_heights(cm, 26);
        sim.set_heights(h);
        sim.compute_psf();
        const std::vector<RealStack> cubes = {random_stack(cm.bands, 20, 18, 27, 0, 1), random_stack(cm.bands, 20, 18, 28, 0, 1)};
        sim.sensor_images(cubes);
        const std::vector<RealStack> g = {random_stack(3, 20, 18, 29), random_stack(3, 20, 18, 30)};
        const RealStack got = sim.sensor_images_vjp(g);
        RealStack want(cm.bands, s, s);
        for (std::size_t k = 0; k < 2; ++k) {
          const RealStack part = ref::convolve_vjp_psf(cubes[k], ref::sensor_integrate_vjp(g[k], sim.srf()), s, mode);
          for (std::size_t i = 0; i < want.size(); ++i) want.data[i] += part.data[i];
        }
        const auto d = diff(got.data, want.data);
        CAPTURE(d.rel_l2);
        CHECK(d.rel_l2 <= 1e3 * eps(p));
        if (p == Precision::F64 && mode == ConvolutionMode::Linear) {
          // End to end: L(H) = sum_k <g_k, sensor_image_k(H)>, gradient through every stage.
          const Map2D dh = sim.psf_sensor_vjp(got);
          auto loss = [&](const Map2D& hh) {
            sim.set_heights(hh);
            sim.compute_psf();
            const auto imgs = sim.sensor_images(cubes);
            return dot(imgs[0].data, g[0].data) + dot(imgs[1].data, g[1].data);
          };
          for (auto [i, j] : {std::pair<std::size_t, std::size_t>{16, 16}, {12, 20}, {20, 9}}) {
            Map2D a = h, b = h;
            a(i, j) += 1e-11;
            b(i, j) -= 1e-11;
            const double fd = (loss(a) - loss(b)) / 2e-11;
            CAPTURE(i);
            CAPTURE(j);
            CHECK(std::fabs(fd - dh(i, j)) <= 1e-5 * std::fabs(dh(i, j)) + 1e-7 * std::sqrt(dot(dh.data, dh.data) / double(dh.data.size())));
          }
        }
      }
    }
  }
}

TEST_SUITE("adjoint") {
  // The fused host propagation (HostPropagator, FFTW on CPU devices) against the same Simulator
  // with fusion off (FFT plan, transfer-function and crop kernels, intensity and resampling
  // adjoint kernels: the path of every other backend), and against the CPU reference. N = 42
  // (M = 62: a partial column block, rows off the SIMD alignment), both propagators, a sensor
  // distance long enough for the Fresnel band limit to cut the spectrum, and a two-design batch.
  TEST_CASE("the fused host propagation gives the kernel path's PSF, sampling report and gradients") {
    if (!skip_unless(runtime().info().type == "CPU", "the host propagation runs with the FFTW backend, on CPU devices only"))
      return;
    // Its own Runtime with the FFTW backend, whatever QDO_FFT says (the suite also runs with clfft
    // and vkfft).
    Runtime rt(std::string(""), FftBackend::FFTW);
    for (Precision p : device_precisions(rt)) {
      for (Propagator prop : {Propagator::Fresnel, Propagator::AngularSpectrum}) {
        for (std::size_t n : {40, 42}) {
          CAPTURE(to_string(p));
          CAPTURE(int(prop));
          CAPTURE(n);
          SystemConfig c = tiny_config(n, 3);
          c.propagator = prop;
          c.sensor_pitch_m = 10e-6;  // ratio 2.5: fractional area weights, transposed taps > 1
          c.sensor_distance_m *= 3;
          const Map2D h = smooth_heights(c, 21);
          Simulator fused(rt, c, p), plain(rt, c, p);
          plain.set_host_fusion(false);
          REQUIRE(fused.uses_host_propagation());
          REQUIRE_FALSE(plain.uses_host_propagation());
          for (Simulator* s : {&fused, &plain}) {
            s->set_heights(h);
            s->compute_psf();
          }
          const double m = double(fused.geometry().m);
          // Two evaluation orders of the same float computation: 16 eps per FFT stage (|U|²
          // doubles the field's error).
          const double tol = 16 * eps(p) * 2 * std::log2(m);
          const auto dn = diff(fused.psf_native().data, plain.psf_native().data);
          CAPTURE(dn.rel_l2);
          CHECK(dn.rel_l2 <= tol);
          const auto ds = diff(fused.psf_sensor().data, plain.psf_sensor().data);
          CAPTURE(ds.rel_l2);
          CHECK(ds.rel_l2 <= tol);
          // Sampling energies: the host sums per column in double, the kernels per work-group.
          const auto want = ref::psf_stack(c, h);
          for (std::size_t b = 0; b < c.bands; ++b) {
            CAPTURE(b);
            const BandSampling &f = fused.sampling().bands[b], &k = plain.sampling().bands[b];
            CHECK(f.aliased_energy_fraction == doctest::Approx(k.aliased_energy_fraction).epsilon(1e-4).scale(1.0));
            CHECK(f.energy_outside_window == doctest::Approx(k.energy_outside_window).epsilon(1e-4).scale(1.0));
            CHECK(f.aliased_energy_fraction ==
                  doctest::Approx(want.sampling.bands[b].aliased_energy_fraction).epsilon(1e-3).scale(1.0));
            CHECK(f.energy_outside_window ==
                  doctest::Approx(want.sampling.bands[b].energy_outside_window).epsilon(1e-3).scale(1.0));
          }
          // A band limit that cuts the spectrum: the aliased fraction is not trivially zero.
          if (prop == Propagator::Fresnel) CHECK(fused.sampling().bands[c.bands - 1].aliased_energy_fraction > 1e-6);
          // Gradients: the fused sensor adjoint (resampling, |U|² and propagation in one pass)
          // and the native one (intensity kernel, host propagation), against the kernel path
          // and the CPU reference. Sums of bands x M² terms of both signs: 2e3 eps as in
          // "the OpenCL adjoint matches the CPU reference adjoint".
          const RealStack gs = random_stack(c.bands, fused.sensor_size(), fused.sensor_size(), 22);
          const Map2D gf = fused.psf_sensor_vjp(gs), gp = plain.psf_sensor_vjp(gs);
          // The device-buffer form on both paths: the same bits as the host form (the kernel
          // path copies the whole stack into its scratch first, the fused one reads the
          // caller's buffer), and the caller's buffer is left as it was.
          {
            cl::Buffer gdev(rt.context(), CL_MEM_READ_WRITE, gs.data.size() * real_size(p));
            rt.write_reals(gdev, gs.data.data(), gs.data.size(), p);
            CHECK(fused.psf_sensor_vjp(gdev).data == gf.data);
            CHECK(plain.psf_sensor_vjp(gdev).data == gp.data);
            std::vector<double> after(gs.data.size());
            rt.read_reals(gdev, after.data(), after.size(), p);
            std::vector<double> before(gs.data.size());
            for (std::size_t i = 0; i < before.size(); ++i)
              before[i] = p == Precision::F32 ? double(float(gs.data[i])) : gs.data[i];
            CHECK(after == before);
          }
          const auto dg = diff(gf.data, gp.data);
          CAPTURE(dg.rel_l2);
          CHECK(dg.rel_l2 <= 2e3 * eps(p));
          const auto dr = diff(gf.data, ref::psf_sensor_vjp(c, h, gs).data);
          CAPTURE(dr.rel_l2);
          CHECK(dr.rel_l2 <= 2e3 * eps(p));
          const RealStack gn = random_stack(c.bands, c.n, c.n, 23);
          const auto dgn = diff(fused.psf_native_vjp(gn).data, plain.psf_native_vjp(gn).data);
          CAPTURE(dgn.rel_l2);
          CHECK(dgn.rel_l2 <= 2e3 * eps(p));
        }
      }
      // A batch of two designs: each plane set equals its single-design stack.
      SystemConfig c = tiny_config(40, 3);
      const Map2D h0 = random_heights(c.n, c.h_max_m(), 24), h1 = random_heights(c.n, c.h_max_m(), 25);
      Simulator batch(rt, c, p, 2), one(rt, c, p);
      REQUIRE(batch.uses_host_propagation());
      batch.set_heights_batch({h0, h1});
      batch.compute_psf();
      const RealStack both = batch.psf_sensor();
      const std::size_t per = c.bands * batch.sensor_size() * batch.sensor_size();
      for (std::size_t d = 0; d < 2; ++d) {
        CAPTURE(d);
        one.set_heights(d == 0 ? h0 : h1);
        one.compute_psf();
        const std::vector<double> part(both.data.begin() + std::ptrdiff_t(d * per), both.data.begin() + std::ptrdiff_t((d + 1) * per));
        const auto dd = diff(part, one.psf_sensor().data);
        CAPTURE(dd.rel_l2);
        CHECK(dd.rel_l2 <= 4 * eps(p));
      }
    }
  }

  // Simulator::set_keep_field(false) (what `qdo psf` runs): the field made and propagated a chunk
  // of planes at a time through one small buffer gives the kept path's results bit for bit (the
  // same kernel values, the same FFTW plans on the same per-thread arrays), with 11 bands (a
  // chunk of 8 and a partial one), in every precision, with the float64 phase, both propagators;
  // the adjoints then refuse, naming the setting, and work again after a kept compute_psf().
  TEST_CASE("a PSF streamed without keeping the field equals the kept one bit for bit; adjoints then refuse") {
    if (!skip_unless(runtime().info().type == "CPU", "the host propagation runs with the FFTW backend, on CPU devices only"))
      return;
    Runtime rt(std::string(""), FftBackend::FFTW);
    struct Variant {
      Precision p;
      bool phase_fp64;
      Propagator prop;
    };
    std::vector<Variant> variants;
    for (Precision p : device_precisions(rt))
      for (Propagator prop : {Propagator::Fresnel, Propagator::AngularSpectrum}) variants.push_back({p, false, prop});
    if (rt.has_fp64()) variants.push_back({Precision::F32, true, Propagator::Fresnel});
    for (const Variant& v : variants) {
      CAPTURE(to_string(v.p));
      CAPTURE(v.phase_fp64);
      CAPTURE(int(v.prop));
      SystemConfig c = tiny_config(42, 11);
      c.propagator = v.prop;
      c.sensor_distance_m *= 3;  // the Fresnel band limit cuts the spectrum: the aliased energy is not 0
      const Map2D h = smooth_heights(c, 31);
      Simulator kept(rt, c, v.p, 1, v.phase_fp64), streamed(rt, c, v.p, 1, v.phase_fp64);
      streamed.set_keep_field(false);
      REQUIRE(streamed.uses_host_propagation());
      for (Simulator* s : {&kept, &streamed}) {
        s->set_heights(h);
        s->compute_psf();
      }
      CHECK(kept.psf_native().data == streamed.psf_native().data);
      CHECK(kept.psf_sensor().data == streamed.psf_sensor().data);
      for (std::size_t b = 0; b < c.bands; ++b) {
        CAPTURE(b);
        CHECK(kept.sampling().bands[b].aliased_energy_fraction == streamed.sampling().bands[b].aliased_energy_fraction);
        CHECK(kept.sampling().bands[b].energy_outside_window == streamed.sampling().bands[b].energy_outside_window);
      }
      if (v.prop == Propagator::Fresnel) CHECK(streamed.sampling().bands[c.bands - 1].aliased_energy_fraction > 1e-6);
      const RealStack gs = random_stack(c.bands, kept.sensor_size(), kept.sensor_size(), 32);
      CHECK_THROWS_WITH_AS(streamed.psf_sensor_vjp(gs), doctest::Contains("set_keep_field"), qdo::Error);
      CHECK_THROWS_WITH_AS(streamed.psf_native_vjp(random_stack(c.bands, c.n, c.n, 33)), doctest::Contains("set_keep_field"),
                           qdo::Error);
      // A second streamed run over other heights reuses the chunk buffer: still equal.
      const Map2D h2 = random_heights(c.n, c.h_max_m(), 34);
      for (Simulator* s : {&kept, &streamed}) {
        s->set_heights(h2);
        s->compute_psf();
      }
      CHECK(kept.psf_sensor().data == streamed.psf_sensor().data);
      streamed.set_keep_field(true);
      streamed.compute_psf();
      CHECK(kept.psf_sensor_vjp(gs).data == streamed.psf_sensor_vjp(gs).data);
    }
    // Where nothing is streamed (the kernel path), the setting changes nothing and the adjoints work.
    SystemConfig c = tiny_config(40, 3);
    Simulator plain(rt, c, Precision::F32);
    plain.set_host_fusion(false);
    plain.set_keep_field(false);
    plain.set_heights(smooth_heights(c, 35));
    plain.compute_psf();
    CHECK_NOTHROW(plain.psf_sensor_vjp(random_stack(c.bands, plain.sensor_size(), plain.sensor_size(), 36)));
  }

  TEST_CASE("the host propagation refuses bad sizes and buffers before any work") {
    if (!skip_unless(runtime().info().type == "CPU", "the host propagation maps buffers of CPU devices")) return;
    Runtime& rt = runtime();
    CHECK_THROWS_AS(make_host_propagator(rt, 60, 60, 3, Precision::F32), InputError);
    CHECK_THROWS_AS(make_host_propagator(rt, 60, 0, 3, Precision::F32), InputError);
    CHECK_THROWS_AS(make_host_propagator(rt, 60, 40, 0, Precision::F32), InputError);
    auto hp = make_host_propagator(rt, 60, 40, 3, Precision::F32);
    cl::Buffer small(rt.context(), CL_MEM_READ_WRITE, 16);
    cl::Buffer field(rt.context(), CL_MEM_READ_WRITE, 3 * 60 * 60 * 8), tf(rt.context(), CL_MEM_READ_WRITE, 3 * 60 * 8);
    try {
      hp->run(small, HostPropagator::Tf{&tf, true}, HostPropagator::Outputs{});
      FAIL("a too-small field buffer was accepted");
    } catch (const InputError& e) {
      CHECK(std::string(e.what()).find("field") != std::string::npos);
    }
    CHECK_THROWS_AS(hp->run(field, HostPropagator::Tf{&small, true}, HostPropagator::Outputs{}), InputError);
    CHECK_THROWS_AS(hp->run(field, HostPropagator::Tf{&tf, false}, HostPropagator::Outputs{}), InputError);  // needs M x M
    HostPropagator::Outputs no_klim;
    no_klim.energy3 = &small;
    CHECK_THROWS_AS(hp->run(field, HostPropagator::Tf{&tf, true}, no_klim), InputError);
    // run_planes: a range beyond the planes, an empty range, a field too small for its planes.
    CHECK_THROWS_AS(hp->run_planes(field, 2, 2, HostPropagator::Tf{&tf, true}, HostPropagator::Outputs{}), InputError);
    CHECK_THROWS_AS(hp->run_planes(field, 0, 0, HostPropagator::Tf{&tf, true}, HostPropagator::Outputs{}), InputError);
    CHECK_THROWS_AS(hp->run_planes(small, 1, 1, HostPropagator::Tf{&tf, true}, HostPropagator::Outputs{}), InputError);
  }
}
