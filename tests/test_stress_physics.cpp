// Stability suite (doctest suite "stress", STABILITY.md): the forward model at the legal
// extremes of the configuration (distances, pitches, heights at and across the phase wrap,
// quantizers, 1 to 301 spectral samples, degenerate scenes and batches, N from 16 to 4096),
// checked for invariants rather than "no crash": unit-sum PSFs, energy accounted for,
// float32 ~ float64 ~ the CPU reference, honest sampling reports.
//
// Cases whose name ends in "[slow]" run under the CTest label "stress" (ctest -L stress);
// the others with the default label (CTest entry "stress-quick").
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "stage_probes.hpp"
#include "stress_common.hpp"
#include "qdo/physics/adjoint.hpp"
#include "qdo/physics/cpu_reference.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/simulator.hpp"

using namespace qdo;
using namespace qdo::test;
using namespace qdo::test::stress_suite;
namespace fs = std::filesystem;

TEST_SUITE("stress") {
  TEST_CASE("distance, pitch and sensor-distance extremes: finite unit-sum PSFs, energy accounted, f32 ~ f64, honest reports") {
    // N = 32 (M = 48), 3 bands 450..550 nm, a lens and random heights. Scene 0.05 m .. 1 km and
    // infinity; sensor 1 mm .. 1 m; pitch 0.5 .. 20 um: 36 geometries x 2 designs x 2 precisions.
    REQUIRE(runtime().has_fp64());
    double worst_f32 = 0, worst_ref = 0;
    std::size_t flagged = 0, total = 0;
    for (double pitch : {0.5e-6, 4e-6, 20e-6})
      for (double d : {0.05, 1.0, 1000.0, kInf})
        for (double z : {1e-3, 0.03, 1.0}) {
          const SystemConfig c = extreme_config(32, pitch, d, z);
          CAPTURE(describe(c));
          Simulator s64(runtime(), c, Precision::F64), s32(runtime(), c, Precision::F32);
          for (int design = 0; design < 2; ++design) {
            CAPTURE(design);
            const Map2D h = design == 0 ? lens_design(c, 500) : random_heights(c.n, c.h_max_m(), 17);
            s64.set_heights(h);
            s32.set_heights(h);
            s64.compute_psf();
            s32.compute_psf();
            const RealStack p64 = s64.psf_sensor(), p32 = s32.psf_sensor();
            check_unit_planes(s64.psf_native(), 1e-12, "f64 native");
            check_unit_planes(p64, 1e-12, "f64 sensor");
            check_unit_planes(s32.psf_native(), 2e-5, "f32 native");
            check_unit_planes(p32, 2e-5, "f32 sensor");
            // float32 vs float64: relative L2 over the stack (bound stated in STABILITY.md).
            const double e32 = rel_l2(p32.data, p64.data);
            worst_f32 = std::max(worst_f32, e32);
            CAPTURE(e32);
            CHECK(e32 <= 1e-5);
            // float64 kernels vs the double CPU reference.
            const double er = rel_l2(p64.data, ref::psf_sensor_stack(c, h).data);
            worst_ref = std::max(worst_ref, er);
            CHECK(er <= 1e-9);
            // Energy: the Fresnel transfer function is unitary (Parseval), and the reported
            // energy outside the N x N window equals what the field itself says.
            const SamplingReport rep = s64.sampling(), rep32 = s32.sampling();  // copies: the debug calls below redo the stages
            const ComplexStack before = field_after_doe(s64);
            const ComplexStack after = field_after_propagation(s64);
            std::vector<double> crop0, tot0, crop1, tot1;
            window_energies(before, s64.geometry(), crop0, tot0);
            window_energies(after, s64.geometry(), crop1, tot1);
            REQUIRE(rep.bands.size() == c.bands);
            for (std::size_t b = 0; b < c.bands; ++b) {
              CAPTURE(b);
              CHECK(std::fabs(tot1[b] - tot0[b]) <= 1e-10 * tot0[b]);
              const BandSampling& bs = rep.bands[b];
              CHECK(bs.aliased_energy_fraction >= 0);
              CHECK(bs.aliased_energy_fraction <= 1 + 1e-12);
              CHECK(bs.energy_outside_window == doctest::Approx(1 - crop1[b] / tot1[b]).epsilon(1e-9).scale(1));
              CHECK(rep32.bands[b].energy_outside_window == doctest::Approx(bs.energy_outside_window).epsilon(1e-4).scale(1));
              CHECK(rep32.bands[b].aliased_energy_fraction == doctest::Approx(bs.aliased_energy_fraction).epsilon(1e-4).scale(1));
            }
            // The tool says so: an inaccurate configuration is refused in strict mode, and only then.
            ++total;
            SystemConfig strict = c;
            strict.strict_sampling = true;
            Simulator ss(runtime(), strict, Precision::F64);
            ss.set_heights(h);
            if (rep.any_inaccurate()) {
              ++flagged;
              CHECK(has(rep.summary(), "INACCURATE"));
              CHECK_THROWS_WITH_AS(ss.compute_psf(), doctest::Contains("under-sampled"), AccuracyError);
            } else {
              CHECK_NOTHROW(ss.compute_psf());
            }
            // Adjoint: finite for a random cotangent, in both precisions.
            const RealStack g = random_stack(c.bands, s64.sensor_size(), s64.sensor_size(), 5);
            CHECK(all_finite(s64.psf_sensor_vjp(g).data));
            CHECK(all_finite(s32.psf_sensor_vjp(g).data));
          }
        }
    MESSAGE("worst f32 vs f64 " << worst_f32 << ", worst f64 vs CPU reference " << worst_ref << "; " << flagged << " of "
                                << total << " cases flagged inaccurate");
    CHECK(flagged > 0);          // the sweep does reach the under-sampled corner
    CHECK(flagged < total);      // and the well-sampled one
  }

  TEST_CASE("the angular-spectrum propagator at the extremes: unit-sum PSFs, f32 ~ f64, energy only removed") {
    REQUIRE(runtime().has_fp64());
    for (double pitch : {0.5e-6, 20e-6})
      for (double z : {1e-3, 1.0}) {
        SystemConfig c = extreme_config(32, pitch, kInf, z);
        c.propagator = Propagator::AngularSpectrum;
        CAPTURE(describe(c));
        Simulator s64(runtime(), c, Precision::F64), s32(runtime(), c, Precision::F32);
        const Map2D h = random_heights(c.n, c.h_max_m(), 3);
        s64.set_heights(h);
        s32.set_heights(h);
        s64.compute_psf();
        s32.compute_psf();
        check_unit_planes(s64.psf_sensor(), 1e-12, "asm f64");
        check_unit_planes(s32.psf_sensor(), 2e-5, "asm f32");
        CHECK(rel_l2(s32.psf_sensor().data, s64.psf_sensor().data) <= 2e-4);
        std::vector<double> c0, t0, c1, t1;
        window_energies(field_after_doe(s64), s64.geometry(), c0, t0);
        window_energies(field_after_propagation(s64), s64.geometry(), c1, t1);
        for (std::size_t b = 0; b < c.bands; ++b) {
          // The band limit and the evanescent cut remove energy; nothing adds it.
          CHECK(t1[b] <= t0[b] * (1 + 1e-10));
          CHECK(t1[b] > 0);
        }
      }
  }

  TEST_CASE("heights at 0, at h_max and straddling the phase wrap") {
    // Bands 500, 600, 700 nm: at 700 nm (the base wavelength) h_max is exactly one 2pi phase.
    SystemConfig c = extreme_config(32, 4e-6, 1.0, 1.5625e-3);
    c.wavelength_start_nm = 500;
    c.wavelength_step_nm = 100;
    c.validate();
    const double hmax = c.h_max_m();
    for (Precision p : {Precision::F32, Precision::F64}) {
      CAPTURE(to_string(p));
      const double tol = p == Precision::F64 ? 1e-12 : 2e-5;
      Simulator sim(runtime(), c, p);
      // Any constant height is a constant phase: the PSF of H = 0, h_max and 2 h_max is the
      // same in every band.
      sim.set_heights(Map2D(c.n, c.n, 0.0));
      sim.compute_psf();
      const RealStack flat0 = sim.psf_sensor();
      check_unit_planes(flat0, tol, "H = 0");
      for (double level : {hmax, 2 * hmax, 0.37 * hmax}) {
        sim.set_heights(Map2D(c.n, c.n, level));
        sim.compute_psf();
        CHECK(rel_l2(sim.psf_sensor().data, flat0.data) <= (p == Precision::F64 ? 1e-12 : 3e-6));
      }
      // Straddling the wrap: H and H - h_max (for H > h_max) differ by 2pi at 700 nm only.
      Map2D up = random_heights(c.n, 2e-9, 9), wrapped(c.n, c.n);
      for (std::size_t i = 0; i < up.data.size(); ++i) {
        up.data[i] += hmax - 1e-9;  // h_max - 1 nm .. h_max + 1 nm
        wrapped.data[i] = up.data[i] >= hmax ? up.data[i] - hmax : up.data[i];
      }
      sim.set_heights(up);
      sim.compute_psf();
      const RealStack a = sim.psf_sensor();
      sim.set_heights(wrapped);
      sim.compute_psf();
      const RealStack b = sim.psf_sensor();
      check_unit_planes(a, tol, "straddling");
      const std::size_t plane = a.plane_size();
      const std::vector<double> a700(a.plane(2), a.plane(2) + plane), b700(b.plane(2), b.plane(2) + plane);
      CHECK(rel_l2(a700, b700) <= (p == Precision::F64 ? 1e-10 : 5e-6));
      // Out of range: rejected before any device work, naming the sample.
      Map2D bad(c.n, c.n, 0.0);
      bad(3, 4) = 2 * hmax * (1 + 1e-9);
      CHECK_THROWS_WITH_AS(sim.set_heights(bad), doctest::Contains("height_m[3][4]"), InputError);
      bad(3, 4) = -1e-15;
      CHECK_THROWS_AS(sim.set_heights(bad), InputError);
      bad(3, 4) = std::nan("");
      CHECK_THROWS_AS(sim.set_heights(bad), InputError);
    }
  }

  TEST_CASE("quantizer extremes: L = 2 .. 256, offsets at their clip limits, exact decision boundaries") {
    const SystemConfig c = extreme_config(32, 4e-6, 1.0, 1.5625e-3);
    const double hmax = c.h_max_m();
    Simulator sim(runtime(), c, Precision::F64);
    for (int levels : {2, 3, 4, 8, 16, 64, 256})
      for (Placement pl : {Placement::Inclusive, Placement::Wrapped})
        for (int mode = 0; mode < 4; ++mode) {
          Quantizer q;
          q.levels = levels;
          q.placement = pl;
          const double lim = levels == 2 ? 0.2 : 1.0;
          if (mode > 0) {
            q.offsets.assign(std::size_t(levels), 0.0);
            for (int l = 1; l < levels; ++l)
              q.offsets[std::size_t(l)] = mode == 1 ? lim : mode == 2 ? -lim : (l % 2 ? lim : -lim);
          }
          CAPTURE(levels);
          CAPTURE(to_string(pl));
          CAPTURE(mode);
          REQUIRE_NOTHROW(q.validate());
          const auto lv = q.level_heights_m(hmax);
          for (double v : lv) {
            CHECK(v >= 0);
            CHECK(v <= 2 * hmax);  // set_heights' range, so every fabricated design can be simulated
          }
          // Parameters on the radial grid: random, the ends, and exact decision boundaries
          // u = (k + 0.5) / (L - 1) (inclusive) or (k + 0.5) / L (wrapped), where rounding ties.
          std::vector<double> params(parameter_count(Parameterization::Radial, c.n));
          std::mt19937_64 rng(std::uint64_t(levels) * 7 + std::uint64_t(mode));
          const double denom = pl == Placement::Inclusive ? levels - 1 : levels;
          for (std::size_t i = 0; i < params.size(); ++i) {
            const double u = i == 0 ? 0.0 : i == 1 ? 1.0 : i % 3 == 0 ? (double(rng() % std::uint64_t(levels)) + 0.5) / denom
                                                                      : double(rng() >> 11) * 0x1.0p-53;
            params[i] = std::min(1.0, u) * hmax;
          }
          const Map2D hf = expand_parameters(Parameterization::Radial, params, c.n, hmax);
          for (double alpha : {0.0, 0.5, 1.0}) {
            const Map2D host = quantize_heights(hf, hmax, q, alpha);
            sim.set_design(Parameterization::Radial, params, &q, alpha);
            const Map2D dev = sim.heights();
            CHECK(diff(dev.data, host.data).max_abs <= 4e-16 * hmax * levels);
          }
          const Map2D fab = quantize_heights(hf, hmax, q, 1.0);
          const std::set<double> distinct(fab.data.begin(), fab.data.end());
          CHECK(distinct.size() <= std::size_t(levels));
          sim.set_heights(fab);
          sim.compute_psf();
          check_unit_planes(sim.psf_sensor(), 1e-12, "quantized");
          // Offsets gradient at the clip limits against central differences (smooth in a_l).
          const Map2D g = random_heights(c.n, 1.0, 11);
          const auto vjp = ref::quantize_vjp(hf, hmax, q, 0.7, g);
          CHECK(all_finite(vjp.g_offsets));
          if (mode > 0)
            for (int l = 1; l < levels; l += std::max(1, levels / 5)) {
              // One-sided difference from the limit inward (the map is linear in a_l).
              Quantizer a = q;
              const double step = q.offsets[std::size_t(l)] > 0 ? -1e-6 : 1e-6;
              a.offsets[std::size_t(l)] += step;
              const double l0 = dot(g.data, quantize_heights(hf, hmax, q, 0.7).data);
              const double l1 = dot(g.data, quantize_heights(hf, hmax, a, 0.7).data);
              CAPTURE(l);
              CHECK(std::fabs((l1 - l0) / step - vjp.g_offsets[std::size_t(l)]) <= 1e-6 * (1 + std::fabs(vjp.g_offsets[std::size_t(l)])));
            }
        }
  }

  TEST_CASE("1 to 301 spectral samples (srf_interpolate): unit PSFs, a flat spectrum stays flat") {
    for (std::size_t bands : {1ul, 2ul, 31ul, 301ul}) {
      SystemConfig c = extreme_config(32, 4e-6, 1.0, 1.5625e-3, bands);
      c.wavelength_start_nm = 400;
      c.wavelength_step_nm = bands > 1 ? 300.0 / double(bands - 1) : 1.0;
      c.srf_interpolate = true;
      c.validate();
      CAPTURE(bands);
      const Eigen::MatrixXd srf = sensor_response(c);
      for (int r = 0; r < 3; ++r) CHECK(srf.row(r).sum() == doctest::Approx(1).epsilon(1e-12));
      for (Precision p : {Precision::F32, Precision::F64}) {
        Simulator sim(runtime(), c, p);
        sim.set_heights(random_heights(c.n, c.h_max_m(), 4));
        sim.compute_psf();
        check_unit_planes(sim.psf_sensor(), p == Precision::F64 ? 1e-12 : 2e-5, "bands");
        CHECK(sim.sampling().bands.size() == bands);
        // Eq. 7: a flat spectrum of 0.25 integrates to 0.25 in every channel.
        const RealStack flat(bands, 5, 4, 0.25);
        const RealStack rgb = sim.integrate(flat);
        for (double v : rgb.data) CHECK(v == doctest::Approx(0.25).epsilon(p == Precision::F64 ? 1e-12 : 1e-5));
      }
    }
    SystemConfig c = tiny_config(32, 1);
    c.bands = 1002;
    CHECK_THROWS_WITH_AS(c.validate(), doctest::Contains("'bands'"), InputError);
  }

  TEST_CASE("scenes all zero, constant, one bright pixel; results independent of the batch") {
    // Work-group size is fixed (Runtime::kLocalSize = 128) in this code base, so only the batch
    // size can vary: a scene's image must not depend on its batch or its position in it.
    double worst_batch = 0;
    for (ConvolutionMode mode : {ConvolutionMode::Linear, ConvolutionMode::Circular})
      for (Precision p : {Precision::F32, Precision::F64}) {
        SystemConfig c = extreme_config(32, 4e-6, 1.0, 1.5625e-3);
        c.convolution = mode;
        CAPTURE(int(mode));
        CAPTURE(to_string(p));
        const double tol = p == Precision::F64 ? 1e-12 : 2e-6;
        Simulator sim(runtime(), c, p);
        Camera cam(sim);
        sim.set_heights(lens_design(c, 500));
        sim.compute_psf();
        const RealStack psf = sim.psf_sensor();
        const std::size_t S = sim.sensor_size(), H = 40, W = 48;  // S = 16; 40 = 2^3 5, 48 = 2^4 3
        const RealStack zero(c.bands, H, W, 0.0), constant(c.bands, H, W, 0.5);
        RealStack bright(c.bands, H, W, 0.0);
        for (std::size_t b = 0; b < c.bands; ++b) bright(b, H / 2, W / 2) = 1.0;
        const RealStack noisy = random_cube(c.bands, H, W, 3);
        // One bright pixel: the image is the PSF itself (the PSF fits inside the scene).
        const RealStack blur = cam.blur({bright}).front();
        CHECK(all_finite(blur.data));
        double worst = 0;
        for (std::size_t b = 0; b < c.bands; ++b) {
          double sum = 0;
          for (std::size_t y = 0; y < S; ++y)
            for (std::size_t x = 0; x < S; ++x) {
              worst = std::max(worst, std::fabs(blur(b, H / 2 - S / 2 + y, W / 2 - S / 2 + x) - psf(b, y, x)));
              sum += blur(b, H / 2 - S / 2 + y, W / 2 - S / 2 + x);
            }
          CHECK(sum == doctest::Approx(1).epsilon(tol * 10));
        }
        CHECK(worst <= tol);
        // All zero stays exactly zero; a constant stays constant where the PSF is inside the
        // scene (everywhere for circular convolution).
        const RealStack z = cam.blur({zero}).front();
        CHECK(std::all_of(z.data.begin(), z.data.end(), [](double v) { return v == 0.0; }));
        const RealStack k = cam.blur({constant}).front();
        double kerr = 0;
        for (std::size_t b = 0; b < c.bands; ++b)
          for (std::size_t y = S; y + S < H; ++y)
            for (std::size_t x = S; x + S < W; ++x) kerr = std::max(kerr, std::fabs(k(b, y, x) - 0.5));
        if (mode == ConvolutionMode::Circular)
          for (double v : k.data) kerr = std::max(kerr, std::fabs(v - 0.5));
        CHECK(kerr <= 10 * tol);
        // Batches: each scene's image equals its image alone, for batch sizes 1, 2, 3 and 5.
        const std::vector<RealStack> scenes = {zero, constant, bright, noisy, bright};
        std::vector<RealStack> alone;
        for (const auto& sc : scenes) alone.push_back(cam.images({sc}, no_skipping()).front());
        for (std::size_t batch : {1ul, 2ul, 3ul, 5ul})
          for (std::size_t first = 0; first + batch <= scenes.size(); first += batch) {
            const std::vector<RealStack> in(scenes.begin() + long(first), scenes.begin() + long(first + batch));
            const std::vector<RealStack> out = cam.images(in, no_skipping());
            for (std::size_t i = 0; i < batch; ++i) {
              CAPTURE(batch);
              CAPTURE(first + i);
              CHECK(all_finite(out[i].data));
              const double d = diff(out[i].data, alone[first + i].data).max_abs;
              worst_batch = std::max(worst_batch, d);
              CHECK(d <= tol);
            }
          }
        // The sensor adjoint through a batch: finite for every scene type.
        std::vector<RealStack> g;
        for (std::size_t i = 0; i < scenes.size(); ++i) g.push_back(random_stack(3, H, W, unsigned(i)));
        cam.images(scenes, no_skipping());
        CHECK(all_finite(cam.vjp(g, false).psf.data));
      }
    MESSAGE("largest difference between a scene's image in a batch and alone: " << worst_batch);
  }

  TEST_CASE("N from 16 to 256: invariants and f32 ~ f64 ~ CPU reference at every size") {
    for (std::size_t n : {16ul, 32ul, 64ul, 128ul, 256ul}) {
      SystemConfig c = tiny_config(n, 3);
      c.read_noise_sigma = 0;
      CAPTURE(n);
      const Map2D h = random_heights(n, c.h_max_m(), 6);
      Simulator s64(runtime(), c, Precision::F64), s32(runtime(), c, Precision::F32);
      s64.set_heights(h);
      s32.set_heights(h);
      s64.compute_psf();
      s32.compute_psf();
      check_unit_planes(s64.psf_sensor(), 1e-12, "f64");
      check_unit_planes(s32.psf_sensor(), 2e-5, "f32");
      CHECK(rel_l2(s32.psf_sensor().data, s64.psf_sensor().data) <= 2e-4);
      CHECK(rel_l2(s64.psf_sensor().data, ref::psf_sensor_stack(c, h).data) <= 1e-9);
    }
  }

  TEST_CASE("under-sampling of the point source's spherical wave on the DOE grid is reported") {
    // Regression (the sampling report used to check only the transfer function). A source at d = 0.05 m seen through a 20 um grid of N = 64 has a
    // local phase frequency r / (lambda d) = 27.6 /mm at the aperture rim, above the grid's
    // Nyquist 25 /mm, so the field after the DOE aliases (and float32 phases grow with it), yet
    // strict_sampling accepts it. Expected: SamplingReport flags the band and enforce() throws
    // AccuracyError naming the source distance and the remedy (finer pitch or larger d).
    SystemConfig c = extreme_config(64, 20e-6, 0.05, 0.1, 3);  // lambda z <= M pitch^2: the transfer function is fine
    c.padding_px = 64;
    c.strict_sampling = true;
    c.validate();
    Simulator sim(runtime(), c, Precision::F64);
    sim.set_heights(flat_design(c));
    CHECK_THROWS_WITH_AS(sim.compute_psf(), doctest::Contains("scene_distance_m"), AccuracyError);
  }

  TEST_CASE("large grids: N = 1024 (31 bands), 2048 (3 bands), 4096 (1 band) against the CPU reference [slow]") {
    // The envelope's upper end on PoCL (8 GiB device memory, 4 GiB per allocation, 2 cores):
    // N = 4096 with N/4 padding is a 6144^2 field per band (302 MiB in float32).
    struct Size {
      std::size_t n, bands;
    };
    for (const Size& z : {Size{1024, 31}, Size{2048, 3}, Size{4096, 1}}) {
      SystemConfig c = preset_config("paper");
      c.n = z.n;
      c.padding_px = z.n / 4;
      c.bands = z.bands;
      if (z.bands < 31) {
        c.wavelength_start_nm = 450;
        c.wavelength_step_nm = 100;
      }
      c.sensor_distance_m = 0.05 * double(z.n) / 1024.0;  // the paper's NA and sampling ratio
      c.read_noise_sigma = 0;
      c.validate();
      CAPTURE(describe(c));
      const Map2D h = lens_design(c, 550);
      auto t0 = std::chrono::steady_clock::now();
      auto secs = [&t0] {
        const double v = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        t0 = std::chrono::steady_clock::now();
        return v;
      };
      const RealStack want = ref::psf_sensor_stack(c, h);
      MESSAGE("N = " << c.n << ": CPU reference " << secs() << " s");
      for (Precision p : {Precision::F32, Precision::F64}) {
        CAPTURE(to_string(p));
        Simulator sim(runtime(), c, p);
        sim.set_heights(h);
        sim.compute_psf();
        MESSAGE("N = " << c.n << " " << to_string(p) << ": set-up and PSF " << secs() << " s (includes building FFT kernels)");
        const RealStack got = sim.psf_sensor();
        check_unit_planes(got, p == Precision::F64 ? 1e-11 : 1e-4, "large N");
        const double e = rel_l2(got.data, want.data);
        CAPTURE(e);
        MESSAGE("N = " << c.n << " " << to_string(p) << ": rel. L2 vs CPU reference " << e << "; "
                       << sim.sampling().summary());
        CHECK(e <= (p == Precision::F64 ? 1e-9 : 1e-4));
        for (const auto& b : sim.sampling().bands) {
          CHECK(b.aliased_energy_fraction >= 0);
          CHECK(b.aliased_energy_fraction <= 1);
          CHECK(b.energy_outside_window >= 0);
          CHECK(b.energy_outside_window <= 1);
        }
      }
    }
  }
}
