// The PSF stage (kernels/psf.cl; CPU reference src/physics/psf_reference.cpp): the PSF stack on
// the DOE grid and on the sensor grid against the reference in float32 and float64, and the whole
// chain heights -> PSF end to end (a diffractive lens focuses with its first dark ring where the
// Airy pattern puts it). Tolerances are derived from the kernel precision eps and stated next to
// each check.
#include <cmath>

#include "common.hpp"
#include "qdo/physics/cpu_reference.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/physics/simulator.hpp"

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

}  // namespace

TEST_SUITE("psf") {
  TEST_CASE("PSF stack on the DOE grid and on the sensor grid match the CPU reference") {
    for (Precision p : device_precisions(runtime())) {
      CAPTURE(to_string(p));
      SystemConfig c = tiny_config(64, 5);
      c.sensor_pitch_m = 10e-6;  // non-integer ratio 2.5: exercises fractional area weights
      const Map2D h = random_heights(c.n, c.h_max_m(), 13);
      Simulator sim(runtime(), c, p);
      sim.set_heights(h);
      sim.compute_psf();
      const auto want = ref::psf_stack(c, h);
      const RealStack got = sim.psf_native();
      const double m = double(sim.geometry().m);
      const double tol = 16 * eps(p) * (2 * std::log2(m) + max_phase(c));  // |U|² doubles the field error
      const auto d = diff(got.data, want.psf.data);
      CAPTURE(d.rel_l2);
      CHECK(d.rel_l2 <= tol);
      RealStack want_s = ref::resample_area(want.psf, AreaWeights::make(c.n, c.pitch_m, sim.sensor_size(), c.sensor_pitch_m));
      ref::normalize_planes(want_s);
      const auto ds = diff(sim.psf_sensor().data, want_s.data);
      CAPTURE(ds.rel_l2);
      CHECK(ds.rel_l2 <= tol);
      for (std::size_t b = 0; b < c.bands; ++b)
        CHECK(sim.sampling().bands[b].energy_outside_window ==
              doctest::Approx(want.sampling.bands[b].energy_outside_window).epsilon(1e-3).scale(1.0));
    }
  }

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
}
