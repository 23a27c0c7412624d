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

}  // namespace qdo::test
