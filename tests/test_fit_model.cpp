// The as-built fit's model (suite `fit`, include/qdo/asbuilt/fit.hpp): its lateral moves, the
// bilinear shift of a stack (integer and fractional shifts) and the registration
// that moves the pixel grid over the native PSF (against the native PSF cut into sub-cells, moved
// and integrated; its adjoint; a fit that recovers it), and the piston that lifts a level below
// level 0, and the relief offset as the fit models it (an exact move: whole pixels in the map, the
// rest as the optical axis moved, continuous across the switch). The fits themselves are
// tests/test_fit.cpp.
#include <doctest/doctest.h>

#include <cmath>
#include <string>
#include <vector>

#include "adjoint_ladder.hpp"
#include "common.hpp"
#include "fit_common.hpp"
#include "qdo/asbuilt/fit.hpp"
#include "qdo/physics/cpu_reference.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/psf_reference.hpp"
#include "qdo/physics/simulator.hpp"

using namespace qdo;
using namespace qdo::test;

TEST_SUITE("fit") {
  TEST_CASE("shift_bilinear: integer shifts exact, a fraction the linear blend of its two neighbours") {
    const std::size_t planes = 2, rows = 7, cols = 9;
    const RealStack x = uniform_stack(planes, rows, cols, 1);
    // An integer shift moves samples exactly: out(2, 3) = in(2 + 1, 3 - 2) for (sx, sy) = (2, -1).
    const auto y = shift_bilinear(x.data, planes, rows, cols, 2.0, -1.0);
    CHECK(y[2 * cols + 3] == x.data[3 * cols + 1]);
    CHECK(y[(rows - 1) * cols + 3] == 0.0);  // brought in from outside
    // (0.25, 0) on plane 1: out(y, x) = 0.75 in(y, x) + 0.25 in(y, x - 1).
    const auto z = shift_bilinear(x.data, planes, rows, cols, 0.25, 0.0);
    const std::size_t p1 = rows * cols;
    CHECK(z[p1 + 4 * cols + 5] == doctest::Approx(0.75 * x.data[p1 + 4 * cols + 5] + 0.25 * x.data[p1 + 4 * cols + 4]).epsilon(1e-15));
    CHECK(z[p1 + 4 * cols + 0] == doctest::Approx(0.75 * x.data[p1 + 4 * cols + 0]).epsilon(1e-15));
  }

  TEST_CASE("the registration moves the pixel grid: a grid off by whole DOE pixels is the model at that shift; the fit recovers it") {
    // The truth by another route: the design's native PSF (bands x N x N on the DOE grid) moved by
    // whole DOE pixels (samples copied), then integrated onto the sensor pixels
    // (ref::resample_area, S = N / 2: a DOE pixel is half a sensor pixel). A sensor grid off by
    // (kx, ky) DOE pixels is the registration (sx, sy) = (kx, ky) x pitch / sensor pitch.
    const SystemConfig cfg = fit_config();
    const Design d = quantized_lens(cfg);
    const std::size_t n = cfg.n;
    RealStack native, at_zero;
    {
      Simulator sim(runtime(), cfg, Precision::F64);
      sim.set_heights(d.height_m);
      sim.compute_psf();
      native = sim.psf_native();
      at_zero = sim.psf_sensor();
    }
    // The native stack cut into f x f sub-cells, f odd (each a uniform share of its cell: the cells
    // are uniform in the model; the middle sub-cell of the axis cell N/2 is the finer grid's axis
    // sample m/2), moved by (mx, my) sub-cells on a grid padded by 8 cells a side (nothing falls
    // off), integrated onto the sensor pixels and normalised.
    const auto moved_then_integrated = [&](std::size_t f, long mx, long my) {
      REQUIRE(f % 2 == 1);
      const std::size_t pad = 8 * f, m = n * f + 2 * pad, left = pad - (f - 1) / 2;
      RealStack moved(native.planes, m, m, 0.0);
      for (std::size_t b = 0; b < native.planes; ++b)
        for (std::size_t y = 0; y < n * f; ++y)
          for (std::size_t x = 0; x < n * f; ++x)
            moved(b, std::size_t(long(y + left) + my), std::size_t(long(x + left) + mx)) =
                native(b, y / f, x / f) / double(f * f);
      RealStack out =
          ref::resample_area(moved, AreaWeights::make(m, cfg.pitch_m / double(f), cfg.sensor_size_px(), cfg.sensor_pitch_m));
      ref::normalize_planes(out);
      return out;
    };
    const auto rel_l2 = [](const std::vector<double>& a, const std::vector<double>& b) {
      double num = 0, den = 0;
      for (std::size_t i = 0; i < a.size(); ++i) {
        num += (a[i] - b[i]) * (a[i] - b[i]);
        den += b[i] * b[i];
      }
      return std::sqrt(num / den);
    };
    const double ratio = cfg.sensor_pitch_m / cfg.pitch_m;
    REQUIRE(ratio == 2.0);
    // At zero shift the integration is the simulator's own sensor stack, and the route above too.
    CHECK(rel_l2(integrate_registered(native, cfg, 0, 0).data, at_zero.data) < 1e-12);
    CHECK(rel_l2(moved_then_integrated(1, 0, 0).data, at_zero.data) < 1e-12);
    // Whole DOE pixels: (1, -3) -> (0.5, -1.5) sensor px. In double, to rounding.
    const RealStack truth_stack = moved_then_integrated(1, 1, -3);  // f = 1: the cells themselves
    CHECK(rel_l2(integrate_registered(native, cfg, 0.5, -1.5).data, truth_stack.data) < 1e-12);
    // Fractions of a DOE pixel, on sub-cells: (1, -2) thirds -> (1/6, -1/3) sensor px, (-3, 2)
    // fifths -> (-0.3, 0.2).
    CHECK(rel_l2(integrate_registered(native, cfg, 1.0 / 6, -1.0 / 3).data, moved_then_integrated(3, 1, -2).data) < 1e-12);
    CHECK(rel_l2(integrate_registered(native, cfg, -0.3, 0.2).data, moved_then_integrated(5, -3, 2).data) < 1e-12);
    // The bilinear shift of the sampled stack the fit used before blurs by up to a sensor pixel.
    const std::vector<double> blurred = shift_bilinear(at_zero.data, at_zero.planes, at_zero.rows, at_zero.cols, 0.5, -1.5);
    const double err_bilinear = rel_l2(blurred, truth_stack.data);
    INFO("a bilinear shift of the sensor stack is " << err_bilinear << " (relative L2) from the moved grid's");
    CHECK(err_bilinear > 0.05);
    // Its adjoint: <A x, g> = <x, A^T g> for the normalised integration's linearisation, by central
    // differences along a random direction of the native stack.
    {
      const RealStack g = uniform_stack(native.planes, at_zero.rows, at_zero.cols, 31);
      const RealStack dir = uniform_stack(native.planes, n, n, 32);
      const RealStack gx = integrate_registered_adjoint(g, native, cfg, 0.3, -0.7);
      const double h = 1e-6;
      RealStack a = native, b = native;
      for (std::size_t i = 0; i < a.data.size(); ++i) {
        a.data[i] += h * dir.data[i];
        b.data[i] -= h * dir.data[i];
      }
      const RealStack fa = integrate_registered(a, cfg, 0.3, -0.7), fb = integrate_registered(b, cfg, 0.3, -0.7);
      double fd = 0, ad = 0;
      for (std::size_t i = 0; i < fa.data.size(); ++i) fd += g.data[i] * (fa.data[i] - fb.data[i]) / (2 * h);
      for (std::size_t i = 0; i < gx.data.size(); ++i) ad += gx.data[i] * dir.data[i];
      INFO("adjoint " << ad << ", central differences " << fd);
      CHECK(std::fabs(ad - fd) <= 1e-7 * std::fabs(fd));
    }
    // The fit from the design (the registration's start at the centroid difference) recovers
    // (0.5, -1.5) and leaves the levels where they are: the moved grid is in the model.
    FitOptions opt;
    opt.parameters = {"levels", "shift"};
    opt.max_iterations = 40;
    const FitResult r = fit_as_built(runtime(), cfg, Precision::F64, d, truth_stack, opt);
    for (const FitValue& v : r.values) {
      CAPTURE(v.name);
      INFO("fitted " << v.value << " (design " << v.design << ")");
      if (v.name == "sx") CHECK(std::fabs(v.value - 0.5) < 1e-3);
      else if (v.name == "sy") CHECK(std::fabs(v.value + 1.5) < 1e-3);
      else CHECK(std::fabs(v.value - v.design) < 0.05e-9);
    }
    CHECK(r.loss_final < 1e-8 * r.loss_design);
  }

  TEST_CASE("the relief offset is an exact move: whole pixels in the map, the rest as the axis moved; continuous where they switch") {
    const SystemConfig cfg = fit_config();
    const Design d = quantized_lens(cfg);
    AsBuiltModel m(runtime(), cfg, Precision::F64, d, {"levels", "offset"});
    REQUIRE(m.parameter_names().size() == 5);  // level1..3, dx, dy
    const double p = cfg.pitch_m;
    std::vector<double> th = m.design_values();
    // dx = 2 pixels, dy = -1 pixel: the map rolled (zero relief brought in), the axis on the grid's
    // centre, the aperture area-weighted; every pixel still holds a design level.
    th[3] = 2 * p;
    th[4] = -p;
    const Map2D h = m.heights(th);
    const SystemConfig c = m.config(th);
    CHECK(c.aperture_edge == ApertureEdge::Area);
    CHECK(std::fabs(c.aperture_offset_x_m) < 1e-18);
    CHECK(std::fabs(c.aperture_offset_y_m) < 1e-18);
    for (std::size_t i = 0; i < cfg.n; ++i)
      for (std::size_t j = 0; j < cfg.n; ++j)
        CHECK(h(i, j) == (j >= 2 && i + 1 < cfg.n ? d.height_m(i + 1, j - 2) : 0.0));
    Simulator sim(runtime(), c, Precision::F64);
    sim.set_heights(h);
    sim.compute_psf();
    CHECK(diff(m.evaluate(th).data, sim.psf_sensor().data).rel_l2 < 1e-12);
    // dx = 0.3 px: the map unmoved, the axis at -0.3 px.
    th[3] = 0.3 * p;
    th[4] = 0;
    CHECK(m.heights(th).data == d.height_m.data);
    CHECK(m.config(th).aperture_offset_x_m == doctest::Approx(-0.3 * p).epsilon(1e-12));
    // Across the switch at half a pixel (0.5 - e: the axis at -0.5 + e px; 0.5 + e: the map one
    // pixel over, the axis at +0.5 - e px) the two are one camera, and the model differs only by the
    // light the sensor window, centred on the axis, finds beyond the native N x N crop: at an axis
    // half a pixel to one side it reaches one DOE column past the crop (no light computed there),
    // half a pixel to the other it does not. So the jump is that column's light (here, a 64-pixel
    // lens whose PSF fills the window, 0.4 %), far above a step of 2e on one side, and bounded by it.
    const double e = 1e-4 * p;
    const auto at = [&](double dx) {
      std::vector<double> t2 = m.design_values();
      t2[3] = dx;
      return m.evaluate(t2);
    };
    const RealStack below = at(0.5 * p - e), above = at(0.5 * p + e), further = at(0.5 * p - 3 * e);
    const double jump = diff(below.data, above.data).rel_l2, step = diff(further.data, below.data).rel_l2;
    {  // The light of the native column next to the crop's edge that the window leaves at the switch.
      std::vector<double> t2 = m.design_values();
      t2[3] = 0.5 * p + e;
      Simulator s2(runtime(), m.config(t2), Precision::F64);
      s2.set_heights(m.heights(t2));
      s2.compute_psf();
      const RealStack nat = s2.psf_native();
      double col = 0;  // the largest share of a plane's light in its first or last column
      for (std::size_t b = 0; b < nat.planes; ++b) {
        double c0 = 0, c1 = 0, t0 = 0;
        for (std::size_t i = 0; i < cfg.n; ++i) {
          c0 += nat(b, i, 0);
          c1 += nat(b, i, cfg.n - 1);
          for (std::size_t j2 = 0; j2 < cfg.n; ++j2) t0 += nat(b, i, j2);
        }
        col = std::max(col, std::max(c0, c1) / t0);
      }
      CAPTURE(jump);
      CAPTURE(step);
      CAPTURE(col);
      CHECK(step > 0);
      CHECK(jump < 4 * col + 2 * step);  // relative L2 of a plane against its edge column's share of light
    }
    // The offset's gradient entries (central differences of the loss) agree with the Jacobian's
    // columns and are not zero.
    th = m.design_values();
    th[3] = 0.21 * p;
    th[4] = -0.37 * p;
    const RealStack meas = at(0.1 * p);
    std::vector<double> g;
    m.loss_gradient(th, meas, g);
    const Eigen::MatrixXd j = m.jacobian(th);
    const RealStack model = m.evaluate(th);
    for (std::size_t k : {std::size_t(3), std::size_t(4)}) {
      CAPTURE(k);
      double jr = 0;
      for (std::size_t i = 0; i < model.data.size(); ++i) jr += j(long(i), long(k)) * (model.data[i] - meas.data[i]);
      CHECK(std::fabs(g[k]) > 0);
      CHECK(g[k] == doctest::Approx(jr).epsilon(1e-4));
    }
  }

  TEST_CASE("a level at the top of the heights' range: the Jacobian takes the backward difference instead of refusing") {
    // The paper preset's fit walked level 3 to 3072.9 nm of a 3073.8 nm range, and the next
    // Jacobian column's forward step left it: the fit ended on the simulator's refusal.
    const SystemConfig cfg = fit_config();
    const Design d = quantized_lens(cfg);
    AsBuiltModel m(runtime(), cfg, Precision::F64, d, {"levels", "z"});
    std::vector<double> th = m.design_values();
    FitOptions defaults;
    th[2] = 2 * cfg.h_max_m() - 0.5 * defaults.fd_height_m;  // level 3 half a step below the top
    CHECK_THROWS_AS(m.evaluate([&] { auto t = th; t[2] += defaults.fd_height_m; return t; }()), InputError);
    Eigen::MatrixXd j;
    REQUIRE_NOTHROW(j = m.jacobian(th));
    std::vector<double> tb = th;
    tb[2] -= defaults.fd_height_m;
    const RealStack f0 = m.evaluate(th), fb = m.evaluate(tb);
    double worst = 0, scale = 0;
    for (std::size_t i = 0; i < f0.data.size(); ++i) {
      worst = std::max(worst, std::fabs(j(long(i), 2) - (f0.data[i] - fb.data[i]) / defaults.fd_height_m));
      scale = std::max(scale, std::fabs(j(long(i), 2)));
    }
    CHECK(scale > 0);
    CHECK(worst <= 1e-12 * scale);
    std::vector<double> g;
    REQUIRE_NOTHROW(m.loss_gradient(th, f0, g));
    for (double v : g) CHECK(std::isfinite(v));
  }

  TEST_CASE("a level below level 0 is a piston away: the model lifts the map instead of refusing it") {
    // The paper preset's fit from the centroid start walked level 3 below level 0 and the
    // simulator refused the negative heights, ending the fit after 6 minutes.
    const SystemConfig cfg = fit_config();
    const Design d = quantized_lens(cfg);
    AsBuiltModel m(runtime(), cfg, Precision::F64, d, {"levels"});
    std::vector<double> th = m.design_values();
    th[0] = -20e-9;  // level 1 20 nm below level 0
    RealStack got;
    REQUIRE_NOTHROW(got = m.evaluate(th));
    // The same map lifted by 20 nm by hand, and the piston itself: +0.3 um on every height.
    Map2D lifted = m.heights(th);
    for (double& v : lifted.data) v += 20e-9;
    Simulator sim(runtime(), cfg, Precision::F64);
    sim.set_heights(lifted);
    sim.compute_psf();
    const RealStack want = sim.psf_sensor();
    for (double& v : lifted.data) v += 0.3e-6;
    sim.set_heights(lifted);
    sim.compute_psf();
    const RealStack pistoned = sim.psf_sensor();
    double num = 0, num_p = 0, den = 0;
    for (std::size_t i = 0; i < want.data.size(); ++i) {
      num += (got.data[i] - want.data[i]) * (got.data[i] - want.data[i]);
      num_p += (pistoned.data[i] - want.data[i]) * (pistoned.data[i] - want.data[i]);
      den += want.data[i] * want.data[i];
    }
    CHECK(std::sqrt(num / den) < 1e-12);
    CHECK(std::sqrt(num_p / den) < 1e-10);  // float64 phases of ~10 rad: rounding of ~1e-15 rad each
    std::vector<double> g;
    const RealStack meas = m.evaluate(m.design_values());
    m.loss_gradient(th, meas, g);
    for (double v : g) CHECK(std::isfinite(v));
  }
}
