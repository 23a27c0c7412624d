// The fit's test fixtures (suite `fit`: tests/test_fit.cpp, tests/test_fit_model.cpp): the tiny
// system and a 4-level lens on it.
#pragma once
#include <doctest/doctest.h>

#include <cmath>
#include <functional>
#include <string>
#include <vector>

#include "common.hpp"
#include "qdo/asbuilt/fit.hpp"
#include "qdo/data/config.hpp"
#include "qdo/data/io.hpp"
#include "qdo/design/design.hpp"
#include "qdo/physics/doe.hpp"

namespace qdo::test {

// The tiny system of the fit tests: N = 64 (S = 32), 8 bands over 450 .. 550 nm, z = 3.125 mm.
inline SystemConfig fit_config() { return tiny_config(64, 8); }

// A 4-level lens for 500 nm (uniform wrapped levels 0, h/4, h/2, 3h/4: every level used; with the
// inclusive placement the lens for 500 nm would leave level 3 = h_max empty).
inline Design quantized_lens(const SystemConfig& cfg) {
  Quantizer q;
  q.levels = 4;
  q.placement = Placement::Wrapped;
  Design d;
  d.height_m = quantize_heights(lens_design(cfg, 500), cfg.h_max_m(), q);
  d.pitch_m = cfg.pitch_m;
  d.levels_m = q.level_heights_m(cfg.h_max_m());
  return d;
}

// A trained DOE: the 4-level QDO+A design of scripts/experiments_section7.sh (small preset, seed 0,
// 120 steps on the CAVE training scenes), its 128 ring levels (ring k: the pixels with
// k <= r / pitch < k + 1) and level heights as that run wrote them to design.h5. Its rings are one
// or two DOE pixels wide, so its PSF is speckled: the case where the fit's start decides the basin.
inline Design trained_design(const SystemConfig& cfg) {
  const std::string rings =
      "20221201131111122121302221210311222113111132022111012232232111221101222133322231300110221112123102011023131020112302111223110221";
  const std::vector<double> levels_m = {0.0, 498.58571290993757e-9, 1031.2915474099382e-9, 1531.6940693731594e-9};
  std::vector<double> ring_m;
  for (char ch : rings) ring_m.push_back(levels_m[std::size_t(ch - '0')]);
  Design d;
  d.height_m = expand_parameters(Parameterization::Radial, ring_m, cfg.n, cfg.h_max_m());
  d.pitch_m = cfg.pitch_m;
  d.levels_m = levels_m;
  return d;
}

// The fit's gradient (AsBuiltModel::loss_gradient at th) against central differences of its loss,
// parameter by parameter, step_of(name, value) the step: the adjoint in double against differences
// whose error is O(h^2) and the loss's rounding (1e-5 relative plus 1e-9 of the gradient's norm),
// and never exactly 0.
inline void check_fit_gradient(AsBuiltModel& m, const std::vector<double>& th, const RealStack& meas,
                               const std::function<double(const std::string&, double)>& step_of) {
  std::vector<double> g;
  m.loss_gradient(th, meas, g);
  double gnorm = 0;
  for (double v : g) gnorm += v * v;
  gnorm = std::sqrt(gnorm);
  for (std::size_t k = 0; k < th.size(); ++k) {
    const std::string& name = m.parameter_names()[k];
    CAPTURE(name);
    const double h = step_of(name, th[k]);
    std::vector<double> a = th, b = th;
    a[k] += h;
    b[k] -= h;
    const double fd = (m.loss(a, meas) - m.loss(b, meas)) / (2 * h);
    INFO("adjoint " << g[k] << ", central differences " << fd << (m.adjoint_parameter(k) ? " (adjoint)" : " (differences)"));
    CHECK(std::fabs(g[k] - fd) <= 1e-5 * std::fabs(fd) + 1e-9 * gnorm);
    CHECK(g[k] != 0.0);
  }
}

// Each fitted value against the truth t (the fit's layout): z within z_rel x t, the lateral ones
// (dx, dy, oxM, oyM) within lateral_px DOE pixels, heights within height_m.
inline void check_recovered(const FitResult& r, const std::vector<double>& t, double pitch_m, double z_rel, double lateral_px,
                            double height_m) {
  REQUIRE(r.values.size() >= t.size());
  for (std::size_t k = 0; k < t.size(); ++k) {
    const FitValue& v = r.values[k];
    CAPTURE(v.name);
    INFO("fitted " << v.value << ", true " << t[k] << " (design " << v.design << ")");
    if (v.name == "z")
      CHECK(std::fabs(v.value - t[k]) < z_rel * t[k]);
    else if (v.name == "dx" || v.name == "dy" || v.name[0] == 'o')
      CHECK(std::fabs(v.value - t[k]) < lateral_px * pitch_m);
    else
      CHECK(std::fabs(v.value - t[k]) < height_m);
  }
}

}  // namespace qdo::test
