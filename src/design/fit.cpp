// The as-built fit (fit.hpp): the model of a measured PSF stack from a design, its adjoint
// gradient, and Levenberg-Marquardt with Gauss-Newton uncertainties.
#include "qdo/fit.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <set>

#include "qdo/design.hpp"
#include "qdo/error.hpp"
#include "qdo/simulator.hpp"

namespace qdo {

namespace {

double since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

std::string fmt(const char* f, double v) {
  char b[64];
  std::snprintf(b, sizeof b, f, v);
  return b;
}

// The bilinear weights of a shift s: s = i + f, i = floor(s), f in [0, 1); out(x) = (1 - f) in(x - i) + f in(x - i - 1).
struct ShiftSplit {
  long i = 0;
  double f = 0;
  explicit ShiftSplit(double s) {
    const double fl = std::floor(s);
    i = long(fl);
    f = s - fl;
  }
};

// Visits every (output index, input index, weight, d weight / d sx, d weight / d sy) of the shift.
template <typename F>
void for_each_tap(std::size_t planes, std::size_t rows, std::size_t cols, double sx, double sy, F&& f) {
  const ShiftSplit x(sx), y(sy);
  const double wx[2] = {1 - x.f, x.f}, wy[2] = {1 - y.f, y.f}, dw[2] = {-1, 1};
  const long r = long(rows), c = long(cols);
  for (std::size_t p = 0; p < planes; ++p) {
    const std::size_t base = p * rows * cols;
    for (long yy = 0; yy < r; ++yy)
      for (int a = 0; a < 2; ++a) {
        const long ys = yy - y.i - a;
        if (ys < 0 || ys >= r) continue;
        for (long xx = 0; xx < c; ++xx)
          for (int b = 0; b < 2; ++b) {
            const long xs = xx - x.i - b;
            if (xs < 0 || xs >= c) continue;
            f(base + std::size_t(yy * c + xx), base + std::size_t(ys * c + xs), wy[a] * wx[b], wy[a] * dw[b], dw[a] * wx[b]);
          }
      }
  }
}

void require_size(const std::vector<double>& v, std::size_t planes, std::size_t rows, std::size_t cols, const char* what) {
  if (v.size() != planes * rows * cols)
    throw Error(std::string("shift_bilinear: ") + what + " holds " + std::to_string(v.size()) + " values, expected " +
                shape(planes, rows, cols));
}

enum class Kind { Level, Mask, Scale, Z, D, DX, DY, SX, SY };

}  // namespace

std::vector<double> shift_bilinear(const std::vector<double>& in, std::size_t planes, std::size_t rows, std::size_t cols, double sx,
                                   double sy) {
  require_size(in, planes, rows, cols, "the input");
  std::vector<double> out(in.size(), 0.0);
  for_each_tap(planes, rows, cols, sx, sy, [&](std::size_t o, std::size_t i, double w, double, double) { out[o] += w * in[i]; });
  return out;
}

std::vector<double> shift_bilinear_adjoint(const std::vector<double>& g_out, std::size_t planes, std::size_t rows, std::size_t cols,
                                           double sx, double sy) {
  require_size(g_out, planes, rows, cols, "the gradient");
  std::vector<double> g(g_out.size(), 0.0);
  for_each_tap(planes, rows, cols, sx, sy, [&](std::size_t o, std::size_t i, double w, double, double) { g[i] += w * g_out[o]; });
  return g;
}

void shift_bilinear_derivative(const std::vector<double>& in, const std::vector<double>& g_out, std::size_t planes, std::size_t rows,
                               std::size_t cols, double sx, double sy, double& d_sx, double& d_sy) {
  require_size(in, planes, rows, cols, "the input");
  require_size(g_out, planes, rows, cols, "the gradient");
  d_sx = d_sy = 0;
  for_each_tap(planes, rows, cols, sx, sy, [&](std::size_t o, std::size_t i, double, double dx, double dy) {
    d_sx += g_out[o] * dx * in[i];
    d_sy += g_out[o] * dy * in[i];
  });
}

std::vector<std::string> fit_parameter_names() { return {"levels", "masks", "scale", "z", "d", "offset", "shift", "aperture"}; }

std::vector<std::string> default_fit_parameters(const Design& design) {
  if (design.levels_m.size() >= 2) return {"levels", "z", "offset"};
  return {"scale", "z", "offset"};
}

// ---------------------------------------------------------------------------------------------
// The model
// ---------------------------------------------------------------------------------------------

struct AsBuiltModel::Impl {
  Impl(Runtime& rt_, const SystemConfig& cfg_, Precision p_, const Design& design_, const FitOptions& opt_)
      : rt(rt_), cfg(cfg_), prec(p_), design(design_), opt(opt_) {}
  Runtime& rt;
  SystemConfig cfg;
  Precision prec;
  Design design;
  FitOptions opt;
  std::size_t n = 0, s = 0;
  bool quantized = false, use_masks = false;
  std::vector<int> level_of;           // N x N: each pixel's level index (quantized designs)
  std::vector<double> masks0;          // the design's mask depths (use_masks)
  std::vector<std::size_t> unused_levels;  // levels no pixel takes (held, not fitted)
  struct Param {
    Kind kind;
    int index;
    std::string name, unit;
    double nominal;
  };
  std::vector<Param> ps;
  std::vector<std::string> names, units;
  double aperture_r = 0;
  std::unique_ptr<Simulator> sim;
  double sim_z = 0, sim_d = 0, sim_r = 0;
  FitTimes t;

  // The complete state at theta: every quantity the model uses, nominal where theta has none.
  struct State {
    std::vector<double> lev, masks;
    double scale = 1, z = 0, d = 0, dx_m = 0, dy_m = 0, sx = 0, sy = 0;
  };

  State state(const std::vector<double>& theta) const {
    if (theta.size() != ps.size())
      throw Error("AsBuiltModel: " + std::to_string(theta.size()) + " parameters given, the model has " + std::to_string(ps.size()));
    State st;
    st.lev = design.levels_m;
    st.masks = masks0;
    st.z = cfg.sensor_distance_m;
    st.d = cfg.scene_distance_m;
    for (std::size_t i = 0; i < ps.size(); ++i) {
      const double v = theta[i];
      switch (ps[i].kind) {
        case Kind::Level: st.lev[std::size_t(ps[i].index)] = v; break;
        case Kind::Mask: st.masks[std::size_t(ps[i].index)] = v; break;
        case Kind::Scale: st.scale = v; break;
        case Kind::Z: st.z = v; break;
        case Kind::D: st.d = v; break;
        case Kind::DX: st.dx_m = v; break;
        case Kind::DY: st.dy_m = v; break;
        case Kind::SX: st.sx = v; break;
        case Kind::SY: st.sy = v; break;
      }
    }
    if (use_masks) st.lev = subset_sums(st.masks);
    return st;
  }

  std::vector<double> subset_sums(const std::vector<double>& m) const {
    std::vector<double> lev(design.levels_m.size(), 0.0);
    for (std::size_t l = 0; l < lev.size(); ++l)
      for (std::size_t j = 0; j < m.size(); ++j)
        if (l & (std::size_t(1) << j)) lev[l] += m[j];
    return lev;
  }

  // H0 (unshifted, scaled) of a state, N x N.
  std::vector<double> unshifted(const State& st) const {
    std::vector<double> h(n * n);
    for (std::size_t i = 0; i < h.size(); ++i)
      h[i] = st.scale * (quantized ? st.lev[std::size_t(level_of[i])] : design.height_m.data[i]);
    return h;
  }

  Map2D heights(const State& st) const {
    Map2D m(n, n);
    m.data = shift_bilinear(unshifted(st), 1, n, n, st.dx_m / cfg.pitch_m, st.dy_m / cfg.pitch_m);
    return m;
  }

  SystemConfig config_of(const State& st) const {
    SystemConfig c = cfg;
    c.sensor_distance_m = st.z;
    c.scene_distance_m = st.d;
    c.aperture_radius_m = aperture_r;
    return c;
  }

  Simulator& simulator(const State& st) {
    if (!sim || sim_z != st.z || sim_d != st.d || sim_r != aperture_r) {
      sim.reset();
      sim = std::make_unique<Simulator>(rt, config_of(st), prec);
      sim_z = st.z;
      sim_d = st.d;
      sim_r = aperture_r;
      ++t.simulators_built;
    }
    return *sim;
  }

  // The PSF stack (unshifted by the registration) at a state; the simulator keeps it for the adjoint.
  RealStack psf(const State& st) {
    Simulator& s_ = simulator(st);
    s_.set_heights(heights(st));
    s_.compute_psf();
    ++t.psf_evaluations;
    return s_.psf_sensor();
  }

  RealStack model(const State& st) {
    RealStack p = psf(st);
    if (st.sx != 0 || st.sy != 0) p.data = shift_bilinear(p.data, p.planes, p.rows, p.cols, st.sx, st.sy);
    return p;
  }

  double half_sq(const RealStack& m, const RealStack& meas) const {
    double l = 0;
    for (std::size_t i = 0; i < m.data.size(); ++i) {
      const double r = m.data[i] - meas.data[i];
      l += r * r;
    }
    return 0.5 * l;
  }

  void check_measured(const RealStack& meas) const {
    if (meas.planes != cfg.bands || meas.rows != s || meas.cols != s)
      throw InputError("the measured PSF stack is " + shape(meas) + "; the configuration needs bands x S x S = " +
                       shape(cfg.bands, s, s));
  }

  // Loss and gradient; the gradient entries of z and d only when fd_distances (else left 0).
  double loss_gradient(const std::vector<double>& theta, const RealStack& meas, std::vector<double>& grad, bool fd_distances,
                       RealStack* model_out) {
    check_measured(meas);
    const State st = state(theta);
    auto t0 = std::chrono::steady_clock::now();
    const RealStack p = psf(st);
    RealStack m = p;
    const bool shifted = st.sx != 0 || st.sy != 0;
    if (shifted) m.data = shift_bilinear(p.data, p.planes, p.rows, p.cols, st.sx, st.sy);
    RealStack r = m;
    double loss = 0;
    for (std::size_t i = 0; i < r.data.size(); ++i) {
      r.data[i] -= meas.data[i];
      loss += r.data[i] * r.data[i];
    }
    loss *= 0.5;
    if (model_out) *model_out = m;
    t.psf_s += since(t0);
    t0 = std::chrono::steady_clock::now();
    grad.assign(ps.size(), 0.0);
    const bool any_adjoint =
        std::any_of(ps.begin(), ps.end(), [](const Param& q) { return q.kind != Kind::Z && q.kind != Kind::D; });
    if (!any_adjoint) {  // z and d only: no adjoint to take
      t.vjp_s += since(t0);
      if (fd_distances) fd_distance_gradient(theta, meas, grad);
      return loss;
    }
    // d / d registration, then back through it to the PSF.
    double g_sx = 0, g_sy = 0;
    RealStack g_p = r;
    if (shifted) {
      shift_bilinear_derivative(p.data, r.data, p.planes, p.rows, p.cols, st.sx, st.sy, g_sx, g_sy);
      g_p.data = shift_bilinear_adjoint(r.data, p.planes, p.rows, p.cols, st.sx, st.sy);
    } else {
      // At exactly zero shift, d/ds is one-sided (the bilinear shift has a kink at integers):
      // the right derivative, as the weights at s = 0+ give it.
      shift_bilinear_derivative(p.data, r.data, p.planes, p.rows, p.cols, 0, 0, g_sx, g_sy);
    }
    const Map2D g_h = sim->psf_sensor_vjp(g_p);
    ++t.vjps;
    const double px = cfg.pitch_m;
    const std::vector<double> h0 = unshifted(st);
    std::vector<double> g_h0 = shift_bilinear_adjoint(g_h.data, 1, n, n, st.dx_m / px, st.dy_m / px);
    double g_dx = 0, g_dy = 0;
    shift_bilinear_derivative(h0, g_h.data, 1, n, n, st.dx_m / px, st.dy_m / px, g_dx, g_dy);
    std::vector<double> g_lev(design.levels_m.size(), 0.0);
    double g_scale = 0;
    for (std::size_t i = 0; i < n * n; ++i) {
      const double base = quantized ? st.lev[std::size_t(level_of[i])] : design.height_m.data[i];
      g_scale += g_h0[i] * base;
      if (quantized) g_lev[std::size_t(level_of[i])] += st.scale * g_h0[i];
    }
    for (std::size_t k = 0; k < ps.size(); ++k) {
      switch (ps[k].kind) {
        case Kind::Level: grad[k] = g_lev[std::size_t(ps[k].index)]; break;
        case Kind::Mask: {
          double g = 0;
          for (std::size_t l = 0; l < g_lev.size(); ++l)
            if (l & (std::size_t(1) << ps[k].index)) g += g_lev[l];
          grad[k] = g;
          break;
        }
        case Kind::Scale: grad[k] = g_scale; break;
        case Kind::DX: grad[k] = g_dx / px; break;
        case Kind::DY: grad[k] = g_dy / px; break;
        case Kind::SX: grad[k] = g_sx; break;
        case Kind::SY: grad[k] = g_sy; break;
        case Kind::Z:
        case Kind::D: break;
      }
    }
    t.vjp_s += since(t0);
    if (fd_distances) fd_distance_gradient(theta, meas, grad);
    return loss;
  }

  // The z and d entries of dL/dtheta by central differences of the loss.
  void fd_distance_gradient(const std::vector<double>& theta, const RealStack& meas, std::vector<double>& grad) {
    const auto t0 = std::chrono::steady_clock::now();
    for (std::size_t k = 0; k < ps.size(); ++k) {
      if (ps[k].kind != Kind::Z && ps[k].kind != Kind::D) continue;
      const double h = step(k, theta);
      std::vector<double> a = theta, b = theta;
      a[k] += h;
      b[k] -= h;
      grad[k] = (half_sq(model(state(a)), meas) - half_sq(model(state(b)), meas)) / (2 * h);
    }
    t.jacobian_s += since(t0);
  }

  double step(std::size_t k, const std::vector<double>& theta) const {
    switch (ps[k].kind) {
      case Kind::Level:
      case Kind::Mask: return opt.fd_height_m;
      case Kind::Scale: return 1e-4;
      case Kind::Z:
      case Kind::D: return opt.fd_rel_distance * std::fabs(theta[k]);
      case Kind::DX:
      case Kind::DY: return opt.fd_px * cfg.pitch_m;
      case Kind::SX:
      case Kind::SY: return opt.fd_px;
    }
    return 0;
  }

  // J (m x p): columns by central differences of the model; the distance columns last, so
  // the simulator of theta's (z, d) serves every other column.
  Eigen::MatrixXd jacobian(const std::vector<double>& theta) {
    const auto t0 = std::chrono::steady_clock::now();
    const std::size_t m = cfg.bands * s * s;
    Eigen::MatrixXd j(m, ps.size());
    std::vector<std::size_t> order;
    for (std::size_t k = 0; k < ps.size(); ++k)
      if (ps[k].kind != Kind::Z && ps[k].kind != Kind::D) order.push_back(k);
    for (std::size_t k = 0; k < ps.size(); ++k)
      if (ps[k].kind == Kind::Z || ps[k].kind == Kind::D) order.push_back(k);
    for (std::size_t k : order) {
      const double h = step(k, theta);
      std::vector<double> a = theta, b = theta;
      a[k] += h;
      b[k] -= h;
      const RealStack fa = model(state(a)), fb = model(state(b));
      for (std::size_t i = 0; i < m; ++i) j(long(i), long(k)) = (fa.data[i] - fb.data[i]) / (2 * h);
    }
    t.jacobian_s += since(t0);
    return j;
  }
};

void check_fit_parameters(const SystemConfig& cfg, const Design& design, const std::vector<std::string>& parameters) {
  cfg.validate();
  if (design.height_m.rows != cfg.n || design.height_m.cols != cfg.n)
    throw InputError("the design is " + std::to_string(design.height_m.rows) + " x " + std::to_string(design.height_m.cols) +
                     "; the configuration's DOE grid is N x N = " + std::to_string(cfg.n) + " x " + std::to_string(cfg.n));
  if (std::fabs(design.pitch_m - cfg.pitch_m) > 1e-6 * cfg.pitch_m)
    throw InputError("the design's pitch_m is " + fmt("%g", design.pitch_m) + "; the configuration's is " + fmt("%g", cfg.pitch_m));
  std::set<std::string> given;
  const auto known = fit_parameter_names();
  for (const auto& name : parameters) {
    if (std::find(known.begin(), known.end(), name) == known.end())
      reject("--fit", name, "a comma-separated list of levels, masks, scale, z, d, offset, shift, aperture");
    if (!given.insert(name).second) reject("--fit", name, "each parameter once");
  }
  given.erase("aperture");  // not a continuous parameter (fit_as_built scans it)
  if (given.empty()) reject("--fit", "aperture alone", "at least one of levels, masks, scale, z, d, offset, shift");
  const auto has = [&](const char* s) { return given.count(s) > 0; };
  const std::size_t levels = design.levels_m.size();
  if ((has("levels") || has("masks")) && levels < 2)
    reject("--fit", has("levels") ? "levels" : "masks",
           "levels or masks only for a quantized design (a design file with /levels_m); this design has no level table: fit scale instead");
  if (has("levels") && has("masks")) reject("--fit", "levels,masks", "one of levels (every level free) and masks (subset sums)");
  if (has("scale") && (has("levels") || has("masks")))
    reject("--fit", "scale with " + std::string(has("levels") ? "levels" : "masks"),
           "scale or free level depths, not both: a global scale of the heights is exactly a scale of every level depth (a "
           "degenerate pair)");
  if (has("d") && cfg.scene_at_infinity)
    reject("--fit", "d", "d only for a finite object distance (the configuration's scene is at infinity)");
  for (double l : design.levels_m)
    if (!std::isfinite(l)) throw InputError("the design's level table holds a non-finite value");
  if (has("masks")) {
    const int k = mask_count(int(levels));  // InputError unless a power of two
    for (std::size_t l = 0; l < levels; ++l) {
      double sum = 0;
      for (int j = 0; j < k; ++j)
        if (l & (std::size_t(1) << j)) sum += design.levels_m[std::size_t(1) << j];
      if (std::fabs(sum - design.levels_m[l]) > 1e-9 || std::fabs(design.levels_m[0]) > 1e-9)
        reject("--fit", "masks",
               "masks only for a QDO+M design: level 0 at 0 and every level the subset sum of the log2(L) mask depths (level " +
                   std::to_string(l) + " is " + fmt("%.2f", design.levels_m[l] * 1e9) + " nm, the subset sum " + fmt("%.2f", sum * 1e9) +
                   " nm, level 0 " + fmt("%.2f", design.levels_m[0] * 1e9) + " nm); fit levels instead");
    }
  }
}

AsBuiltModel::AsBuiltModel(Runtime& rt, const SystemConfig& cfg, Precision p, const Design& design,
                           const std::vector<std::string>& parameters, const FitOptions& opt)
    : impl_(std::make_unique<Impl>(rt, cfg, p, design, opt)) {
  Impl& m = *impl_;
  cfg.validate();
  m.n = cfg.n;
  m.s = cfg.sensor_size_px();
  m.aperture_r = cfg.aperture_radius();
  check_fit_parameters(cfg, design, parameters);
  std::set<std::string> given(parameters.begin(), parameters.end());
  const auto has = [&](const char* s_) { return given.count(s_) > 0; };
  const std::size_t levels = design.levels_m.size();
  m.quantized = levels >= 2;
  if (m.quantized) {
    m.level_of.resize(m.n * m.n);
    for (std::size_t i = 0; i < m.level_of.size(); ++i) {
      const double h = design.height_m.data[i];
      std::size_t best = 0;
      for (std::size_t l = 1; l < levels; ++l)
        if (std::fabs(design.levels_m[l] - h) < std::fabs(design.levels_m[best] - h)) best = l;
      m.level_of[i] = int(best);
    }
  }
  if (has("masks")) {
    const int k = mask_count(int(levels));  // InputError unless a power of two
    m.use_masks = true;
    m.masks0.resize(std::size_t(k));
    for (int j = 0; j < k; ++j) m.masks0[std::size_t(j)] = design.levels_m[std::size_t(1) << j];
  }
  // The layout: in the order of fit_parameter_names().
  const auto add = [&](Kind kind, int index, std::string name, std::string unit, double nominal) {
    m.ps.push_back({kind, index, name, unit, nominal});
    m.names.push_back(name);
    m.units.push_back(unit);
  };
  if (has("levels")) {
    // A level no pixel uses leaves the PSF unchanged: held at its design value (not a parameter).
    std::vector<std::size_t> count(levels, 0);
    for (int l : m.level_of) ++count[std::size_t(l)];
    for (std::size_t l = 1; l < levels; ++l)
      if (count[l] > 0)
        add(Kind::Level, int(l), "level" + std::to_string(l), "m", design.levels_m[l]);
      else
        m.unused_levels.push_back(l);
  }
  if (has("masks"))
    for (std::size_t j = 0; j < m.masks0.size(); ++j) add(Kind::Mask, int(j), "mask" + std::to_string(j), "m", m.masks0[j]);
  if (has("scale")) add(Kind::Scale, 0, "scale", "", 1.0);
  if (has("z")) add(Kind::Z, 0, "z", "m", cfg.sensor_distance_m);
  if (has("d")) add(Kind::D, 0, "d", "m", cfg.scene_distance_m);
  if (has("offset")) {
    add(Kind::DX, 0, "dx", "m", 0.0);
    add(Kind::DY, 0, "dy", "m", 0.0);
  }
  if (has("shift")) {
    add(Kind::SX, 0, "sx", "px", 0.0);
    add(Kind::SY, 0, "sy", "px", 0.0);
  }
}

AsBuiltModel::~AsBuiltModel() = default;

const std::vector<std::string>& AsBuiltModel::parameter_names() const { return impl_->names; }
const std::vector<std::string>& AsBuiltModel::parameter_units() const { return impl_->units; }
std::vector<double> AsBuiltModel::design_values() const {
  std::vector<double> v;
  for (const auto& p : impl_->ps) v.push_back(p.nominal);
  return v;
}
bool AsBuiltModel::adjoint_parameter(std::size_t i) const { return impl_->ps.at(i).kind != Kind::Z && impl_->ps.at(i).kind != Kind::D; }
RealStack AsBuiltModel::evaluate(const std::vector<double>& theta) {
  const auto t0 = std::chrono::steady_clock::now();
  RealStack r = impl_->model(impl_->state(theta));
  impl_->t.psf_s += since(t0);
  return r;
}
double AsBuiltModel::loss_gradient(const std::vector<double>& theta, const RealStack& measured, std::vector<double>& grad) {
  return impl_->loss_gradient(theta, measured, grad, true, nullptr);
}
double AsBuiltModel::loss(const std::vector<double>& theta, const RealStack& measured) {
  impl_->check_measured(measured);
  return impl_->half_sq(evaluate(theta), measured);
}
Map2D AsBuiltModel::heights(const std::vector<double>& theta) const { return impl_->heights(impl_->state(theta)); }
SystemConfig AsBuiltModel::config(const std::vector<double>& theta) const { return impl_->config_of(impl_->state(theta)); }
void AsBuiltModel::set_aperture_radius(double r_m) { impl_->aperture_r = r_m; }
double AsBuiltModel::aperture_radius() const { return impl_->aperture_r; }
std::vector<double> AsBuiltModel::levels(const std::vector<double>& theta) const {
  if (!impl_->quantized) return {};
  const auto st = impl_->state(theta);
  std::vector<double> l = st.lev;
  for (double& v : l) v *= st.scale;
  return l;
}
FitTimes& AsBuiltModel::times() { return impl_->t; }
const std::vector<std::size_t>& AsBuiltModel::unused_levels() const { return impl_->unused_levels; }
double AsBuiltModel::adjoint_gradient(const std::vector<double>& theta, const RealStack& measured, std::vector<double>& grad,
                                      RealStack* model_out) {
  return impl_->loss_gradient(theta, measured, grad, false, model_out);
}
Eigen::MatrixXd AsBuiltModel::jacobian(const std::vector<double>& theta) { return impl_->jacobian(theta); }

// ---------------------------------------------------------------------------------------------
// The fit
// ---------------------------------------------------------------------------------------------

namespace {

std::vector<double> band_residuals(const RealStack& model, const RealStack& meas) {
  const std::size_t plane = meas.rows * meas.cols;
  std::vector<double> out(meas.planes, 0.0);
  for (std::size_t b = 0; b < meas.planes; ++b) {
    double rr = 0, mm = 0;
    for (std::size_t i = b * plane; i < (b + 1) * plane; ++i) {
      const double r = model.data[i] - meas.data[i];
      rr += r * r;
      mm += meas.data[i] * meas.data[i];
    }
    out[b] = mm > 0 ? std::sqrt(rr / mm) : std::sqrt(rr);
  }
  return out;
}

// The mean over bands of the centroid of a minus that of b (sensor px, (columns, rows)), each
// over the pixels above 10 % of its band's peak (the noise of the dark background left out).
std::pair<double, double> centroid_difference_px(const RealStack& a, const RealStack& b) {
  const auto centroid = [](const RealStack& st, std::size_t band, double& cx, double& cy) {
    const std::size_t plane = st.rows * st.cols;
    const double* p = st.data.data() + band * plane;
    const double peak = *std::max_element(p, p + plane);
    double w = 0;
    cx = cy = 0;
    for (std::size_t i = 0; i < plane; ++i)
      if (p[i] > 0.1 * peak) {
        w += p[i];
        cx += p[i] * double(i % st.cols);
        cy += p[i] * double(i / st.cols);
      }
    if (w > 0) {
      cx /= w;
      cy /= w;
    }
    return w > 0;
  };
  double sx = 0, sy = 0;
  std::size_t used = 0;
  for (std::size_t band = 0; band < a.planes; ++band) {
    double ax, ay, bx, by;
    if (!centroid(a, band, ax, ay) || !centroid(b, band, bx, by)) continue;
    sx += ax - bx;
    sy += ay - by;
    ++used;
  }
  return used ? std::make_pair(sx / double(used), sy / double(used)) : std::make_pair(0.0, 0.0);
}

std::string values_line(const AsBuiltModel& m, const std::vector<double>& theta) {
  std::string s;
  for (std::size_t i = 0; i < theta.size(); ++i) {
    const std::string& u = m.parameter_units()[i];
    const std::string& n = m.parameter_names()[i];
    if (u == "m" && (n == "z" || n == "d"))
      s += " " + n + "=" + fmt("%.4f", theta[i] * 1e3) + "mm";
    else if (u == "m" && (n == "dx" || n == "dy"))
      s += " " + n + "=" + fmt("%.3f", theta[i] * 1e6) + "um";
    else if (u == "m")
      s += " " + n + "=" + fmt("%.2f", theta[i] * 1e9) + "nm";
    else
      s += " " + n + "=" + fmt("%.5f", theta[i]);
  }
  return s;
}

}  // namespace

FitResult fit_as_built(Runtime& rt, const SystemConfig& cfg, Precision p, const Design& design, const RealStack& measured,
                       const FitOptions& opt_in) {
  FitOptions opt = opt_in;
  if (opt.parameters.empty()) opt.parameters = default_fit_parameters(design);
  if (opt.max_iterations < 1) reject("--iterations", opt.max_iterations, "an integer >= 1");
  const std::size_t s = cfg.sensor_size_px();
  if (measured.planes != cfg.bands || measured.rows != s || measured.cols != s)
    throw InputError("the measured PSF stack is " + shape(measured) + "; the configuration needs bands x S x S = " +
                     shape(cfg.bands, s, s));
  for (double v : measured.data)
    if (!std::isfinite(v)) throw InputError("the measured PSF stack holds a non-finite value");
  const bool scan_aperture = std::find(opt.parameters.begin(), opt.parameters.end(), "aperture") != opt.parameters.end();
  AsBuiltModel model(rt, cfg, p, design, opt.parameters, opt);  // every other check, before device work
  const std::size_t np = model.parameter_names().size(), m = measured.data.size();
  if (m <= np) throw InputError("the measured PSF stack has " + std::to_string(m) + " values for " + std::to_string(np) + " parameters");
  const auto say = [&](const std::string& l) {
    if (opt.progress) opt.progress(l);
  };
  const Eigen::Map<const Eigen::VectorXd> meas(measured.data.data(), long(m));
  FitResult res;
  FitTimes& t = model.times();
  const auto wall0 = std::chrono::steady_clock::now();
  const std::vector<double> theta0 = model.design_values();
  std::vector<double> theta = theta0;
  res.design_psf = model.evaluate(theta0);
  res.loss_design = 0.5 * (Eigen::Map<const Eigen::VectorXd>(res.design_psf.data.data(), long(m)) - meas).squaredNorm();
  res.residual_rel_design = band_residuals(res.design_psf, measured);
  // The lateral start: a relief offset (dx, dy) moves the image of the on-axis point by
  // (dx, dy) (1 + z/d), while the blur it adds to the sampled relief is the same for +-dx: from
  // zero, the fit can fall into the mirror minimum. It starts from the centroid difference of the
  // measured and design stacks (shift when it is fitted, else offset).
  {
    const auto& names = model.parameter_names();
    const auto find = [&](const char* n) { return std::size_t(std::find(names.begin(), names.end(), n) - names.begin()); };
    const auto c = centroid_difference_px(measured, res.design_psf);
    const std::size_t sx = find("sx"), dx = find("dx");
    if (sx < np) {
      theta[sx] = c.first;
      theta[sx + 1] = c.second;
    } else if (dx < np) {
      const double mag = cfg.scene_at_infinity ? 1.0 : 1.0 + cfg.sensor_distance_m / cfg.scene_distance_m;
      theta[dx] = c.first * cfg.sensor_pitch_m / mag;
      theta[dx + 1] = c.second * cfg.sensor_pitch_m / mag;
    }
    if (sx < np || dx < np) {
      res.centroid_shift_px = {c.first, c.second};
      say("fit: centroid of the measured stack against the design's: (" + fmt("%+.4f", c.first) + ", " + fmt("%+.4f", c.second) +
          ") sensor px; the start of " + (sx < np ? "shift" : "offset"));
    }
    for (const auto& [name, value] : opt.start) {
      const std::size_t k = find(name.c_str());
      if (k >= np) reject("start", name, "a fitted parameter's name (" + [&] {
                            std::string all;
                            for (const auto& n : names) all += (all.empty() ? "" : ", ") + n;
                            return all;
                          }() + ")");
      if (!std::isfinite(value)) reject("start", name + "=" + fmt("%g", value), "a finite value");
      theta[k] = value;
    }
    // A grid of lateral starts: the lowest loss wins (the centroid start among them).
    // The grid is over the offset when it is fitted (with shift fitted too, each offset's shift
    // start keeps the image where the centroid says: c - offset x magnification / sensor pitch),
    // else over the shift.
    const std::size_t lat = dx < np ? dx : sx;
    if (lat < np && opt.lateral_starts > 1) {
      const double mag = cfg.scene_at_infinity ? 1.0 : 1.0 + cfg.sensor_distance_m / cfg.scene_distance_m;
      const double unit = lat == sx ? 1.0 : cfg.sensor_pitch_m / mag;  // sensor px -> the parameter's unit
      const double span = sx < np && dx < np ? 0.5 * opt.lateral_span_px : std::max(std::fabs(c.first), std::fabs(c.second)) + opt.lateral_span_px;
      const int k = opt.lateral_starts;
      double best = model.loss(theta, measured);
      std::vector<double> best_theta = theta;
      for (int iy = 0; iy < k; ++iy)
        for (int ix = 0; ix < k; ++ix) {
          std::vector<double> trial = theta;
          const double ox = -span + 2 * span * ix / (k - 1), oy = -span + 2 * span * iy / (k - 1);  // sensor px
          trial[lat] = ox * unit;
          trial[lat + 1] = oy * unit;
          if (lat == dx && sx < np) {
            trial[sx] = c.first - ox;
            trial[sx + 1] = c.second - oy;
          }
          double l = std::numeric_limits<double>::infinity();
          try {
            if (lat == dx && sx < np) {
              // The registration too: the model at zero shift once, then every whole-pixel shift
              // within +-3 px of the centroid's on the host (a whole-pixel shift is exact).
              trial[sx] = trial[sx + 1] = 0;
              const RealStack p0 = model.evaluate(trial);
              const long cx = std::lround(c.first - ox), cy = std::lround(c.second - oy);
              for (long jy = cy - 3; jy <= cy + 3; ++jy)
                for (long jx = cx - 3; jx <= cx + 3; ++jx) {
                  const std::vector<double> sh = shift_bilinear(p0.data, p0.planes, p0.rows, p0.cols, double(jx), double(jy));
                  double ls = 0;
                  for (std::size_t i = 0; i < sh.size(); ++i) ls += (sh[i] - measured.data[i]) * (sh[i] - measured.data[i]);
                  ls *= 0.5;
                  if (ls < l) {
                    l = ls;
                    trial[sx] = double(jx);
                    trial[sx + 1] = double(jy);
                  }
                }
            } else {
              l = model.loss(trial, measured);
            }
          } catch (const InputError&) {
          }
          if (l < best) {
            best = l;
            best_theta = trial;
          }
        }
      theta = best_theta;
      say("fit: " + std::to_string(k * k) + " lateral starts of " + names[lat] + ", " + names[lat + 1] + " within +-" + fmt("%.3g", span) +
          " sensor px: the lowest loss " + fmt("%.6e", best) + " at " + names[lat] + " = " + fmt("%.4g", theta[lat]) + ", " +
          names[lat + 1] + " = " + fmt("%.4g", theta[lat + 1]));
    }
  }
  double loss = model.loss(theta, measured), lambda = opt.lambda0;
  res.loss_initial = loss;
  res.loss_history.push_back(loss);
  for (std::size_t l : model.unused_levels())
    say("fit: level " + std::to_string(l) + " is used by no DOE pixel: held at its design value (the PSF does not depend on it)");
  res.unused_levels = model.unused_levels();
  say("fit: " + std::to_string(np) + " parameters, " + std::to_string(m) + " residuals; design loss " + fmt("%.6e", loss) +
      values_line(model, theta));
  const auto distance = [&](std::size_t k) { return !model.adjoint_parameter(k); };
  // Levenberg-Marquardt: the adjoint gradient (the distances' entries from the Jacobian's
  // columns), J^T J from the Jacobian, Marquardt's damping on its diagonal.
  const auto run_lm = [&]() {
    for (int it = 1; it <= opt.max_iterations; ++it) {
      std::vector<double> grad;
      RealStack current;
      loss = model.adjoint_gradient(theta, measured, grad, &current);
      const Eigen::MatrixXd j = model.jacobian(theta);
      const auto ts = std::chrono::steady_clock::now();
      const Eigen::VectorXd r = Eigen::Map<const Eigen::VectorXd>(current.data.data(), long(m)) - meas;
      Eigen::VectorXd g = Eigen::VectorXd::Zero(long(np));
      for (std::size_t k = 0; k < np; ++k) g(long(k)) = distance(k) ? j.col(long(k)).dot(r) : grad[k];
      const Eigen::MatrixXd a = j.transpose() * j;
      t.solve_s += since(ts);
      bool accepted = false;
      double trial_loss = loss;
      std::vector<double> trial;
      for (int tries = 0; tries < 16 && !accepted; ++tries) {
        const auto t1 = std::chrono::steady_clock::now();
        Eigen::MatrixXd al = a;
        const double dmax = a.diagonal().maxCoeff();
        for (long k = 0; k < long(np); ++k) al(k, k) += lambda * std::max(a(k, k), 1e-12 * dmax);
        const Eigen::VectorXd delta = al.ldlt().solve(-g);
        t.solve_s += since(t1);
        trial = theta;
        for (std::size_t k = 0; k < np; ++k) trial[k] += delta(long(k));
        try {
          trial_loss = model.loss(trial, measured);
        } catch (const InputError&) {  // a step outside the valid heights or geometry
          trial_loss = std::numeric_limits<double>::infinity();
        }
        if (std::isfinite(trial_loss) && trial_loss < loss) {
          accepted = true;
          lambda = std::max(lambda / 10, 1e-12);
        } else {
          lambda *= 10;
        }
      }
      ++res.iterations;
      if (!accepted) {
        say("fit: iteration " + std::to_string(it) + ": no step lowers the loss (lambda " + fmt("%.1e", lambda) + "); stopping");
        res.converged = true;
        break;
      }
      const double drop = (loss - trial_loss) / loss;
      // The step against the current 1-sigma (s^2 diag((J^T J)^-1), s^2 from the loss before it).
      double step_sigmas = 0;
      {
        const Eigen::MatrixXd cov = a.completeOrthogonalDecomposition().pseudoInverse() * (2 * loss / double(m - np));
        for (std::size_t k = 0; k < np; ++k) {
          const double sg = std::sqrt(std::max(cov(long(k), long(k)), 0.0));
          step_sigmas = std::max(step_sigmas, sg > 0 ? std::fabs(trial[k] - theta[k]) / sg : 0.0);
        }
      }
      theta = trial;
      loss = trial_loss;
      res.loss_history.push_back(loss);
      say("fit: iteration " + std::to_string(it) + "/" + std::to_string(opt.max_iterations) + " loss " + fmt("%.6e", loss) + " (-" +
          fmt("%.2e", drop) + ") lambda " + fmt("%.1e", lambda) + " step " + fmt("%.2g", step_sigmas) + " sigma" +
          values_line(model, theta) + " [" + fmt("%.1f", since(wall0)) + " s]");
      if (drop < opt.tolerance || step_sigmas < opt.step_sigmas) {
        res.converged = true;
        break;
      }
    }
  };
  // The aperture: a walk of the loss over radii in half-pixel steps, downhill from the current
  // radius until the loss rises (at most 40 steps, radii in (0, N/2 pitch]), the rest at their
  // fit; when the radius moved, the rest are fitted again with it and the walk repeated (3 rounds
  // at most). The vertex of the parabola through the minimum and its neighbours is the reported
  // radius, its curvature the sigma; the configuration takes the vertex.
  FitValue aperture;
  const double r_design = model.aperture_radius(), h = 0.5 * cfg.pitch_m, rmax = 0.5 * double(cfg.n) * cfg.pitch_m;
  // One walk; whether the radius moved.
  const auto walk = [&]() {
    const auto t1 = std::chrono::steady_clock::now();
    const double r0 = model.aperture_radius();
    const auto loss_at = [&](double r) {
      model.set_aperture_radius(r);
      const double l = model.loss(theta, measured);
      say("fit: aperture scan radius " + fmt("%.3f", r / cfg.pitch_m) + " px loss " + fmt("%.6e", l));
      return l;
    };
    const auto valid = [&](double r) { return r > 0 && r <= rmax * (1 + 1e-12); };
    double l0 = loss, lm = valid(r0 - h) ? loss_at(r0 - h) : std::numeric_limits<double>::infinity(),
           lp = valid(r0 + h) ? loss_at(r0 + h) : std::numeric_limits<double>::infinity();
    double r = r0;
    const double dir = lm < l0 && lm <= lp ? -1.0 : lp < l0 ? 1.0 : 0.0;
    for (int k = 0; dir != 0 && k < 40; ++k) {
      // Step: (lm, l0, lp) become the triple around r + dir h.
      const double next = r + 2 * dir * h;
      const double l_next = valid(next) ? loss_at(next) : std::numeric_limits<double>::infinity();
      if (dir < 0) {
        lp = l0;
        l0 = lm;
        lm = l_next;
      } else {
        lm = l0;
        l0 = lp;
        lp = l_next;
      }
      r += dir * h;
      if ((dir < 0 ? lm : lp) >= l0) break;  // bracketed
    }
    double r_fit = r, curv = 0;
    if (std::isfinite(lm) && std::isfinite(lp)) {
      curv = (lm + lp - 2 * l0) / (h * h);
      if (curv > 0) r_fit = r - h * (lp - lm) / (2 * (lp + lm - 2 * l0));
    }
    model.set_aperture_radius(r);
    loss = l0;
    aperture = {"aperture", "m", r_design, r_fit, 0, "scan"};
    aperture.sigma = curv > 0 ? std::sqrt(2 * loss / double(m - np) / curv) : std::numeric_limits<double>::infinity();
    t.scan_s += since(t1);
    if (r == r0) return false;
    say("fit: aperture radius " + fmt("%.3f", r / cfg.pitch_m) + " px; the other parameters fitted (again) with it");
    return true;
  };
  if (scan_aperture) walk();  // first at the start values: a wrong aperture pulls the levels far
  run_lm();
  for (int round = 0; scan_aperture && round < 3 && walk(); ++round) {
    lambda = opt.lambda0;
    res.converged = false;
    run_lm();
  }
  // Uncertainties at the fit: Cov = s^2 (J^T J)^-1, in the unit-diagonal scaling.
  const Eigen::MatrixXd j = model.jacobian(theta);
  const auto t2 = std::chrono::steady_clock::now();
  const Eigen::MatrixXd a = j.transpose() * j;
  Eigen::VectorXd dinv = Eigen::VectorXd::Zero(long(np));
  for (long k = 0; k < long(np); ++k) dinv(k) = a(k, k) > 0 ? 1 / std::sqrt(a(k, k)) : 0;
  const Eigen::MatrixXd as = dinv.asDiagonal() * a * dinv.asDiagonal();
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(as);
  const Eigen::VectorXd ev = es.eigenvalues();
  const double evmax = ev.maxCoeff(), evmin = ev.minCoeff();
  res.condition = evmin > 0 ? evmax / evmin : std::numeric_limits<double>::infinity();
  Eigen::VectorXd evinv = Eigen::VectorXd::Zero(long(np));
  for (long k = 0; k < long(np); ++k) evinv(k) = ev(k) > 1e-15 * evmax ? 1 / ev(k) : 0;
  const Eigen::MatrixXd as_inv = es.eigenvectors() * evinv.asDiagonal() * es.eigenvectors().transpose();
  const double s2 = 2 * loss / double(m - np);
  res.residual_sigma = std::sqrt(s2);
  res.correlation = Eigen::MatrixXd::Zero(long(np), long(np));
  for (long a_ = 0; a_ < long(np); ++a_)
    for (long b = 0; b < long(np); ++b) {
      const double den = std::sqrt(as_inv(a_, a_) * as_inv(b, b));
      res.correlation(a_, b) = den > 0 ? as_inv(a_, b) / den : (a_ == b ? 1.0 : 0.0);
    }
  for (std::size_t k = 0; k < np; ++k) {
    FitValue v;
    v.name = model.parameter_names()[k];
    v.unit = model.parameter_units()[k];
    v.design = theta0[k];
    v.value = theta[k];
    v.sigma = as_inv(long(k), long(k)) > 0 ? std::sqrt(s2 * as_inv(long(k), long(k))) * dinv(long(k))
                                           : std::numeric_limits<double>::infinity();
    v.gradient = model.adjoint_parameter(k) ? "adjoint" : "central differences";
    res.values.push_back(v);
  }
  for (std::size_t x = 0; x < np; ++x)
    for (std::size_t y = x + 1; y < np; ++y)
      if (std::fabs(res.correlation(long(x), long(y))) > 0.95) res.degenerate.push_back({x, y});
  t.solve_s += since(t2);
  if (scan_aperture) res.values.push_back(aperture);
  res.model_psf = model.evaluate(theta);
  res.loss_final = 0.5 * (Eigen::Map<const Eigen::VectorXd>(res.model_psf.data.data(), long(m)) - meas).squaredNorm();
  res.residual_rel_fit = band_residuals(res.model_psf, measured);
  res.as_built.height_m = model.heights(theta);
  res.as_built.pitch_m = design.pitch_m;
  res.as_built.levels_m = model.levels(theta);
  res.as_built_config = model.config(theta);
  if (scan_aperture) res.as_built_config.aperture_radius_m = aperture.value;
  res.times = t;
  return res;
}


}  // namespace qdo
