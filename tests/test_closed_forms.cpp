// Closed forms with sharp tolerances: the Airy pattern's peak and encircled
// energy, the direction and amount a tilted wave moves, and the first-order efficiency of
// L-level blazed gratings. Expected values come from the formulas written here, never from the
// simulator's host helpers; every tolerance is derived next to its check.
#include <cmath>

#include "common.hpp"
#include "qdo/physics/cpu_reference.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/physics/simulator.hpp"
#include "stage_probes.hpp"

using namespace qdo;
using namespace qdo::test;

namespace {

// n - 1 of OHARA S-K1300 (Sellmeier, coefficients of QDO constants.py typed in here), λ in nm.
double sk1300_n_minus_1(double wavelength_nm) {
  const double b[3] = {0.744386780, 0.360198890, 0.918623119};
  const double c[3] = {0.00495119834, 0.0141130274, 100.428510};
  const double l2 = (wavelength_nm / 1000.0) * (wavelength_nm / 1000.0);
  double n2 = 1.0;
  for (int i = 0; i < 3; ++i) n2 += b[i] * l2 / (l2 - c[i]);
  return std::sqrt(n2) - 1.0;
}

SystemConfig airy_config() {
  SystemConfig c = preset_config("small");  // S-K1300, pitch 4 µm
  c.n = 256;
  c.padding_px = 128;
  c.bands = 1;
  c.wavelength_start_nm = 550;
  c.sensor_distance_m = 0.05;
  c.aperture_radius_m = 0.25e-3;  // D = 0.5 mm
  c.scene_at_infinity = true;
  c.validate();
  return c;
}

// A lens focusing a plane wave at z (exact path difference sqrt(r² + z²) - z), wrapped to one
// wave and converted to relief with the independent n - 1: heights in metres.
Map2D lens_heights(const SystemConfig& c, double wavelength_nm) {
  const double k = 2 * M_PI / (wavelength_nm * 1e-9), z = c.sensor_distance_m;
  Map2D h(c.n, c.n);
  for (std::size_t i = 0; i < c.n; ++i)
    for (std::size_t j = 0; j < c.n; ++j) {
      const double y = (double(i) - double(c.n / 2)) * c.pitch_m, x = (double(j) - double(c.n / 2)) * c.pitch_m;
      const double r2 = x * x + y * y;
      double phi = std::fmod(-k * r2 / (std::sqrt(r2 + z * z) + z), 2 * M_PI);
      if (phi < 0) phi += 2 * M_PI;
      h(i, j) = phi / (k * sk1300_n_minus_1(wavelength_nm));
    }
  return h;
}

ComplexStack propagate_both(Simulator& sim, const ComplexStack& f, double wl, double pitch, double z, Propagator p,
                            ComplexStack& ref_out) {
  ref_out = f;
  ref::propagate(ref_out, {wl}, pitch, z, p);
  return propagate_field(sim, f, z);
}

}  // namespace

TEST_SUITE("closedforms") {
  TEST_CASE("Airy: peak pixel pi D^2 pitch^2 / (4 lambda^2 z^2) and 83.8 % of the energy inside the first dark ring") {
    const SystemConfig c = airy_config();
    const double lambda = 550e-9, z = c.sensor_distance_m, d = 2 * c.aperture_radius(), px = c.pitch_m;
    // Unit power through an aperture of area A focuses to I(0) = A / (λ z)² (Fraunhofer at the
    // focus); one pixel holds I(0) Δ².
    const double want_peak = M_PI * d * d * px * px / (4 * lambda * lambda * z * z);
    // Encircled energy of the Airy pattern: 1 - J0(v)² - J1(v)², v = π D r / (λ z); at the
    // first zero of J1 (v = 3.8317, r = 1.22 λ z / D) this is 0.8378.
    const double v1 = 3.8317059702075123;
    const double want_ee = 1 - std::pow(std::cyl_bessel_j(0.0, v1), 2) - std::pow(std::cyl_bessel_j(1.0, v1), 2);
    CHECK(want_ee == doctest::Approx(0.8378).epsilon(1e-4));
    const double r1_px = v1 * lambda * z / (M_PI * d) / px;  // 16.8 px
    const Map2D lens = lens_heights(c, 550);
    // Tolerances: the sampled aperture (R = 62.5 px) has an area within ~0.5 % of π D²/4 (the
    // lattice-point discrepancy of a disc, O(R^(2/3)) pixels of ~12300); the exact lens phase vs
    // the paraxial propagator leaves k r⁴ / (8 z³) < 1e-4 rad of aberration; float32 and the
    // window's aliasing (< 1e-4 of the energy) are far below. 2 % covers it. The dark-ring sum
    // adds only pixels where the intensity is ~0, so pixelation of the disc edge costs < 0.5 %.
    // The psf is normalised inside the N x N crop: scaled back to unit total energy with the
    // reported energy outside the window.
    auto check = [&](const RealStack& psf, double outside) {
      CAPTURE(outside);
      const double scale = 1.0 - outside;
      const double peak = psf(0, c.n / 2, c.n / 2) * scale;
      CAPTURE(peak);
      CAPTURE(want_peak);
      CHECK(std::fabs(peak / want_peak - 1) <= 0.02);
      double ee = 0;
      for (std::size_t i = 0; i < c.n; ++i)
        for (std::size_t j = 0; j < c.n; ++j) {
          const double dy = double(i) - double(c.n / 2), dx = double(j) - double(c.n / 2);
          if (dy * dy + dx * dx <= r1_px * r1_px) ee += psf(0, i, j);
        }
      ee *= scale;
      CAPTURE(ee);
      CHECK(std::fabs(ee / want_ee - 1) <= 0.02);
    };
    const auto r = ref::psf_stack(c, lens);
    check(r.psf, r.sampling.bands[0].energy_outside_window);
    Simulator sim(runtime(), c, Precision::F32);
    sim.set_heights(lens);
    sim.compute_psf();
    check(sim.psf_native(), sim.sampling().bands[0].energy_outside_window);
  }

  TEST_CASE("a tilted Gaussian beam moves by +lambda z f0 (direction and amount), Fresnel and angular spectrum") {
    // A wave exp(i 2π f0 x) travels towards +x at angle λ f0: after z its centroid sits at
    // λ z f0 (exact for the Fresnel propagator: d<x>/dz = λ <f>). Here λ z f0 = 20 pixels.
    SystemConfig c = preset_config("small");
    c.n = 128;
    c.padding_px = 64;  // M = 256
    c.pitch_m = 2e-6;
    c.sensor_pitch_m = 8e-6;
    c.bands = 1;
    c.wavelength_start_nm = 500;
    c.validate();
    const double lambda = 500e-9, w0 = 20e-6, zr = M_PI * w0 * w0 / lambda, z = std::sqrt(3.0) * zr;
    const double shift_px = 20, f0 = shift_px * c.pitch_m / (lambda * z);
    const std::size_t m = 256;
    ComplexStack f(1, m, m);
    for (std::size_t i = 0; i < m; ++i)
      for (std::size_t j = 0; j < m; ++j) {
        const double y = (double(i) - double(m / 2)) * c.pitch_m, x = (double(j) - double(m / 2)) * c.pitch_m;
        f(0, i, j) = std::exp(-(x * x + y * y) / (w0 * w0)) * std::polar(1.0, 2 * M_PI * f0 * x);
      }
    auto centroid = [&](const ComplexStack& u, bool along_x) {
      double s = 0, sx = 0;
      for (std::size_t i = 0; i < m; ++i)
        for (std::size_t j = 0; j < m; ++j) {
          const double e = std::norm(u(0, i, j));
          s += e;
          sx += e * (along_x ? double(j) - double(m / 2) : double(i) - double(m / 2));
        }
      return sx / s;
    };
    for (Propagator p : {Propagator::Fresnel, Propagator::AngularSpectrum}) {
      CAPTURE(int(p));
      c.propagator = p;
      Simulator sim(runtime(), c, Precision::F32);
      ComplexStack r;
      const ComplexStack k = propagate_both(sim, f, 500, c.pitch_m, z, p, r);
      // Fresnel: exact up to the Gaussian's truncation (< e^-38); angular spectrum: the
      // centroid moves by z λ f / sqrt(1 - λ² f²), (λ f0)² / 2 = 4e-5 relative = 1e-3 px.
      // float32 sums over 65536 samples: ~1e-5 px. A flipped transfer function sign gives -20.
      for (const ComplexStack* u : std::initializer_list<const ComplexStack*>{&r, &k}) {
        CHECK(std::fabs(centroid(*u, true) - shift_px) <= 0.01);
        CHECK(std::fabs(centroid(*u, false)) <= 0.01);
      }
    }
  }

  TEST_CASE("L-level blazed gratings put sinc^2(1/L) of the light into the +1 order: 0.405, 0.811, 0.950, 0.987") {
    // Set-up where the focal plane is an exact DFT: a square N x N aperture, a paraxial lens
    // phase -π (x² + y²) / (λ z) sampled at pitch Δ with λ z = M Δ² (the lens phase on sample j
    // is then -π j² / M), and a grating of period P = 64 samples along x quantized by qdo's
    // quantizer (L levels, wrapped placement, each level exactly q = P / L samples wide). The
    // Fresnel transfer function exp(-iπ λ z f²) then turns the field into its M-point DFT times
    // a chirp, so with N a multiple of P and M / P an integer:
    //   * lens alone: the axis pixel holds N² / M² of the energy (|sum| = N² of N² unit samples,
    //     Dirichlet kernel), exactly;
    //   * with the grating: pixel (M/2, M/2 + M/P) holds |c_1|² of that, where
    //     c_1 = sin(π/L) / (q sin(π/P)) is the sampled staircase's first Fourier coefficient
    //     (the other orders vanish there: they sit on zeros of the Dirichlet kernel), and
    //     |c_1|² = sinc²(1/L) (π/P / sin(π/P))² = sinc²(1/L) (1 + 8e-4) for P = 64;
    //   * the -1 order (pixel M/2 - M/P) is empty for L >= 3 (only orders 1 + jL exist).
    // A ramp rising towards +x (a prism thicker at +x) sends the light to +x: direction and
    // amount M/P = λ z / (P Δ) / Δ pixels are checked with the efficiency.
    const std::size_t n = 128, m = 256, period = 64;
    const double px = 4e-6, wl = 550;
    const double z = double(m) * px * px / (wl * 1e-9);
    SystemConfig c = preset_config("small");
    c.n = n;
    c.padding_px = (m - n) / 2;
    c.pitch_m = px;
    c.bands = 1;
    c.wavelength_start_nm = wl;
    c.base_wavelength_nm = wl;  // h_max = one wave at 550 nm
    c.sensor_distance_m = z;
    c.validate();
    Simulator sim(runtime(), c, Precision::F32);
    REQUIRE(sim.geometry().m == m);
    const double hmax = c.h_max_m();
    // The field on the window: lens chirp times exp(i 2π H / h_max) over the N x N square.
    auto field = [&](const Map2D* grating_h) {
      ComplexStack f(1, m, m);
      const std::size_t off = (m - n) / 2;
      for (std::size_t i = 0; i < n; ++i)
        for (std::size_t j = 0; j < n; ++j) {
          const double yi = double(off + i) - double(m / 2), xj = double(off + j) - double(m / 2);
          double phase = -M_PI * (yi * yi + xj * xj) / double(m);
          if (grating_h) phase += 2 * M_PI * (*grating_h)(i, j) / hmax;
          f(0, off + i, off + j) = std::polar(1.0, phase);
        }
      return f;
    };
    const std::size_t ax = m / 2, order = m / period;
    ComplexStack lens_r;
    const ComplexStack lens_k = propagate_both(sim, field(nullptr), wl, px, z, Propagator::Fresnel, lens_r);
    const double total = double(n * n);
    const double i0_r = std::norm(lens_r(0, ax, ax)), i0_k = std::norm(lens_k(0, ax, ax));
    // Double: exact up to rounding (1e-12); float32 field and FFTs: a coherent sum of N² terms
    // with ~eps relative error each, ~1e-6; 1e-5 is the bound. A flipped propagation sign
    // leaves a chirp of twice the lens power: the axis pixel then holds ~1e-3 of the energy.
    CHECK(i0_r / total == doctest::Approx(double(n * n) / double(m * m)).epsilon(1e-12));
    CHECK(i0_k / total == doctest::Approx(double(n * n) / double(m * m)).epsilon(1e-5));
    const double sinc2_expected[4] = {0.405, 0.811, 0.950, 0.987};
    int li = 0;
    for (int levels : {2, 4, 8, 16}) {
      CAPTURE(levels);
      Quantizer q;
      q.levels = levels;
      q.placement = Placement::Wrapped;
      // Height rising by one wave per period towards +x, sampled half a sample off the level
      // boundaries ((j + 1/2) / P) so that no sample sits on a rounding tie of the quantizer
      // (floor(L u + 1/2) at exactly half-integers would split levels unevenly by rounding).
      Map2D ramp(n, n);
      for (std::size_t i = 0; i < n; ++i)
        for (std::size_t j = 0; j < n; ++j) ramp(i, j) = hmax * (double(j % period) + 0.5) / double(period);
      const Map2D hq = quantize_heights(ramp, hmax, q);
      ComplexStack gr;
      const ComplexStack gk = propagate_both(sim, field(&hq), wl, px, z, Propagator::Fresnel, gr);
      const double ql = double(period) / levels;
      const double sinc2 = std::pow(std::sin(M_PI / levels) / (M_PI / levels), 2);
      const double exact = std::pow(std::sin(M_PI / levels) / (ql * std::sin(M_PI / double(period))), 2);
      CHECK(sinc2 == doctest::Approx(sinc2_expected[li++]).epsilon(1e-3));
      CHECK(std::fabs(exact / sinc2 - 1) <= 1e-3);
      const double eta_r = std::norm(gr(0, ax, ax + order)) / i0_r, eta_k = std::norm(gk(0, ax, ax + order)) / i0_k;
      CAPTURE(eta_r);
      CAPTURE(eta_k);
      CHECK(eta_r == doctest::Approx(exact).epsilon(1e-9));
      CHECK(eta_k == doctest::Approx(exact).epsilon(1e-5));
      // Against sinc²(1/L) itself: the P = 64 sampling factor (8e-4) plus float32: 2e-3.
      CHECK(std::fabs(eta_k / sinc2 - 1) <= 2e-3);
      if (levels >= 3) {
        // The -1 order is empty: double rounding (1e-20 of the lens peak) or float32 noise
        // (amplitude ~1e-6 of the peak amplitude, intensity 1e-12); 1e-8 is the bound.
        CHECK(std::norm(gr(0, ax, ax - order)) / i0_r <= 1e-8);
        CHECK(std::norm(gk(0, ax, ax - order)) / i0_k <= 1e-8);
      }
    }
  }
}
