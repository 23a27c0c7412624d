// The fit's test fixtures (suite `fit`: tests/test_fit.cpp, tests/test_fit_model.cpp): the tiny
// system and a 4-level lens on it.
#pragma once
#include "common.hpp"
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

}  // namespace qdo::test
