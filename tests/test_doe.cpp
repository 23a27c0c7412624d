#include <algorithm>
#include <cmath>
#include <random>
#include <set>

#include "common.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/physics/simulator.hpp"

using namespace qdo;
using namespace qdo::test;

TEST_SUITE("doe") {
  TEST_CASE("the uniform quantizer yields exactly L levels and is idempotent, in both placements") {
    const double hmax = 1.5369e-6;
    const Map2D h = random_heights(64, hmax, 31);
    for (Placement pl : {Placement::Inclusive, Placement::Wrapped})
      for (int L : {2, 3, 4, 8, 16, 32, 256}) {
        CAPTURE(L);
        CAPTURE(to_string(pl));
        Quantizer q;
        q.levels = L;
        q.placement = pl;
        const Map2D hq = quantize_heights(h, hmax, q);
        std::set<double> distinct(hq.data.begin(), hq.data.end());
        const auto table = q.level_heights_m(hmax);
        CHECK(distinct.size() <= std::size_t(L));
        for (double v : distinct) CHECK(std::find(table.begin(), table.end(), v) != table.end());
        // Idempotent, exactly.
        CHECK(quantize_heights(hq, hmax, q).data == hq.data);
        // Deviation bounded by half a step (plus the wrap for the wrapped placement).
        for (std::size_t i = 0; i < h.data.size(); ++i) {
          const double step = hmax / (pl == Placement::Inclusive ? L - 1 : L);
          double dev = std::fabs(hq.data[i] - h.data[i]);
          if (pl == Placement::Wrapped) dev = std::min(dev, std::fabs(hq.data[i] + hmax - h.data[i]));
          CHECK(dev <= 0.5 * step * (1 + 1e-12));
        }
      }
    // A dense ramp hits every level.
    Map2D ramp(1, 1001);
    for (std::size_t i = 0; i < ramp.data.size(); ++i) ramp.data[i] = hmax * double(i) / 1000.0;
    Quantizer q4;
    q4.levels = 4;
    const Map2D r4 = quantize_heights(ramp, hmax, q4);
    CHECK(std::set<double>(r4.data.begin(), r4.data.end()).size() == 4);
    CHECK(r4.data.front() == 0.0);
    CHECK(r4.data.back() == doctest::Approx(hmax));  // inclusive: h_max is a level
    q4.placement = Placement::Wrapped;
    const Map2D w4 = quantize_heights(ramp, hmax, q4);
    CHECK(std::set<double>(w4.data.begin(), w4.data.end()).size() == 4);
    CHECK(w4.data.back() == 0.0);  // wrapped: h_max is the same phase as 0 at the base wavelength
  }

  TEST_CASE("alpha blending and adaptive offsets follow REFERENCE section 2") {
    const double hmax = 1e-6;
    Quantizer q;
    q.levels = 4;
    q.offsets = {0.0, 0.5, -1.0, 1.0};
    // Level l at (l + 0.5 a_l) / (L - 1).
    CHECK(q.level_value(1) == doctest::Approx((1 + 0.25) / 3));
    CHECK(q.level_value(2) == doctest::Approx((2 - 0.5) / 3));
    CHECK(q.level_value(3) == doctest::Approx((3 + 0.5) / 3));
    Map2D h(1, 1, 0.4e-6);  // u = 0.4 -> index round(1.2) = 1
    const Map2D hq = quantize_heights(h, hmax, q, 0.25);
    CHECK(hq.data[0] == doctest::Approx(0.25 * hmax * 1.25 / 3 + 0.75 * 0.4e-6));
    // Offset limits: [-1, 1], and [-0.2, 0.2] at L = 2; level 0 fixed.
    q.offsets = {0.0, 0.0, 0.0, 1.5};
    CHECK_THROWS_WITH_AS(q.validate(), doctest::Contains("offsets[3]"), InputError);
    Quantizer q2;
    q2.levels = 2;
    q2.offsets = {0.0, 0.3};
    CHECK_THROWS_AS(q2.validate(), InputError);
    q2.offsets = {0.1, 0.0};
    CHECK_THROWS_WITH_AS(q2.validate(), doctest::Contains("offsets[0]"), InputError);
    Quantizer q1;
    q1.levels = 1;
    CHECK_THROWS_WITH_AS(q1.validate(), doctest::Contains("levels"), InputError);
  }

  TEST_CASE("the cubic alpha schedule hits 0 at T0, 7/8 at the midpoint and 1 at T1") {
    CHECK(alpha_schedule(0, 5, 40) == 0.0);
    CHECK(alpha_schedule(5, 5, 40) == 0.0);
    CHECK(alpha_schedule(22.5, 5, 40) == doctest::Approx(1 - 0.125));
    CHECK(alpha_schedule(40, 5, 40) == doctest::Approx(1.0));
    CHECK(alpha_schedule(45, 5, 40) == 1.0);
    double prev = 0;
    for (double s = 5; s <= 40; s += 0.5) {
      const double a = alpha_schedule(s, 5, 40);
      CHECK(a >= prev);
      prev = a;
    }
    CHECK_THROWS_AS(alpha_schedule(1, 5, 5), InputError);
  }

  TEST_CASE("parameterizations expand onto the N x N grid") {
    const std::size_t n = 16;
    std::vector<double> radial(n / 2);
    for (std::size_t k = 0; k < radial.size(); ++k) radial[k] = double(k);
    const Map2D r = expand_parameters(Parameterization::Radial, radial, n, 100.0);
    CHECK(r(n / 2, n / 2) == 0.0);
    CHECK(r(n / 2, n / 2 + 3) == 3.0);
    CHECK(r(n / 2 + 3, n / 2 + 4) == 5.0);  // r = 5 exactly -> ring 5
    CHECK(r(n / 2 + 2, n / 2 + 2) == 2.0);  // r = 2.83 -> ring 2
    CHECK(r(0, 0) == double(n / 2 - 1));     // corners take the last ring
    std::vector<double> quad((n / 2) * (n / 2));
    for (std::size_t i = 0; i < quad.size(); ++i) quad[i] = double(i);
    const Map2D qd = expand_parameters(Parameterization::Quad, quad, n, 1e9);
    CHECK(qd(n / 2 - 2, n / 2 + 3) == qd(n / 2 + 2, n / 2 - 3));
    CHECK(qd(n / 2 + 2, n / 2 + 3) == double(2 * (n / 2) + 3));
    CHECK_THROWS_WITH_AS(expand_parameters(Parameterization::Radial, std::vector<double>(5), n, 1.0),
                         doctest::Contains("params.size()"), InputError);
    // Clamped to [0, h_max].
    const Map2D c = expand_parameters(Parameterization::Full2D, std::vector<double>(n * n, 5.0), n, 1.0);
    CHECK(c(3, 3) == 1.0);
  }

  TEST_CASE("lens design stays within [0, h_max] and is rotationally symmetric") {
    const SystemConfig c = tiny_config(64, 3);
    const Map2D h = lens_design(c, 550);
    for (double v : h.data) {
      CHECK(v >= 0);
      CHECK(v <= c.h_max_m());
    }
    CHECK(h(32, 40) == doctest::Approx(h(40, 32)));
    CHECK(h(32, 24) == doctest::Approx(h(24, 32)));
  }

  TEST_CASE("an explicit level table overrides the level values, not the index") {
    Quantizer q;
    q.levels = 4;
    q.level_table = {0.0, 0.2, 0.45, 0.9};  // e.g. subset sums of etch depths 0.2 and 0.45 (+ both)
    q.validate();
    CHECK(q.level_value(2) == 0.45);
    CHECK(q.quantize(0.7) == 0.45);  // index round(0.7 * 3) = 2
    q.level_table = {0.0, 0.2, NAN, 0.9};
    CHECK_THROWS_WITH_AS(q.validate(), doctest::Contains("level_table[2]"), InputError);
    q.level_table = {0.0, 0.2};
    CHECK_THROWS_WITH_AS(q.validate(), doctest::Contains("level_table.size()"), InputError);
  }

  TEST_CASE("parameter expansion and the alpha-blended quantizer match the CPU reference") {
    for (Precision p : device_precisions(runtime())) {
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
          q.offsets = std::vector<double>{0.0, 0.3, -0.7, 1.0, -1.0};
          if (pl == Placement::Wrapped) q.level_table = std::vector<double>{0.0, 0.15, 0.5, 0.55, 0.95};  // explicit table path
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

}
