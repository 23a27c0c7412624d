// The adjoint ladder as one test body (Devito's and Meep's habit): every forward/adjoint pair of
// qdo is described by a Stage, and check_ladder() runs the same three rungs over each:
//   1. dot product       <J d, g> = <d, J^T g> for random d, g (linear stages: J = the map);
//   2. directional FD    (f(x + e d) - f(x - e d)) / 2e . g against <vjp(x, g), d>;
//   3. central FD        on a few sampled parameters i: (f(x + e e_i) - f(x - e e_i)) / 2e . g
//                        against vjp(x, g)[i].
// Tolerances are relative and given per stage (derived from its precision and size); every
// comparison is reported with both numbers. Rung 1 needs a jvp (linear stages: the forward map
// itself); without one the stage runs rungs 2 and 3 only.
#pragma once
#include <doctest/doctest.h>

#include <cmath>
#include <cstdint>
#include <functional>
#include <random>
#include <string>
#include <utility>
#include <vector>

namespace qdo::test {

struct Stage {
  Stage(std::string stage_name, std::size_t n_in, std::size_t n_out)
      : name(std::move(stage_name)), inputs(n_in), outputs(n_out) {}
  std::string name;
  std::size_t inputs = 0, outputs = 0;
  std::function<std::vector<double>(const std::vector<double>& x)> forward;
  std::function<std::vector<double>(const std::vector<double>& x, const std::vector<double>& g)> vjp;
  // Optional: J d at x (linear stages: forward(d)).
  std::function<std::vector<double>(const std::vector<double>& x, const std::vector<double>& d)> jvp;
  std::vector<double> x0;   // the point (inputs values); empty: random in [lo, hi]
  double lo = -1, hi = 1;   // range of random points and directions
  double dot_tol = 1e-12;   // rung 1, relative to |<J d, g>| + |d||J^T g|
  double fd_step = 1e-6;    // rungs 2 and 3, absolute step along a unit-scale direction
  double fd_tol = 1e-7;     // rungs 2 and 3, relative to the gradient's RMS times sqrt(inputs)
  std::size_t samples = 4;  // rung 3: parameters probed
};

namespace ladder_detail {
inline double dot(const std::vector<double>& a, const std::vector<double>& b) {
  REQUIRE(a.size() == b.size());
  double s = 0;
  for (std::size_t i = 0; i < a.size(); ++i) s += a[i] * b[i];
  return s;
}
inline std::vector<double> random_vec(std::size_t n, std::uint64_t seed, double lo, double hi) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(lo, hi);
  std::vector<double> v(n);
  for (auto& e : v) e = u(rng);
  return v;
}
inline std::vector<double> axpy(const std::vector<double>& x, double a, const std::vector<double>& d) {
  std::vector<double> y(x);
  for (std::size_t i = 0; i < y.size(); ++i) y[i] += a * d[i];
  return y;
}
}  // namespace ladder_detail

// Runs the three rungs on `st` (seeded: reproducible). Each rung is a doctest SUBCASE-free block
// of CHECKs captured with the stage name, so a failure names the stage and the rung.
inline void check_ladder(const Stage& st, std::uint64_t seed) {
  using namespace ladder_detail;
  INFO("stage: " << st.name);
  const std::vector<double> x = st.x0.empty() ? random_vec(st.inputs, seed, st.lo, st.hi) : st.x0;
  REQUIRE(x.size() == st.inputs);
  const std::vector<double> g = random_vec(st.outputs, seed + 1, -1, 1);
  const std::vector<double> d = random_vec(st.inputs, seed + 2, -1, 1);
  const std::vector<double> grad = st.vjp(x, g);
  REQUIRE(grad.size() == st.inputs);
  const double gnorm = std::sqrt(dot(grad, grad));
  // Rung 1: dot product.
  if (st.jvp) {
    const std::vector<double> jd = st.jvp(x, d);
    REQUIRE(jd.size() == st.outputs);
    const double lhs = dot(jd, g), rhs = dot(d, grad);
    const double scale = std::fabs(lhs) + std::sqrt(dot(d, d)) * gnorm;
    INFO("rung 1 (dot product): <J d, g> = " << lhs << ", <d, J^T g> = " << rhs);
    CHECK(std::fabs(lhs - rhs) <= st.dot_tol * scale);
  }
  const double e = st.fd_step;
  auto slope = [&](const std::vector<double>& dir) {
    const std::vector<double> fp = st.forward(axpy(x, e, dir)), fm = st.forward(axpy(x, -e, dir));
    REQUIRE(fp.size() == st.outputs);
    double s = 0;
    for (std::size_t i = 0; i < fp.size(); ++i) s += (fp[i] - fm[i]) * g[i];
    return s / (2 * e);
  };
  // Rung 2: one directional difference of the whole map.
  {
    const double fd = slope(d), an = dot(d, grad);
    INFO("rung 2 (directional FD): FD = " << fd << ", adjoint = " << an);
    CHECK(std::fabs(fd - an) <= st.fd_tol * std::sqrt(dot(d, d)) * gnorm);
  }
  // Rung 3: central differences on sampled parameters.
  std::mt19937_64 rng(seed + 3);
  for (std::size_t k = 0; k < st.samples && st.inputs > 0; ++k) {
    const std::size_t i = std::size_t(rng() % st.inputs);
    std::vector<double> ei(st.inputs, 0.0);
    ei[i] = 1;
    const double fd = slope(ei);
    INFO("rung 3 (central FD) at parameter " << i << ": FD = " << fd << ", adjoint = " << grad[i]);
    CHECK(std::fabs(fd - grad[i]) <= st.fd_tol * gnorm);
  }
}

}  // namespace qdo::test
