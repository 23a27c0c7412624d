// Helpers shared by the tests from design to fab (doctest suite "fab", tests/test_fab_*.cpp).
#pragma once
#include <cmath>
#include <cstdint>
#include <random>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/data/io.hpp"

namespace qdo::test::fab_suite {

// A quantized design with L levels (uniform, inclusive unless a table is given): rings of random
// width around the axis, overlaid with random 3 x 3 blocks, so masks get holes, islands, diagonal
// contacts and every level.
inline Design level_design(const SystemConfig& cfg, int L, unsigned seed, std::vector<double> table = {}) {
  if (table.empty()) {
    Quantizer q;
    q.levels = L;
    table = q.level_heights_m(cfg.h_max_m());
  }
  std::mt19937_64 rng(seed);
  const std::size_t n = cfg.n;
  std::vector<int> block((n / 3 + 1) * (n / 3 + 1));
  for (auto& b : block) b = int(rng() % 5 == 0 ? rng() % std::uint64_t(L) : 1000);
  Design d;
  d.pitch_m = cfg.pitch_m;
  d.levels_m = table;
  d.height_m = Map2D(n, n);
  for (std::size_t i = 0; i < n; ++i)
    for (std::size_t j = 0; j < n; ++j) {
      const double r = std::hypot(double(i) - double(n / 2), double(j) - double(n / 2));
      int l = int(r / 2.5) % L;
      const int b = block[(i / 3) * (n / 3 + 1) + j / 3];
      if (b < 1000) l = b;
      d.height_m(i, j) = table[std::size_t(l)];
    }
  for (int l = 0; l < L && std::size_t(l) < n; ++l) d.height_m(0, std::size_t(l)) = table[std::size_t(l)];  // every level used
  return d;
}

}  // namespace qdo::test::fab_suite
