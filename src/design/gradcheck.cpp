// `qdo gradcheck`: every adjoint of a design run against central finite differences (gradcheck.hpp).
#include "qdo/design/gradcheck.hpp"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <random>

#include "design/problem.hpp"
#include "qdo/physics/adjoint.hpp"
#include "qdo/physics/cpu_reference.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/physics/simulator.hpp"

namespace qdo {

std::vector<GradcheckRow> gradcheck(Runtime& rt, const DesignRunOptions& given, std::uint64_t seed) {
  DesignRunOptions o = given;
  SystemConfig& c = o.cfg;
  if (c.n > 64) {  // same physics at a smaller N: z scales with N (constant NA and sampling ratio)
    const double f = 64.0 / double(c.n);
    c.sensor_distance_m *= f;
    c.padding_px = std::size_t(double(c.padding_px) * f);
    c.n = 64;
  }
  c.bands = std::min<std::size_t>(c.bands, 4);
  c.srf_interpolate = true;
  o.synthetic_scenes = 4;
  o.design.seed = seed;
  o.design.steps_per_epoch = 2;
  o.design.t0_epochs = 1;
  o.design.t1_epochs = 5;
  c.validate();
  const Precision p = rt.has_fp64() ? Precision::F64 : Precision::F32;
  o.precision = p;
  std::vector<GradcheckRow> rows;
  std::mt19937_64 rng(seed);
  // Error relative to the analytic value, floored at 1 % of the gradient's RMS so entries that
  // are nearly zero do not turn round-off into large relative errors.
  auto rms = [](const std::vector<double>& v) {
    double s2 = 0;
    for (double x : v) s2 += x * x;
    return std::sqrt(s2 / double(std::max<std::size_t>(v.size(), 1)));
  };
  auto rel = [](double fd, double an, double scale) { return std::fabs(fd - an) / std::max({std::fabs(an), 1e-2 * scale, 1e-300}); };

  // 1. The PSF chain: OpenCL adjoint vs CPU reference adjoint, on random heights.
  Simulator sim(rt, c, p);
  Map2D h(c.n, c.n);
  std::uniform_real_distribution<double> uh(0.2 * c.h_max_m(), 0.8 * c.h_max_m());
  for (double& v : h.data) v = uh(rng);
  sim.set_heights(h);
  sim.compute_psf();
  RealStack g(c.bands, sim.sensor_size(), sim.sensor_size());
  std::normal_distribution<double> nd;
  for (double& v : g.data) v = nd(rng);
  const Map2D gk = sim.psf_sensor_vjp(g), gr = ref::psf_sensor_vjp(c, h, g);
  double num = 0, den = 0;
  for (std::size_t i = 0; i < gk.data.size(); ++i) {
    num += (gk.data[i] - gr.data[i]) * (gk.data[i] - gr.data[i]);
    den += gr.data[i] * gr.data[i];
  }
  rows.push_back({"PSF chain: OpenCL " + to_string(p) + " adjoint vs CPU adjoint (rel. L2)", std::sqrt(num / den),
                  p == Precision::F64 ? 1e-9 : 3e-4});
  // 2. CPU adjoint vs central differences on sampled heights.
  auto loss_h = [&](const Map2D& hh) {
    const RealStack s = ref::psf_sensor_stack(c, hh);
    double l = 0;
    for (std::size_t i = 0; i < s.size(); ++i) l += s.data[i] * g.data[i];
    return l;
  };
  double worst = 0;
  for (int k = 0; k < 6; ++k) {
    const std::size_t i = c.n / 2 - 8 + rng() % 16, j = c.n / 2 - 8 + rng() % 16;
    Map2D a = h, b = h;
    a(i, j) += 1e-11;
    b(i, j) -= 1e-11;
    worst = std::max(worst, rel((loss_h(a) - loss_h(b)) / 2e-11, gr(i, j), rms(gr.data)));
  }
  rows.push_back({"PSF chain: CPU adjoint vs central differences (6 heights)", worst, 1e-5});
  // 3-4. End to end through the mode's quantizer and the parameterization, and the offsets.
  const Problem pb = make_problem(rt, o);
  // Rows 3-5 check the chain from the parameters through the PSF to a loss by central
  // differences, which need a smooth loss. The MAE objectives (wiener-mae, and the stand-in a
  // network run's check uses, since the network itself is not part of this chain) are piecewise
  // linear in every error: a 1e-5 step crosses a kink often enough to give errors of ~5e-4 with a
  // correct gradient (seeds 0 and 1 at the default configuration). Those rows then use the Wiener
  // MSE on the same scenes, which shares every part of the chain the check is about. The network's
  // own loss -> PSF gradient is checked in the test suite (adjoint table, joint training's rows).
  const bool smooth = o.objective != Objective::WienerMae && o.objective != Objective::Network;
  DesignRunOptions oc = o;
  if (!smooth) oc.objective = Objective::WienerMse;
  const std::string obj_name = smooth ? to_string(o.objective) : "wiener-mse, a smooth stand-in for " + to_string(o.objective);
  const PsfObjective obj = make_objective(oc, pb, 0);
  Designer d(sim, o.design);
  DesignState st = d.initial_state(initial_params(o));
  st.step = 6;  // mid-schedule
  const std::size_t pinned = std::size_t(o.design.quantizer.pinned_level());
  for (std::size_t l = 0; l < st.offsets.size(); ++l)  // the pinned level's stays 0; level 0 above H = 0 when the top is pinned
    st.offsets[l] = l == pinned ? 0.0 : l == 0 ? 0.1 : 0.1 * double(l % 3) - 0.1;
  if (o.design.mode == DesignMode::QDOM)  // mask depths: uniform, moved by +-10 % so levels are not uniform
    for (std::size_t j = 0; j < st.offsets.size(); ++j)
      st.offsets[j] = uniform_mask_depths(o.design.quantizer)[j] * (j % 2 ? 0.9 : 1.1);
  auto gd = d.gradient(st, obj);
  // Fault injection, for testing that a wrong gradient is caught and reported (exit code 5):
  // QDO_GRADCHECK_FAULT=1 scales the analytic weight gradient by 1.5 before the comparison.
  if (const char* f = std::getenv("QDO_GRADCHECK_FAULT"); f && std::string(f) == "1")
    for (double& gw : gd.g_w) gw *= 1.5;
  // Central-difference step on the normalised parameters: 1e-5 (7.7 pm of height, ~5e-5 rad) in
  // float64; in float32 the loss carries ~1e-7 relative rounding, which a 1e-5 step turns into
  // errors of several percent (the check failed falsely on float32-only devices), so the step
  // is 2e-3 there (truncation error ~h^2, still below the float32 tolerance).
  const double h_fd = p == Precision::F64 ? 1e-5 : 2e-3;
  worst = 0;
  for (int k = 0; k < 5; ++k) {
    const std::size_t idx = rng() % st.w.size();
    DesignState a = st, b = st;
    a.w[idx] += h_fd;
    b.w[idx] -= h_fd;
    const double fd = (d.gradient(a, obj).report.loss - d.gradient(b, obj).report.loss) / (2 * h_fd);
    worst = std::max(worst, rel(fd, gd.g_w[idx], rms(gd.g_w)));
  }
  const double tol_e2e = p == Precision::F64 ? 1e-4 : 5e-2;
  if (o.design.mode == DesignMode::STE) {
    rows.push_back({"weights w (ste): not a derivative (straight-through); checked in the test suite instead", 0, tol_e2e});
  } else {
    rows.push_back({"weights w (" + to_string(o.design.mode) + ", " + obj_name + ", end to end, 5 samples)", worst, tol_e2e});
  }
  if (o.design.mode == DesignMode::QDOA || o.design.mode == DesignMode::QDOM) {
    // qdo+a: the level offsets but the pinned level's; qdo+m: every mask depth.
    const bool masks = o.design.mode == DesignMode::QDOM;
    worst = 0;
    for (std::size_t l = 0; l < st.offsets.size(); ++l) {
      if (!masks && l == pinned) continue;
      DesignState a = st, b = st;
      a.offsets[l] += h_fd;
      b.offsets[l] -= h_fd;
      const double fd = (d.gradient(a, obj).report.loss - d.gradient(b, obj).report.loss) / (2 * h_fd);
      worst = std::max(worst, rel(fd, gd.g_offsets[l], rms(gd.g_offsets)));
    }
    rows.push_back({std::string(masks ? "mask depths delta (qdo+m, " : "level offsets a (qdo+a, ") + obj_name + ")", worst, tol_e2e});
  }
  // 5. The objective with respect to the PSF (CPU, double), at the 6 entries with the largest
  // gradient (most PSF entries barely matter, and their differences are round-off).
  RealStack psf = sim.psf_sensor(), gp;
  const double ref_value = obj(psf, gp);  // also row 6's reference
  worst = 0;
  std::vector<std::size_t> order(psf.size());
  for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::partial_sort(order.begin(), order.begin() + 6, order.end(),
                    [&](std::size_t x, std::size_t y) { return std::fabs(gp.data[x]) > std::fabs(gp.data[y]); });
  // Richardson's extrapolation of two central differences (steps 1e-5 and 2e-5): truncation
  // O(h^4) instead of O(h^2), so the step can be large enough that rounding of the loss stays
  // small. A plain difference with a step of 1e-7 was off by 1.7e-5 (rounding) at a correct
  // gradient (wiener-mse, seed 1, the small preset reduced to N = 64); this one by ~1e-7.
  auto central = [&](std::size_t i, double step) {
    RealStack a = psf, b = psf, tmp;
    a.data[i] += step;
    b.data[i] -= step;
    return (obj(a, tmp) - obj(b, tmp)) / (2 * step);
  };
  for (int k = 0; k < 6; ++k) {
    const std::size_t i = order[std::size_t(k)];
    const double fd = (4 * central(i, 1e-5) - central(i, 2e-5)) / 3;
    worst = std::max(worst, rel(fd, gp.data[i], rms(gp.data)));
  }
  rows.push_back({"objective " + obj_name + " vs PSF (6 largest-gradient entries)", worst, 1e-5});
  // 6. The design loop's device objective (wiener, --wiener-on device) against that CPU reference
  // at the same PSF: the larger of the value's relative error and the gradient's relative L2
  // error. Rows 3-5 use the CPU objective (double) so that they check the chain alone.
  if (const auto dev = make_device_objective(rt, o, pb)) {
    const wiener::PsfObjective r = dev->expected(psf);
    double gnum = 0, gden = 0;
    for (std::size_t i = 0; i < gp.data.size(); ++i) {
      gnum += (r.grad_psf.data[i] - gp.data[i]) * (r.grad_psf.data[i] - gp.data[i]);
      gden += gp.data[i] * gp.data[i];
    }
    const double value_err = std::fabs(r.value - ref_value) / std::fabs(ref_value);
    // float64: round-off amplified by the solve's conditioning; float32: the OTFs and A P in float
    // (measured at the paper preset: 3e-8 value, 8e-6 gradient; BENCHMARKS "CPU speed").
    rows.push_back({"objective wiener on the device (" + to_string(o.precision) + ") vs the CPU reference",
                    std::max(value_err, gden > 0 ? std::sqrt(gnum / gden) : std::sqrt(gnum)),
                    o.precision == Precision::F64 ? 1e-8 : 1e-2});
  }
  return rows;
}

}  // namespace qdo
