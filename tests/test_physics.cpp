// Physics against closed forms and independent computations (CPU reference and kernels).
#include <cmath>

#include "common.hpp"
#include "qdo/cpu_reference.hpp"
#include "qdo/doe.hpp"
#include "qdo/error.hpp"
#include "qdo/simulator.hpp"
#include "stage_probes.hpp"

using namespace qdo;
using namespace qdo::test;

namespace {

// First minimum of the azimuthally averaged profile of a PSF plane around (cy, cx), in
// pixels, refined by a parabola through the three samples around the discrete minimum.
double first_dark_ring_px(const RealStack& psf, std::size_t plane, double cy, double cx) {
  const int n_r = 400, n_a = 64;
  const double dr = 0.1;
  std::vector<double> prof(n_r, 0.0);
  for (int ir = 0; ir < n_r; ++ir)
    for (int ia = 0; ia < n_a; ++ia) {
      const double a = 2 * M_PI * ia / n_a, r = ir * dr;
      const double y = cy + r * std::sin(a), x = cx + r * std::cos(a);
      const auto y0 = static_cast<std::size_t>(std::floor(y)), x0 = static_cast<std::size_t>(std::floor(x));
      const double fy = y - double(y0), fx = x - double(x0);
      prof[ir] += (1 - fy) * ((1 - fx) * psf(plane, y0, x0) + fx * psf(plane, y0, x0 + 1)) +
                  fy * ((1 - fx) * psf(plane, y0 + 1, x0) + fx * psf(plane, y0 + 1, x0 + 1));
    }
  for (int ir = 2; ir < n_r - 1; ++ir)
    if (prof[ir] <= prof[ir - 1] && prof[ir] < prof[ir + 1]) {
      const double a = prof[ir - 1], b = prof[ir], c = prof[ir + 1];
      const double off = 0.5 * (a - c) / (a - 2 * b + c);
      return (ir + off) * dr;
    }
  return -1;
}

SystemConfig airy_config() {
  SystemConfig c = preset_config("small");
  c.n = 256;
  c.padding_px = 128;
  c.bands = 1;
  c.wavelength_start_nm = 550;
  c.sensor_distance_m = 0.05;
  c.aperture_radius_m = 0.25e-3;  // D = 0.5 mm: first dark ring at 67 µm = 16.8 px
  c.validate();
  return c;
}

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

TEST_SUITE("physics") {
  TEST_CASE("a diffractive lens at 550 nm focuses on axis with its first dark ring at 1.22 lambda z / D") {
    const SystemConfig c = airy_config();
    const Map2D lens = lens_design(c, 550);
    const double expected_px = 1.22 * 550e-9 * c.sensor_distance_m / (2 * c.aperture_radius()) / c.pitch_m;
    auto check_psf = [&](const RealStack& psf) {
      // Peak on the axis sample (N/2, N/2).
      std::size_t best = 0;
      for (std::size_t i = 0; i < psf.plane_size(); ++i)
        if (psf.data[i] > psf.data[best]) best = i;
      CHECK(best / c.n == c.n / 2);
      CHECK(best % c.n == c.n / 2);
      const double ring = first_dark_ring_px(psf, 0, double(c.n / 2), double(c.n / 2));
      CAPTURE(ring);
      CAPTURE(expected_px);
      CHECK(std::fabs(ring - expected_px) <= 0.10 * expected_px);
    };
    check_psf(ref::psf_stack(c, lens).psf);
    Simulator sim(runtime(), c, Precision::F32);
    sim.set_heights(lens);
    sim.compute_psf();
    check_psf(sim.psf_native());
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

  TEST_CASE("phase precision: float32 kernels keep the spherical phase at d = 1 m where naive float32 fails") {
    SystemConfig c = preset_config("paper");
    c.n = 256;
    c.padding_px = 0;
    c.bands = 1;
    c.wavelength_start_nm = 400;  // largest k
    c.aperture_radius_m = 2e-3;   // the paper's aperture: r up to 2 mm at d = 1 m
    c.pitch_m = 16e-6;
    c.sensor_pitch_m = 16e-6;
    c.validate();
    Simulator sim(runtime(), c, Precision::F32);
    sim.set_heights(flat_design(c));
    const ComplexStack got = field_after_doe(sim);
    const ComplexStack want = ref::doe_field(c, flat_design(c), sim.geometry());
    double worst = 0, worst_naive = 0;
    const float k = float(2 * M_PI / 400e-9), d = 1.0f;
    for (std::size_t i = 0; i < c.n; ++i)
      for (std::size_t j = 0; j < c.n; ++j) {
        const cdouble w = want(0, i, j);
        if (std::abs(w) == 0) continue;
        worst = std::max(worst, std::fabs(std::arg(got(0, i, j) / w)));
        // The naive float32 phase k sqrt(r² + d²) (minus k d, both in float) for comparison.
        const float y = float((double(i) - 128) * c.pitch_m), x = float((double(j) - 128) * c.pitch_m);
        const float naive = k * std::sqrt(x * x + y * y + d * d) - k * d;
        worst_naive = std::max(worst_naive, std::fabs(std::arg(std::polar(1.0, double(naive)) / w)));
      }
    CAPTURE(worst);
    CAPTURE(worst_naive);
    CHECK(worst <= 1e-4);        // rad
    CHECK(worst_naive >= 0.1);   // the pitfall is real
  }
}
