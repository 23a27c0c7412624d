// The field stage (kernels/field.cl; CPU reference src/physics/field_reference.cpp): the field just
// after the DOE against the reference in float32 and float64 (and float32 with the float64 phase),
// the aperture's boundary samples, the spherical phase's float32 precision, and the debug
// accessors' effect on the adjoints. Tolerances are derived from the kernel precision eps
// (float32: 1.19e-7, float64: 2.2e-16) and stated next to each check.
#include <cmath>

#include "common.hpp"
#include "stage_probes.hpp"
#include "qdo/physics/cpu_reference.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/physics/simulator.hpp"

using namespace qdo;
using namespace qdo::test;

TEST_SUITE("field") {
  TEST_CASE("doe_field matches the CPU reference") {
    for (Precision p : device_precisions(runtime())) {
      for (bool inf : {false, true}) {
        CAPTURE(to_string(p));
        CAPTURE(inf);
        SystemConfig c = tiny_config(48, 4);
        if (inf) {
          c.scene_at_infinity = true;
          c.scene_distance_m = INFINITY;
        }
        const Map2D h = random_heights(c.n, c.h_max_m(), 11);
        Simulator sim(runtime(), c, p);
        sim.set_heights(h);
        const ComplexStack got = field_after_doe(sim);
        const ComplexStack want = ref::doe_field(c, h, sim.geometry());
        const auto d = diff(got.data, want.data);
        // Per sample: phase error <= 4 eps |phase| (argument rounding) + 4 eps (sincos).
        const double tol = 4 * eps(p) * (max_phase(c) + 1);
        CAPTURE(d.worst);
        CHECK(d.max_abs <= tol);
      }
    }
  }

  TEST_CASE("float32 with float64 phase: the field is the double field rounded once") {
    if (!skip_unless(runtime().has_fp64(), "the device has no float64")) return;
    // A large phase (short scene distance, big heights) where float32 phase arithmetic loses
    // digits: the plain float32 field errs by ~eps32 x |phase|, the phase_fp64 field only by the
    // final rounding of cos/sin to float (<= eps32 per component).
    SystemConfig c = tiny_config(64, 4);
    c.scene_distance_m = 0.02;
    const Map2D h = random_heights(c.n, c.h_max_m(), 21);
    Simulator plain(runtime(), c, Precision::F32);
    Simulator p64(runtime(), c, Precision::F32, 1, true);
    CHECK(p64.phase_fp64());
    plain.set_heights(h);
    p64.set_heights(h);
    const ComplexStack want = ref::doe_field(c, h, p64.geometry());
    // The float32 heights are themselves rounded: that is an input error both share, so the
    // reference gets the same rounded heights.
    Map2D hf = h;
    for (double& v : hf.data) v = double(float(v));
    const ComplexStack want_f = ref::doe_field(c, hf, p64.geometry());
    const auto d64 = diff(field_after_doe(p64).data, want_f.data);
    const auto d32 = diff(field_after_doe(plain).data, want_f.data);
    CAPTURE(d64.max_abs);
    CAPTURE(d32.max_abs);
    CHECK(d64.max_abs <= 2 * eps(Precision::F32));
    CHECK(d64.max_abs < d32.max_abs);
    CHECK(diff(want.data, want_f.data).max_abs < 1e-3);  // the height rounding is a small effect
    // The PSF stack through the rest of the float32 chain still matches the reference.
    p64.compute_psf();
    const auto dp = diff(p64.psf_native().data, ref::psf_stack(c, h).psf.data);
    CAPTURE(dp.rel_l2);
    CHECK(dp.rel_l2 <= 1e-5);
  }

  TEST_CASE("aperture boundary samples are the same in float32, float64 and the reference") {
    // With the release's aperture (N/2 - 1) pitch, samples on the axes sit exactly on the rim;
    // a radius test in metres rounds differently per precision and toggles whole samples
    // (a regression: it put 1e-3 relative error into float32 PSFs at N = 256).
    // Both edges: r <= R (qdo's default) and r < R (the release's, aperture_edge "strict").
    for (ApertureEdge edge : {ApertureEdge::Inclusive, ApertureEdge::Strict})
      for (std::size_t n : {64ul, 256ul, 512ul}) {
        SystemConfig c = preset_config("paper");
        c.n = n;
        c.padding_px = 0;
        c.bands = 1;
        c.aperture_edge = edge;
        c.validate();
        for (Precision p : device_precisions(runtime())) {
          Simulator sim(runtime(), c, p);
          sim.set_heights(flat_design(c));
          const ComplexStack got = field_after_doe(sim);
          const ComplexStack want = ref::doe_field(c, flat_design(c), sim.geometry());
          std::size_t toggled = 0, inside = 0;
          for (std::size_t i = 0; i < got.size(); ++i) {
            toggled += (std::abs(got.data[i]) > 0.5) != (std::abs(want.data[i]) > 0.5);
            inside += std::abs(want.data[i]) > 0.5;
          }
          // The reference keeps exactly the samples with di² + dj² <= R² (or < R²), R = N/2 - 1,
          // counted here with integers.
          const long r = long(n / 2) - 1;
          std::size_t want_inside = 0;
          for (long di = -long(n / 2); di < long(n / 2); ++di)
            for (long dj = -long(n / 2); dj < long(n / 2); ++dj)
              want_inside += edge == ApertureEdge::Strict ? di * di + dj * dj < r * r : di * di + dj * dj <= r * r;
          CAPTURE(n);
          CAPTURE(to_string(p));
          CAPTURE(int(edge));
          CHECK(toggled == 0);
          CHECK(inside == want_inside);
        }
      }
  }

  TEST_CASE("aperture_edge strict drops exactly the samples on the rim (12 at N = 1024, as the release)") {
    // REFERENCE §1: the release keeps r < (N/2 - 1) pitch; r <= adds 12 samples at N = 1024
    // (511² = 511² + 0² = 385² + 336²: 4 + 8 lattice points).
    SystemConfig c = preset_config("paper");
    const double inclusive = c.aperture_inside_px2();
    c.aperture_edge = ApertureEdge::Strict;
    const double strict = c.aperture_inside_px2();
    CHECK(inclusive == 511.0 * 511.0 + 0.5);
    CHECK(strict == 511.0 * 511.0 - 0.5);
    std::size_t rim = 0;
    for (long di = -512; di < 512; ++di)
      for (long dj = -512; dj < 512; ++dj) {
        const double r2 = double(di * di + dj * dj);
        rim += (r2 <= inclusive) != (r2 <= strict);
      }
    CHECK(rim == 12);
    // A radius that is not a lattice radius: both edges keep the same samples.
    c.aperture_radius_m = 300.5 * c.pitch_m;
    const double s2 = c.aperture_inside_px2();
    c.aperture_edge = ApertureEdge::Inclusive;
    CHECK(c.aperture_inside_px2() == s2);
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
