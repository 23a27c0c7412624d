// The adjoint ladder as one test body (Devito's and Meep's habit): every forward/adjoint pair of
// qdo is described by a Stage, and check_ladder() runs the same three rungs over each:
//   1. dot product       <J d, g> = <d, J^T g> for random d, g (linear stages: J = the map);
//   2. directional FD    (f(x + e d) - f(x - e d)) / 2e . g against <vjp(x, g), d>;
//   3. central FD        on a few parameters i: (f(x + e e_i) - f(x - e e_i)) / 2e . g
//                        against vjp(x, g)[i].
// The table of the rows (the PSF chain, the parameterizations, the quantizer, the radial engine,
// the encoders, the design loop, the Wiener decoder, joint training) is tests/adjoint_table.hpp,
// run by the suite `adjoint`; the camera operator's and the device Wiener objective's rows run in
// test_camera.cpp and test_wiener_device.cpp through this same body.
//
// Tolerances are given per stage (derived from its precision and size) as a sum of terms, each
// off at 0; every comparison is reported with both numbers. Rung 1 needs a jvp (linear stages:
// the forward map itself); without one the stage runs rungs 2 and 3 only. The point x, the output
// weights g and the direction d are seeded random vectors unless the stage fixes them (x0, g0, d0).
#pragma once
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <functional>
#include <random>
#include <string>
#include <utility>
#include <vector>

namespace qdo::test {

// The real inner product sum_i a_i b_i (a complex vector stored as interleaved (re, im) pairs
// gives Re <a, b>).
inline double dot(const std::vector<double>& a, const std::vector<double>& b) {
  REQUIRE(a.size() == b.size());
  double s = 0;
  for (std::size_t i = 0; i < a.size(); ++i) s += a[i] * b[i];
  return s;
}

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
  std::vector<double> g0;   // the output weights (outputs values); empty: random in [-1, 1]
  std::vector<double> d0;   // the direction (inputs values); empty: random in [-1, 1]
  double lo = -1, hi = 1;   // range of random points
  // Rung 1: |<J d, g> - <d, J^T g>| <= dot_tol (|<J d, g>| + |d| |J^T g|)
  //                                   + dot_rel min(|<J d, g>|, |<d, J^T g>|) + dot_norms |d| |g| + dot_abs.
  double dot_tol = 1e-12, dot_rel = 0, dot_norms = 0, dot_abs = 0;
  // Steps: rung 2 takes x +- dir_step d, rung 3 x +- probe_step e_i (0: fd_step, a step along a
  // unit-scale direction). With richardson, each difference D(e) becomes (4 D(e) - D(2e)) / 3.
  double fd_step = 1e-6, dir_step = 0, probe_step = 0;
  bool richardson = false;
  // Rung 2: |FD - <d, grad>| <= fd_tol |d| |grad| + dir_rel min(|FD|, |<d, grad>|) + dir_abs.
  // Rung 3: |FD_i - grad_i| <= fd_tol |grad| + probe_rel min(|FD_i|, |grad_i|) + probe_rms |grad| / sqrt(inputs)
  //                           + probe_abs.
  double fd_tol = 1e-7, dir_rel = 0, dir_abs = 0, probe_rel = 0, probe_rms = 0, probe_abs = 0;
  std::vector<std::size_t> probes;  // rung 3's parameters; empty: `samples` random ones
  std::size_t samples = 4;
};

namespace ladder_detail {
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
  const std::vector<double> g = st.g0.empty() ? random_vec(st.outputs, seed + 1, -1, 1) : st.g0;
  const std::vector<double> d = st.d0.empty() ? random_vec(st.inputs, seed + 2, -1, 1) : st.d0;
  REQUIRE(g.size() == st.outputs);
  REQUIRE(d.size() == st.inputs);
  const std::vector<double> grad = st.vjp(x, g);
  REQUIRE(grad.size() == st.inputs);
  const double gnorm = std::sqrt(dot(grad, grad)), dnorm = std::sqrt(dot(d, d));
  // Rung 1: dot product.
  if (st.jvp) {
    const std::vector<double> jd = st.jvp(x, d);
    REQUIRE(jd.size() == st.outputs);
    const double lhs = dot(jd, g), rhs = dot(d, grad);
    const double tol = st.dot_tol * (std::fabs(lhs) + dnorm * gnorm) + st.dot_rel * std::min(std::fabs(lhs), std::fabs(rhs)) +
                       st.dot_norms * dnorm * std::sqrt(dot(g, g)) + st.dot_abs;
    INFO("rung 1 (dot product): <J d, g> = " << lhs << ", <d, J^T g> = " << rhs);
    CHECK(std::fabs(lhs - rhs) <= tol);
  }
  auto central = [&](const std::vector<double>& dir, double e) {
    const std::vector<double> fp = st.forward(axpy(x, e, dir)), fm = st.forward(axpy(x, -e, dir));
    REQUIRE(fp.size() == st.outputs);
    REQUIRE(fm.size() == st.outputs);
    double s = 0;
    for (std::size_t i = 0; i < fp.size(); ++i) s += (fp[i] - fm[i]) * g[i];
    return s / (2 * e);
  };
  auto slope = [&](const std::vector<double>& dir, double e) {
    return st.richardson ? (4 * central(dir, e) - central(dir, 2 * e)) / 3 : central(dir, e);
  };
  // Rung 2: one directional difference of the whole map.
  {
    const double fd = slope(d, st.dir_step > 0 ? st.dir_step : st.fd_step), an = dot(d, grad);
    const double tol = st.fd_tol * dnorm * gnorm + st.dir_rel * std::min(std::fabs(fd), std::fabs(an)) + st.dir_abs;
    INFO("rung 2 (directional FD): FD = " << fd << ", adjoint = " << an);
    CHECK(std::fabs(fd - an) <= tol);
  }
  // Rung 3: central differences on the probed (or sampled) parameters.
  std::vector<std::size_t> probes = st.probes;
  if (probes.empty()) {
    std::mt19937_64 rng(seed + 3);
    for (std::size_t k = 0; k < st.samples && st.inputs > 0; ++k) probes.push_back(std::size_t(rng() % st.inputs));
  }
  const double rms = st.inputs > 0 ? gnorm / std::sqrt(double(st.inputs)) : 0.0;
  for (std::size_t i : probes) {
    REQUIRE(i < st.inputs);
    std::vector<double> ei(st.inputs, 0.0);
    ei[i] = 1;
    const double fd = slope(ei, st.probe_step > 0 ? st.probe_step : st.fd_step);
    const double tol = st.fd_tol * gnorm + st.probe_rel * std::min(std::fabs(fd), std::fabs(grad[i])) + st.probe_rms * rms +
                       st.probe_abs;
    INFO("rung 3 (central FD) at parameter " << i << ": FD = " << fd << ", adjoint = " << grad[i]);
    CHECK(std::fabs(fd - grad[i]) <= tol);
  }
}

}  // namespace qdo::test
