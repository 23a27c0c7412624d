// Every OpenCL stage against its CPU reference, in float32 and float64 kernels, on seeded
// random inputs. Tolerances are derived from the kernel precision eps (float32: 1.19e-7,
// float64: 2.2e-16) and stated next to each check.
#include <cmath>
#include <random>

#include "common.hpp"
#include "qdo/error.hpp"
#include "qdo/cpu_reference.hpp"
#include "qdo/doe.hpp"
#include "qdo/simulator.hpp"
#include "stage_probes.hpp"

using namespace qdo;
using namespace qdo::test;

namespace {

std::vector<Precision> precisions() { return device_precisions(runtime()); }

// Largest |phase| the DOE stage evaluates: source term plus DOE term at the shortest band.
double max_phase(const SystemConfig& c) {
  const double r = c.aperture_radius();
  const double k = 2 * M_PI / (c.wavelength_start_nm * 1e-9);
  const double src = c.scene_at_infinity ? 0 : r * r / (std::sqrt(r * r + c.scene_distance_m * c.scene_distance_m) + c.scene_distance_m);
  return k * (src + 0.6 * 2 * c.h_max_m());
}

}  // namespace

TEST_SUITE("kernels") {
  TEST_CASE("parameter expansion and the alpha-blended quantizer match the CPU reference") {
    for (Precision p : precisions()) {
      CAPTURE(to_string(p));
      const SystemConfig c = tiny_config(64, 1);
      const double hmax = c.h_max_m();
      Simulator sim(runtime(), c, p);
      for (Parameterization kind : {Parameterization::Full2D, Parameterization::Radial, Parameterization::Quad}) {
        CAPTURE(int(kind));
        std::mt19937_64 rng(41);
        std::uniform_real_distribution<double> u(-0.1 * hmax, 1.1 * hmax);  // some values get clamped
        std::vector<double> params(parameter_count(kind, c.n));
        for (double& v : params) v = u(rng);
        const Map2D want_full = expand_parameters(kind, params, c.n, hmax);
        sim.set_design(kind, params);
        // Expansion is a gather plus a clamp: exact up to the conversion to the kernel precision.
        CHECK(diff(sim.heights().data, want_full.data).max_abs <= eps(p) * hmax);
        for (Placement pl : {Placement::Inclusive, Placement::Wrapped}) {
          Quantizer q;
          q.levels = 5;
          q.placement = pl;
          q.offsets = {0.0, 0.3, -0.7, 1.0, -1.0};
          if (pl == Placement::Wrapped) q.level_table = {0.0, 0.15, 0.5, 0.55, 0.95};  // explicit table path
          const Map2D want = quantize_heights(want_full, hmax, q, 0.6);
          sim.set_design(kind, params, &q, 0.6);
          const Map2D got = sim.heights();
          // In float64 identical; in float32 a sample within rounding of a decision boundary may
          // pick the neighbouring level: allow 0.5 % of samples, the rest within 4 eps h_max.
          std::size_t off = 0;
          for (std::size_t i = 0; i < got.data.size(); ++i)
            if (std::fabs(got.data[i] - want.data[i]) > 4 * eps(p) * hmax) ++off;
          CAPTURE(off);
          if (p == Precision::F64) CHECK(off == 0);
          else CHECK(double(off) <= 0.005 * double(got.data.size()));
        }
      }
    }
  }

  TEST_CASE("doe_field matches the CPU reference") {
    for (Precision p : precisions()) {
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

  TEST_CASE("propagation (Fresnel and band-limited ASM) matches the CPU reference") {
    for (Precision p : precisions()) {
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

  TEST_CASE("PSF stack on the DOE grid and on the sensor grid match the CPU reference") {
    for (Precision p : precisions()) {
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

  TEST_CASE("per-band convolution (linear and circular) matches the CPU reference") {
    for (Precision p : precisions()) {
      for (ConvolutionMode mode : {ConvolutionMode::Linear, ConvolutionMode::Circular}) {
        CAPTURE(to_string(p));
        CAPTURE(int(mode));
        SystemConfig c = tiny_config(32, 3);  // sensor PSF 16 x 16
        c.convolution = mode;
        const Map2D h = random_heights(c.n, c.h_max_m(), 14);
        Simulator sim(runtime(), c, p);
        sim.set_heights(h);
        sim.compute_psf();
        const RealStack psf = sim.psf_sensor();
        // Two scene shapes (non-square, and smaller than the PSF for circular folding).
        for (auto shape : {std::pair<std::size_t, std::size_t>{20, 30}, {12, 10}}) {
          const RealStack cube = random_cube(c.bands, shape.first, shape.second, 15);
          const RealStack got = sim.convolve(cube);
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

  TEST_CASE("sensor integration with noise matches the CPU reference") {
    for (Precision p : precisions()) {
      CAPTURE(to_string(p));
      SystemConfig c = tiny_config(32, 3);
      c.read_noise_sigma = 0.01;
      c.full_well_photons = 200;  // means from 0 to 200 photons: both Poisson branches
      c.noise_seed = 0x123456789ull;
      Simulator sim(runtime(), c, p);
      const RealStack cube = random_cube(c.bands, 16, 24, 16);
      const RealStack got = sim.integrate(cube);
      RealStack want = ref::sensor_integrate(cube, sim.srf());
      ref::add_noise(want, c.read_noise_sigma, c.full_well_photons, c.noise_seed);
      // Same counters give the same integer draws; in float32 a Poisson count may still land
      // one step off when the uniform sits within rounding of a CDF step: allow 1 % of pixels.
      std::size_t off = 0;
      for (std::size_t i = 0; i < got.size(); ++i)
        if (std::fabs(got.data[i] - want.data[i]) > 1e3 * eps(p)) ++off;
      CAPTURE(off);
      if (p == Precision::F64) CHECK(off == 0);
      else CHECK(double(off) <= 0.01 * double(got.size()));
    }
  }

  TEST_CASE("a batch of scenes gives the per-scene results, noise counters included") {
    SystemConfig c = tiny_config(32, 3);
    c.read_noise_sigma = 0.02;
    c.noise_seed = 99;
    const Precision p = runtime().has_fp64() ? Precision::F64 : Precision::F32;
    Simulator sim(runtime(), c, p);
    sim.set_heights(random_heights(c.n, c.h_max_m(), 17));
    sim.compute_psf();
    const RealStack psf = sim.psf_sensor();
    std::vector<RealStack> cubes;
    for (unsigned k = 0; k < 3; ++k) cubes.push_back(random_cube(c.bands, 20, 18, 100 + k));
    const auto got = sim.sensor_images(cubes);
    REQUIRE(got.size() == 3);
    for (std::size_t k = 0; k < 3; ++k) {
      RealStack want = ref::sensor_integrate(ref::convolve(cubes[k], psf, c.convolution), sim.srf());
      ref::add_noise(want, c.read_noise_sigma, c.full_well_photons, c.noise_seed, k);
      CHECK(diff(got[k].data, want.data).max_abs <= 1e3 * eps(p));
    }
    // Batch size does not change a scene's result.
    const auto single = sim.sensor_images({cubes[0]});
    CHECK(diff(single[0].data, got[0].data).max_abs <= 1e3 * eps(p));
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
}
