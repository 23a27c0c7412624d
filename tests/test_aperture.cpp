// The area-weighted aperture and the moved optical axis (config.hpp aperture_edge "area",
// aperture_offset_m; optics.hpp aperture_transmission, sensor_weights; kernels/field.cl use_amp,
// kernels/psf.cl col_offset): the circle-cell areas against closed forms and a fine quadrature, the
// configuration's keys and refusals, the kernels against the CPU reference (field, sensor PSF and
// both adjoints, with the host propagation and without), the reference chain through the adjoint
// ladder, and the physics: a relief moved by a whole DOE pixel against a fixed aperture gives the
// same sensor PSF as the axis moved the other way, which is what lets qdo fit and qdo fabricate
// move a relief against its aperture with every pixel on its level.
#include <cmath>
#include <random>
#include <string>

#include "adjoint_table.hpp"
#include "common.hpp"
#include "stage_probes.hpp"
#include "qdo/physics/adjoint.hpp"
#include "qdo/physics/cpu_reference.hpp"
#include "qdo/physics/radial.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/runtime/error.hpp"

using namespace qdo;
using namespace qdo::test;

namespace {

constexpr double kPi = 3.14159265358979323846;

// A small configuration with the area-weighted aperture, its axis at (ax, ay) DOE pixels, the
// sensor pitch 2.5 DOE pixels (fractional area weights), a finite scene distance.
SystemConfig area_config(double ax_px, double ay_px, std::size_t n = 32, std::size_t bands = 3) {
  SystemConfig c = tiny_config(n, bands);
  c.sensor_pitch_m = 2.5 * c.pitch_m;
  c.aperture_edge = ApertureEdge::Area;
  c.aperture_radius_m = (double(n) / 2.0 - 2.0) * c.pitch_m;
  c.aperture_offset_x_m = ax_px * c.pitch_m;
  c.aperture_offset_y_m = ay_px * c.pitch_m;
  c.scene_distance_m = 0.5;
  c.validate();
  return c;
}

// The area of [x0, x1] x [y0, y1] inside the circle of radius r by a midpoint rule of k columns in x
// with the exact chord in y: an independent quadrature (error O(1/k²) away from the circle's sides).
double area_by_columns(double r, double x0, double x1, double y0, double y1, int k) {
  double a = 0;
  const double dx = (x1 - x0) / k;
  for (int i = 0; i < k; ++i) {
    const double x = x0 + (i + 0.5) * dx;
    if (std::fabs(x) >= r) continue;
    const double c = std::sqrt(r * r - x * x);
    a += std::max(0.0, std::min(y1, c) - std::max(y0, -c)) * dx;
  }
  return a;
}

// The samples (y + dy, x + dx) for y, x in [margin, rows - margin) of every plane, each plane divided by
// the sum of those samples.
std::vector<double> interior(const RealStack& s, std::size_t margin, long dy, long dx) {
  std::vector<double> out;
  for (std::size_t q = 0; q < s.planes; ++q) {
    const std::size_t first = out.size();
    double sum = 0;
    for (std::size_t y = margin; y + margin < s.rows; ++y)
      for (std::size_t x = margin; x + margin < s.cols; ++x) {
        const double v = s(q, std::size_t(long(y) + dy), std::size_t(long(x) + dx));
        out.push_back(v);
        sum += v;
      }
    for (std::size_t i = first; i < out.size(); ++i) out[i] /= sum;
  }
  return out;
}

Map2D as_map(const std::vector<double>& x, std::size_t n) {
  Map2D m(n, n);
  m.data = x;
  return m;
}

}  // namespace

QDO_ADJOINT_ROWS(moved_aperture, "area-weighted aperture, moved axis") {
  std::vector<Stage> rows;
  // Heights -> sensor PSF through the CPU reference chain with the axis at (0.3, -0.45) DOE pixels:
  // the aperture's weights, the moved point source and both axes' own area weights.
  const SystemConfig c = area_config(0.3, -0.45);
  const std::size_t s = c.sensor_size_px();
  Stage st("heights -> sensor PSF, area aperture, axis at (0.3, -0.45) px (reference)", c.n * c.n, c.bands * s * s);
  st.forward = [c](const std::vector<double>& x) { return ref::psf_sensor_stack(c, as_map(x, c.n)).data; };
  st.vjp = [c, s](const std::vector<double>& x, const std::vector<double>& g) {
    RealStack gs(c.bands, s, s);
    gs.data = g;
    return ref::psf_sensor_vjp(c, as_map(x, c.n), gs).data;
  };
  st.jvp = [c](const std::vector<double>& x, const std::vector<double>& d) {
    return ref::psf_sensor_jvp(c, as_map(x, c.n), as_map(d, c.n)).data;
  };
  st.x0 = smooth_heights(c, 5).data;
  std::mt19937_64 rng(6);
  std::normal_distribution<double> nd(0, 1e-8);
  st.d0.resize(c.n * c.n);
  for (double& v : st.d0) v = nd(rng);
  st.g0 = uniform_stack(c.bands, s, s, 7).data;
  st.dot_tol = 0;
  st.dot_rel = 1e-9;
  // Rung 2 along x +- 1e-4 d (d of size 1e-8 m: phase steps ~1e-5 rad), within 1e-6; rung 3 at
  // twelve samples of the aperture (weights > 0), +- 1e-11 m.
  st.fd_tol = 0;
  st.dir_step = 1e-4;
  st.dir_rel = 1e-6;
  const std::vector<double> amp = aperture_transmission(c);
  for (std::size_t i = 0; st.probes.size() < 12 && i < amp.size(); i += 37)
    if (amp[i] > 0) st.probes.push_back(i);
  st.probe_step = 1e-11;
  st.probe_rel = 1e-5;
  st.probe_rms = 1e-6;
  rows.push_back(st);
  return rows;
}

TEST_SUITE("aperture") {
  TEST_CASE("circle_rectangle_area: closed forms, symmetry and a fine quadrature") {
    const double r = 3.7;
    CHECK(circle_rectangle_area(r, -r, r, -r, r) == doctest::Approx(kPi * r * r).epsilon(1e-14));
    CHECK(circle_rectangle_area(r, 0, r, 0, r) == doctest::Approx(kPi * r * r / 4).epsilon(1e-14));
    CHECK(circle_rectangle_area(r, -10, 10, 0, 10) == doctest::Approx(kPi * r * r / 2).epsilon(1e-14));
    CHECK(circle_rectangle_area(r, -0.5, 0.5, -0.5, 0.5) == 1.0);  // a cell well inside
    CHECK(circle_rectangle_area(r, 5, 6, 0, 1) == 0.0);            // one outside
    CHECK(circle_rectangle_area(r, 1, 0, 0, 1) == 0.0);            // empty
    // A circular segment: the part of the disc above y = h is r² acos(h / r) - h sqrt(r² - h²).
    const double h = 1.3;
    CHECK(circle_rectangle_area(r, -r, r, h, r) == doctest::Approx(r * r * std::acos(h / r) - h * std::sqrt(r * r - h * h)).epsilon(1e-13));
    // Cells cut by the circle in every way, against 20000 columns of exact chords (midpoint error
    // ~1e-8 of a cell away from the circle's sides, ~1e-6 where a side of the circle crosses).
    std::mt19937_64 rng(3);
    std::uniform_real_distribution<double> u(-r - 0.5, r - 0.5);
    int cut = 0;
    for (int k = 0; k < 200; ++k) {
      const double x0 = u(rng), y0 = u(rng);
      const double got = circle_rectangle_area(r, x0, x0 + 1, y0, y0 + 1);
      const double want = area_by_columns(r, x0, x0 + 1, y0, y0 + 1, 20000);
      CAPTURE(x0);
      CAPTURE(y0);
      CHECK(std::fabs(got - want) <= 2e-6);
      CHECK(std::fabs(got - circle_rectangle_area(r, -x0 - 1, -x0, y0, y0 + 1)) <= 1e-13);  // mirror x
      CHECK(std::fabs(got - circle_rectangle_area(r, y0, y0 + 1, x0, x0 + 1)) <= 1e-13);    // swap axes
      cut += got > 0 && got < 1;
    }
    CHECK(cut > 50);
  }

  TEST_CASE("aperture_transmission: the area of the circle wherever its centre sits; whole samples without area") {
    for (const auto& [ax, ay] : {std::pair<double, double>{0, 0}, {0.37, -0.21}, {-1.4, 0.5}, {0.5, 0.5}}) {
      CAPTURE(ax);
      CAPTURE(ay);
      const SystemConfig c = area_config(ax, ay);
      const std::vector<double> t = aperture_transmission(c);
      const double r_px = c.aperture_radius() / c.pitch_m;
      double sum = 0;
      for (double v : t) {
        CHECK(v >= 0);
        CHECK(v <= 1);
        sum += v;
      }
      CHECK(sum == doctest::Approx(kPi * r_px * r_px).epsilon(1e-12));
      // The circle's centre where the configuration says (sample (N/2, N/2) at the origin, x along
      // columns): the axis mirrored in x gives the map mirrored (column j -> N - j), and every cell
      // cut by the edge holds its area by an independent quadrature.
      const std::vector<double> tm = aperture_transmission(area_config(-ax, ay));
      for (std::size_t i = 0; i < c.n; ++i)
        for (std::size_t j = 1; j < c.n; ++j) {
          CHECK(std::fabs(t[i * c.n + j] - tm[i * c.n + (c.n - j)]) <= 1e-13);
          const double v = t[i * c.n + j];
          if (v > 0 && v < 1) {
            const double x = double(j) - double(c.n / 2) - ax, y = double(i) - double(c.n / 2) - ay;
            CHECK(std::fabs(v - area_by_columns(r_px, x - 0.5, x + 0.5, y - 0.5, y + 0.5, 4000)) <= 1e-5);
          }
        }
    }
    // Inclusive and strict: exactly the integer radius test.
    SystemConfig c = tiny_config(32, 3);
    const std::vector<double> t = aperture_transmission(c);
    const double r2 = c.aperture_inside_px2();
    for (std::size_t i = 0; i < c.n; ++i)
      for (std::size_t j = 0; j < c.n; ++j) {
        const double di = double(i) - 16, dj = double(j) - 16;
        CHECK(t[i * c.n + j] == (di * di + dj * dj <= r2 ? 1.0 : 0.0));
      }
  }

  TEST_CASE("configuration: area and the axis offset read and written; offsets refused with whole samples or outside the grid") {
    SystemConfig c = area_config(0.25, -0.5);
    const std::string text = config_to_json_text(c);
    CHECK(text.find("\"aperture_edge\": \"area\"") != std::string::npos);
    CHECK(text.find("\"aperture_offset_m\"") != std::string::npos);
    const SystemConfig back = config_from_json_text(text);
    CHECK(back.aperture_edge == ApertureEdge::Area);
    CHECK(back.aperture_offset_x_m == c.aperture_offset_x_m);
    CHECK(back.aperture_offset_y_m == c.aperture_offset_y_m);
    // A centred axis writes no key (configurations from before write the same JSON).
    c.aperture_offset_x_m = c.aperture_offset_y_m = 0;
    CHECK(config_to_json_text(c).find("aperture_offset_m") == std::string::npos);
    // An offset with whole samples is refused, naming both keys.
    SystemConfig w = tiny_config(32, 3);
    w.aperture_offset_x_m = 1e-6;
    CHECK_THROWS_WITH_AS(w.validate(), doctest::Contains("aperture_offset_m"), InputError);
    CHECK_THROWS_WITH_AS(w.validate(), doctest::Contains("\"area\""), InputError);
    // An offset that takes the circle past the grid's cells is refused, naming the axis.
    SystemConfig o = area_config(0, 0);
    o.aperture_offset_y_m = 2.6 * o.pitch_m;  // radius N/2 - 2: up to 1.5 px upward
    CHECK_THROWS_WITH_AS(o.validate(), doctest::Contains("aperture_offset_m[1]"), InputError);
    CHECK_THROWS_WITH_AS(config_from_json_text("{\"aperture_edge\": \"soft\"}"), doctest::Contains("\"area\""), InputError);
    CHECK_THROWS_WITH_AS(config_from_json_text("{\"aperture_offset_m\": 1e-6}"), doctest::Contains("aperture_offset_m"), InputError);
    // The radial path's rings are whole samples about the centre: it refuses.
    CHECK_THROWS_WITH_AS(radial_config(area_config(0.25, 0)), doctest::Contains("2-D path"), InputError);
  }

  TEST_CASE("kernels match the CPU reference: field, sensor PSF, both adjoints; host propagation on and off") {
    for (Precision p : device_precisions(runtime())) {
      for (bool fusion : {true, false}) {
        CAPTURE(to_string(p));
        CAPTURE(fusion);
        const SystemConfig c = area_config(0.3, -0.45, 48, 4);
        const Map2D h = smooth_heights(c, 11);
        Simulator sim(runtime(), c, p);
        sim.set_host_fusion(fusion);
        sim.set_heights(h);
        sim.compute_psf();
        {  // The field: per sample, the phase error of test_field's bound times a weight <= 1.
          const ComplexStack got = field_after_doe(sim);
          const ComplexStack want = ref::doe_field(c, h, sim.geometry());
          double max_phase = 0;
          for (const double k : wavenumber_per_band(c)) max_phase = std::max(max_phase, k * (c.aperture_radius() * c.aperture_radius() / c.scene_distance_m + 2 * c.h_max_m()));
          CHECK(diff(got.data, want.data).max_abs <= 4 * eps(p) * (max_phase + 1) + 2 * eps(p));
        }
        const RealStack want_s = ref::psf_sensor_stack(c, h);
        const auto ds = diff(sim.psf_sensor().data, want_s.data);
        CAPTURE(ds.rel_l2);
        CHECK(ds.rel_l2 <= 2e3 * eps(p));  // as the PSF suite: bands x M² terms per value
        const RealStack gs = uniform_stack(c.bands, sim.sensor_size(), sim.sensor_size(), 12);
        const auto dv = diff(sim.psf_sensor_vjp(gs).data, ref::psf_sensor_vjp(c, h, gs).data);
        CAPTURE(dv.rel_l2);
        CHECK(dv.rel_l2 <= 2e3 * eps(p));
        const RealStack gn = uniform_stack(c.bands, c.n, c.n, 13);
        const auto dn = diff(sim.psf_native_vjp(gn).data, ref::psf_native_vjp(c, h, gn).data);
        CAPTURE(dn.rel_l2);
        CHECK(dn.rel_l2 <= 2e3 * eps(p));
      }
    }
  }

  TEST_CASE("Simulator::set_optical_axis equals a new simulator at that axis (stack and adjoint); a refused axis changes nothing") {
    const SystemConfig a = area_config(0.2, -0.1, 48, 3), b = area_config(-0.45, 0.3, 48, 3);
    const Map2D h = smooth_heights(a, 31);
    for (Precision p : device_precisions(runtime())) {
      CAPTURE(to_string(p));
      Simulator moved(runtime(), a, p), fresh(runtime(), b, p);
      moved.set_heights(h);
      moved.compute_psf();
      moved.set_optical_axis(b.aperture_offset_x_m, b.aperture_offset_y_m);
      CHECK_FALSE(moved.psf_ready());
      CHECK(moved.config().aperture_offset_x_m == b.aperture_offset_x_m);
      moved.compute_psf();
      fresh.set_heights(h);
      fresh.compute_psf();
      CHECK(moved.psf_sensor().data == fresh.psf_sensor().data);  // the same tables, the same arithmetic
      const RealStack g = uniform_stack(b.bands, fresh.sensor_size(), fresh.sensor_size(), 5);
      CHECK(moved.psf_sensor_vjp(g).data == fresh.psf_sensor_vjp(g).data);
      // An axis the configuration refuses (beyond the grid) is refused before any change.
      CHECK_THROWS_WITH_AS(moved.set_optical_axis(30 * b.pitch_m, 0), doctest::Contains("aperture_offset_m[0]"), InputError);
      CHECK(moved.config().aperture_offset_x_m == b.aperture_offset_x_m);
      CHECK(moved.psf_ready());
    }
    Simulator whole(runtime(), tiny_config(32, 3), Precision::F32);
    CHECK_THROWS_WITH_AS(whole.set_optical_axis(1e-6, 0), doctest::Contains("\"area\""), InputError);
  }

  TEST_CASE("a relief moved by one DOE pixel against its aperture = the axis moved by one pixel the other way") {
    // Camera A: the aperture centred, the relief moved by +1 column and -1 row (the rolled map,
    // zero relief brought in, outside the aperture). Camera B: the relief where it was, the optical
    // axis (aperture, point source, sensor window) at (-1, +1) pixel. They are one camera seen from
    // two origins: their sensor PSFs agree to the precision (the propagation is shift-covariant in
    // its padded window; the PSF stays inside the sensor window).
    const Precision p = runtime().has_fp64() ? Precision::F64 : Precision::F32;
    SystemConfig a = area_config(0, 0, 48, 3);
    SystemConfig b = area_config(-1, 1, 48, 3);
    a.sensor_pitch_m = b.sensor_pitch_m = 2 * a.pitch_m;  // the axis's move is half a sensor pixel
    // A diffractive lens that focuses the source onto the sensor at 500 nm (1/f = 1/z + 1/d), with a
    // ripple that breaks its symmetry: a compact PSF, far from the window's edges.
    const Map2D ripple = smooth_heights(a, 21);
    Map2D h(a.n, a.n);
    {
      const double lambda = 500e-9, f = 1.0 / (1.0 / a.sensor_distance_m + 1.0 / a.scene_distance_m);
      const double hmax = a.h_max_m();
      for (std::size_t i = 0; i < a.n; ++i)
        for (std::size_t j = 0; j < a.n; ++j) {
          const double x = (double(j) - double(a.n / 2) + 1) * a.pitch_m, y = (double(i) - double(a.n / 2) - 1) * a.pitch_m;
          const double waves = -(x * x + y * y) / (2 * f * lambda);  // the lens's phase in waves
          h(i, j) = hmax * (waves - std::floor(waves)) * 0.9 + 0.1 * ripple(i, j);
        }
    }
    Map2D moved(a.n, a.n);
    for (std::size_t i = 0; i + 1 < a.n; ++i)
      for (std::size_t j = 1; j < a.n; ++j) moved(i, j) = h(i + 1, j - 1);
    Simulator sa(runtime(), a, p), sb(runtime(), b, p);
    sa.set_heights(moved);
    sb.set_heights(h);
    sa.compute_psf();
    sb.compute_psf();
    // The two windows share every sample but one row and one column at their edges (A's native
    // sample (i, j) is B's (i + 1, j - 1); the sensor windows are the same pixels), and the
    // propagation is a circular convolution in the padded window: on the shared interior, each
    // plane renormalised there, the stacks agree to the rounding (float64: 1e-10 relative).
    const double tol = p == Precision::F64 ? 1e-10 : 1e-4;
    const RealStack na = sa.psf_native(), nb = sb.psf_native();
    const auto dn = diff(interior(na, 2, 0, 0), interior(nb, 2, 1, -1));
    CAPTURE(dn.rel_l2);
    CHECK(dn.rel_l2 <= tol);
    CHECK(diff(interior(na, 2, 0, 0), interior(nb, 2, -1, 1)).rel_l2 > 0.1);  // the other way round: not a match
    const RealStack psa = sa.psf_sensor(), psb = sb.psf_sensor();
    const auto ds = diff(interior(psa, 1, 0, 0), interior(psb, 1, 0, 0));
    CAPTURE(ds.rel_l2);
    CHECK(ds.rel_l2 <= tol);
    // The whole sensor stacks differ by the light in the edge rows (about 2 % of it here).
    CHECK(diff(psa.data, psb.data).rel_l2 <= 0.05);
    // Control: the same two without moving the axis differ by far more (the test can fail).
    SystemConfig b0 = b;
    b0.aperture_offset_x_m = b0.aperture_offset_y_m = 0;
    Simulator s0(runtime(), b0, p);
    s0.set_heights(h);
    s0.compute_psf();
    CHECK(diff(interior(psa, 1, 0, 0), interior(s0.psf_sensor(), 1, 0, 0)).rel_l2 > 1e-2);
    // And the reference says the same of B.
    CHECK(diff(sb.psf_sensor().data, ref::psf_sensor_stack(b, h).data).rel_l2 <= 2e3 * eps(p));
  }
}
