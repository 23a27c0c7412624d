// The propagation stage (kernels/propagate.cl, the fused host propagation
// src/runtime/propagate_fftw.cpp; CPU reference src/physics/propagate_reference.cpp): the kernels
// against the reference in float32 and float64 (Fresnel and band-limited angular spectrum),
// energy conservation, +z then -z (and against a closed-form Gaussian beam, which the round trip
// alone cannot tell from a flipped transfer function), a direct Fresnel integral, the paraxial
// agreement of the two propagators, the sampling report and strict mode, and the fused host
// propagation against the kernel path (PSFs, sampling report, gradients, the streamed PSF, its
// refusals).
#include <cmath>

#include "common.hpp"
#include "stage_probes.hpp"
#include "qdo/physics/cpu_reference.hpp"
#include "qdo/physics/adjoint.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/physics/simulator.hpp"

using namespace qdo;
using namespace qdo::test;

namespace {

ComplexStack gaussian_beam(std::size_t m, double pitch_m, double waist_m, std::size_t planes = 1) {
  ComplexStack f(planes, m, m);
  for (std::size_t p = 0; p < planes; ++p)
    for (std::size_t i = 0; i < m; ++i)
      for (std::size_t j = 0; j < m; ++j) {
        const double y = (double(i) - double(m / 2)) * pitch_m, x = (double(j) - double(m / 2)) * pitch_m;
        f(p, i, j) = std::exp(-(x * x + y * y) / (waist_m * waist_m));
      }
  return f;
}

double energy(const ComplexStack& f, std::size_t plane = 0) {
  double e = 0;
  for (std::size_t i = 0; i < f.plane_size(); ++i) e += std::norm(f.plane(plane)[i]);
  return e;
}

}  // namespace

TEST_SUITE("propagate") {
  TEST_CASE("propagation (Fresnel and band-limited ASM) matches the CPU reference") {
    for (Precision p : device_precisions(runtime())) {
      for (Propagator prop : {Propagator::Fresnel, Propagator::AngularSpectrum}) {
        CAPTURE(to_string(p));
        CAPTURE(int(prop));
        SystemConfig c = tiny_config(40, 3);  // M = 60: radices 2, 3, 5
        c.propagator = prop;
        const Map2D h = random_heights(c.n, c.h_max_m(), 12);
        Simulator sim(runtime(), c, p);
        sim.set_heights(h);
        SamplingReport sampling;
        const ComplexStack got = field_after_propagation(sim, &sampling);
        ComplexStack want = ref::doe_field(c, h, sim.geometry());
        std::vector<BandSampling> s;
        ref::propagate(want, c.wavelengths_nm(), c.pitch_m, c.sensor_distance_m, prop, &s);
        const auto d = diff(got.data, want.data);
        // Two FFTs of log2(M²) stages each plus the DOE phase: rel. L2 <= 8 eps (log2 M² + phase).
        const double m = double(sim.geometry().m);
        const double tol = 8 * eps(p) * (2 * std::log2(m) + max_phase(c));
        CAPTURE(d.rel_l2);
        CHECK(d.rel_l2 <= tol);
        // The sampling report agrees with the reference's.
        for (std::size_t b = 0; b < c.bands; ++b)
          CHECK(sampling.bands[b].aliased_energy_fraction ==
                doctest::Approx(s[b].aliased_energy_fraction).epsilon(1e-3).scale(1.0));
      }
    }
  }

  TEST_CASE("propagation conserves energy: 1e-5 unpadded, and with padding the window accounts for the rest") {
    SystemConfig c = tiny_config(64, 3);
    c.padding_px = 0;
    const Map2D h = random_heights(c.n, c.h_max_m(), 21);
    const auto g = PropagationGeometry::from_config(c);
    ComplexStack f = ref::doe_field(c, h, g);
    std::vector<double> e0;
    for (std::size_t b = 0; b < c.bands; ++b) e0.push_back(energy(f, b));
    ComplexStack fr = f;
    ref::propagate(fr, c.wavelengths_nm(), c.pitch_m, c.sensor_distance_m, Propagator::Fresnel);
    Simulator sim(runtime(), c, Precision::F32);
    const ComplexStack fk = propagate_field(sim, f, c.sensor_distance_m);
    for (std::size_t b = 0; b < c.bands; ++b) {
      CHECK(std::fabs(energy(fr, b) / e0[b] - 1) <= 1e-12);
      CHECK(std::fabs(energy(fk, b) / e0[b] - 1) <= 1e-5);
    }
    // With padding, energy inside the N x N crop plus the reported energy outside = total.
    SystemConfig cp = tiny_config(64, 3);
    const auto gp = PropagationGeometry::from_config(cp);
    ComplexStack fp = ref::doe_field(cp, h, gp);
    const double total = energy(fp, 0);
    ref::propagate(fp, cp.wavelengths_nm(), cp.pitch_m, cp.sensor_distance_m, Propagator::Fresnel);
    double inside = 0;
    for (std::size_t i = 0; i < cp.n; ++i)
      for (std::size_t j = 0; j < cp.n; ++j) inside += std::norm(fp(0, gp.offset + i, gp.offset + j));
    Simulator simp(runtime(), cp, Precision::F32);
    simp.set_heights(h);
    simp.compute_psf();
    const double outside = simp.sampling().bands[0].energy_outside_window;
    CHECK(outside > 1e-3);  // random heights scatter light out of the window
    CHECK(inside / total + outside == doctest::Approx(1.0).epsilon(1e-5));
  }

  TEST_CASE("+z then -z returns the field") {
    // Invertibility only: blind to the transfer function's sign (see the closed-form case below).
    SystemConfig c = tiny_config(48, 2);
    const Map2D h = random_heights(c.n, c.h_max_m(), 22);
    const auto g = PropagationGeometry::from_config(c);
    const ComplexStack f0 = ref::doe_field(c, h, g);
    for (Propagator p : {Propagator::Fresnel, Propagator::AngularSpectrum}) {
      CAPTURE(int(p));
      ComplexStack f = f0;
      ref::propagate(f, c.wavelengths_nm(), c.pitch_m, c.sensor_distance_m, p);
      ref::propagate(f, c.wavelengths_nm(), c.pitch_m, -c.sensor_distance_m, p);
      if (p == Propagator::Fresnel) {
        CHECK(diff(f.data, f0.data).rel_l2 <= 1e-12);
      } else {
        // The band limit removes what lies beyond it on the way out; the rest comes back.
        CHECK(diff(f.data, f0.data).rel_l2 <= 0.5);
      }
    }
    Simulator sim(runtime(), c, Precision::F32);
    const ComplexStack back = propagate_field(sim, propagate_field(sim, f0, c.sensor_distance_m), -c.sensor_distance_m);
    CHECK(diff(back.data, f0.data).rel_l2 <= 1e-5);
  }

  TEST_CASE("+z then -z is blind to the transfer function's sign: a closed-form diverging Gaussian goes back to its waist") {
    // The round trip above only shows that -z inverts +z, which holds for either sign of the
    // transfer function (a flipped sign inverts itself). Here one leg is the closed form:
    // the Gaussian exp(-r²/w0²) after z is (q0 / (q0 + z)) exp(iπ r² / (λ (q0 + z))), q0 = -i zR,
    // zR = π w0² / λ (diverging phase +k r² / 2R in the exp(+ikr) convention of the reference).
    // Propagating the computed field must equal it, and propagating the closed form by -z must
    // give back the waist; with the opposite sign, -z would spread it to w(2z) instead.
    const std::size_t n = 128;
    SystemConfig c = preset_config("small");
    c.n = n;
    c.padding_px = 64;  // M = 256
    c.pitch_m = 2e-6;
    c.bands = 1;
    c.wavelength_start_nm = 500;
    c.validate();
    const std::size_t m = 256;
    const double lambda = 500e-9, w0 = 20e-6, zr = M_PI * w0 * w0 / lambda, z = std::sqrt(3.0) * zr;  // w(z) = 2 w0
    const ComplexStack waist = gaussian_beam(m, c.pitch_m, w0);
    ComplexStack at_z(1, m, m);
    const cdouble q = cdouble(z, -zr);
    for (std::size_t i = 0; i < m; ++i)
      for (std::size_t j = 0; j < m; ++j) {
        const double y = (double(i) - double(m / 2)) * c.pitch_m, x = (double(j) - double(m / 2)) * c.pitch_m;
        at_z(0, i, j) = cdouble(0, -zr) / q * std::exp(cdouble(0, M_PI * (x * x + y * y) / lambda) / q);
      }
    // Tolerances: the Gaussian's spectrum at the transfer function's limit and its tails at
    // the window edge are < e^-38, so the double Fresnel result is exact to rounding (1e-9);
    // the angular spectrum differs from the paraxial closed form by k z θ⁴ / 8 ~ 3e-5 rad
    // (θ = λ / (π w0)), and float32 FFTs of M = 256 give ~1e-6: 1e-4 for both. A flipped sign
    // gives a relative L2 error of order 1.
    for (Propagator p : {Propagator::Fresnel, Propagator::AngularSpectrum}) {
      CAPTURE(int(p));
      const double tol_ref = p == Propagator::Fresnel ? 1e-9 : 1e-4;
      ComplexStack fwd = waist, back = at_z;
      ref::propagate(fwd, {500}, c.pitch_m, z, p);
      ref::propagate(back, {500}, c.pitch_m, -z, p);
      CHECK(diff(fwd.data, at_z.data).rel_l2 <= tol_ref);
      CHECK(diff(back.data, waist.data).rel_l2 <= tol_ref);
      c.propagator = p;
      Simulator sim(runtime(), c, Precision::F32);
      CHECK(diff(propagate_field(sim, waist, z).data, at_z.data).rel_l2 <= 1e-4);
      CHECK(diff(propagate_field(sim, at_z, -z).data, waist.data).rel_l2 <= 1e-4);
    }
  }

  TEST_CASE("Fresnel transfer function agrees with a direct Fresnel integral") {
    // Gaussian beam, 64 x 64 at 2 µm, 500 nm, z = 1 mm: both the transfer function
    // (λz <= M pitch²) and the direct kernel are sampled above Nyquist here.
    const std::size_t n = 64;
    const double pitch = 2e-6, z = 1e-3, wl = 500;
    const ComplexStack src = gaussian_beam(n, pitch, 12e-6);
    const ComplexStack direct = ref::fresnel_integral_direct(src, wl, pitch, z);
    ComplexStack padded(1, 2 * n, 2 * n);
    for (std::size_t i = 0; i < n; ++i)
      for (std::size_t j = 0; j < n; ++j) padded(0, n / 2 + i, n / 2 + j) = src(0, i, j);
    ref::propagate(padded, {wl}, pitch, z, Propagator::Fresnel);
    std::vector<cdouble> a, b;
    for (std::size_t i = 8; i < n - 8; ++i)
      for (std::size_t j = 8; j < n - 8; ++j) {
        a.push_back(padded(0, n / 2 + i, n / 2 + j));
        b.push_back(direct(0, i, j));
      }
    const auto d = diff(a, b);
    CAPTURE(d.rel_l2);
    CHECK(d.rel_l2 <= 1e-3);
  }

  TEST_CASE("Fresnel and band-limited angular spectrum agree in the paraxial regime, and differ outside it") {
    const std::size_t m = 128;
    const double pitch = 2e-6, wl = 500;
    const ComplexStack src = gaussian_beam(m, pitch, 20e-6);  // divergence ~ 8 mrad
    ComplexStack a = src, b = src;
    ref::propagate(a, {wl}, pitch, 1e-3, Propagator::Fresnel);
    ref::propagate(b, {wl}, pitch, 1e-3, Propagator::AngularSpectrum);
    CHECK(diff(a.data, b.data).rel_l2 <= 1e-3);
    // A 1 µm waist diverges at ~0.16 rad: the paraxial phase error k z θ⁴ / 8 ~ 0.1 rad at 100 µm.
    ComplexStack c = gaussian_beam(256, 0.5e-6, 1e-6), d = c;
    ref::propagate(c, {wl}, 0.5e-6, 0.1e-3, Propagator::Fresnel);
    ref::propagate(d, {wl}, 0.5e-6, 0.1e-3, Propagator::AngularSpectrum);
    CHECK(diff(c.data, d.data).rel_l2 >= 1e-2);
  }

  TEST_CASE("sampling check: the paper's 700 nm band is flagged, strict mode refuses an aliased design") {
    const SystemConfig paper = preset_config("paper");
    const auto g = PropagationGeometry::from_config(paper);
    CHECK(g.m == 1536);
    const double f700 = transfer_function_limit_per_m(Propagator::Fresnel, 700, paper.sensor_distance_m, g.m, paper.pitch_m);
    CHECK(f700 == doctest::Approx(87771.4).epsilon(1e-4));  // M pitch / (2 λ z)
    CHECK(f700 < 0.5 / paper.pitch_m);
    SystemConfig c = tiny_config(64, 3);
    c.strict_sampling = true;
    // Random heights put energy at every frequency: refused with the band named.
    CHECK_THROWS_AS(ref::psf_stack(c, random_heights(c.n, c.h_max_m(), 23)), AccuracyError);
    Simulator sim(runtime(), c, Precision::F32);
    sim.set_heights(random_heights(c.n, c.h_max_m(), 23));
    CHECK_THROWS_WITH_AS(sim.compute_psf(), doctest::Contains("under-sampled"), AccuracyError);
    // The remedy the message names: with padding such that λz <= M pitch² at every band
    // (M = 112 >= 500 nm * 3.125 mm / (4 µm)² = 98), the same design is accepted.
    c.padding_px = 24;
    c.wavelength_start_nm = 400;
    c.wavelength_step_nm = 50;
    Simulator padded(runtime(), c, Precision::F32);
    padded.set_heights(random_heights(c.n, c.h_max_m(), 23));
    CHECK_NOTHROW(padded.compute_psf());
    CHECK_FALSE(padded.sampling().any_inaccurate());
  }

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
          const RealStack gs = uniform_stack(c.bands, fused.sensor_size(), fused.sensor_size(), 22);
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
          const RealStack gn = uniform_stack(c.bands, c.n, c.n, 23);
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
      const RealStack gs = uniform_stack(c.bands, kept.sensor_size(), kept.sensor_size(), 32);
      CHECK_THROWS_WITH_AS(streamed.psf_sensor_vjp(gs), doctest::Contains("set_keep_field"), qdo::Error);
      CHECK_THROWS_WITH_AS(streamed.psf_native_vjp(uniform_stack(c.bands, c.n, c.n, 33)), doctest::Contains("set_keep_field"),
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
    CHECK_NOTHROW(plain.psf_sensor_vjp(uniform_stack(c.bands, plain.sensor_size(), plain.sensor_size(), 36)));
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
