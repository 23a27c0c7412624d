// The as-built model of the fit (fit.hpp): AsBuiltModel, a measured PSF stack's model from a
// design, its adjoint gradient and Jacobian. The registration shift is fit_shift.cpp, the
// parameters' names and checks fit_parameters.cpp, the fit itself fit.cpp.
#include "qdo/asbuilt/fit.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <set>

#include "qdo/design/design.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/physics/simulator.hpp"

#include "fit_internal.hpp"

namespace qdo {

using fit_detail::since;

namespace {

enum class Kind { Level, Mask, Scale, Z, D, DX, DY, SX, SY, OX, OY };

}  // namespace

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
  // With the overlay fitted: the masks (fit_mask_set), each moved by its own (ox, oy).
  bool overlay = false;
  FitMaskSet mask_set;
  bool scale_fitted = false;  // dL/dscale is taken only then (it needs the unscaled relief again)
  std::vector<std::string> names, units;
  double aperture_r = 0;
  bool offset = false;  // the relief's offset is fitted: the model moves it exactly (move_relief)
  std::unique_ptr<Simulator> sim;
  double sim_z = 0, sim_d = 0, sim_r = 0, sim_ax = 0, sim_ay = 0;
  // With the registration fitted: the native stack of the last PSF computed (planes x N x N), for
  // the simulator build and the heights it was computed for; the registration's differences and
  // other states with the same heights and geometry integrate it again without a new PSF.
  bool registration = false;
  RealStack native;
  Map2D native_heights;
  long native_build = 0;  // sim_generation when native was computed
  long sim_generation = 0;  // incremented by every new simulator and every move of its optical axis
  FitTimes t;

  // The complete state at theta: every quantity the model uses, nominal where theta has none.
  struct State {
    std::vector<double> lev, masks;
    double scale = 1, z = 0, d = 0, dx_m = 0, dy_m = 0, sx = 0, sy = 0;
    std::vector<double> ox_m, oy_m;  // each mask's overlay (metres; index 0, the first mask, stays 0)
  };

  State state(const std::vector<double>& theta) const {
    if (theta.size() != ps.size())
      throw Error("AsBuiltModel: " + std::to_string(theta.size()) + " parameters given, the model has " + std::to_string(ps.size()));
    State st;
    st.lev = design.levels_m;
    st.masks = masks0;
    st.z = cfg.sensor_distance_m;
    st.d = cfg.scene_distance_m;
    st.ox_m.assign(mask_set.open.size(), 0.0);
    st.oy_m.assign(mask_set.open.size(), 0.0);
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
        case Kind::OX: st.ox_m[std::size_t(ps[i].index)] = v; break;
        case Kind::OY: st.oy_m[std::size_t(ps[i].index)] = v; break;
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

  // H0 / scale (unshifted) of a state, N x N: the level map, or with the overlay the masks' relief.
  std::vector<double> unscaled(const State& st) const {
    if (overlay) {
      double top = 0;
      const std::vector<double> e = fit_detail::mask_etch_depths(mask_set, st.lev, st.masks, top);
      return fit_detail::mask_relief(mask_set, e, top, st.ox_m, st.oy_m, cfg.pitch_m);
    }
    std::vector<double> h(n * n);
    for (std::size_t i = 0; i < h.size(); ++i) h[i] = quantized ? st.lev[std::size_t(level_of[i])] : design.height_m.data[i];
    return h;
  }

  // H0 (unshifted, scaled) of a state, N x N.
  std::vector<double> unshifted(const State& st) const {
    std::vector<double> h = unscaled(st);
    for (double& v : h) v *= st.scale;
    return h;
  }

  // The configuration before the relief's move (z, d and the aperture radius of the state).
  SystemConfig base_config(const State& st) const {
    SystemConfig c = cfg;
    c.sensor_distance_m = st.z;
    c.scene_distance_m = st.d;
    c.aperture_radius_m = aperture_r;
    return c;
  }

  // The relief (N x N) and the configuration that simulate a state: with the offset fitted, the
  // relief moved by (dx, dy) exactly (optics.hpp move_relief: whole pixels in the map, the rest as
  // the optical axis moved the other way, the aperture area-weighted at every offset so the model
  // is continuous in it); otherwise the unmoved relief in cfg's geometry.
  Map2D heights(const State& st) const {
    Map2D m(n, n);
    m.data = unshifted(st);
    if (offset) move_relief(base_config(st), m, st.dx_m, st.dy_m);
    return m;
  }

  SystemConfig config_of(const State& st) const {
    return offset ? moved_relief_config(base_config(st), st.dx_m, st.dy_m) : base_config(st);
  }

  // A new simulator when z, d or the aperture radius change; when only the relief's offset does,
  // the simulator's optical axis is moved instead (Simulator::set_optical_axis: new aperture
  // weights, point table and sensor weights, no new kernels or FFT plans).
  Simulator& simulator(const State& st) {
    const SystemConfig c = config_of(st);
    if (!sim || sim_z != st.z || sim_d != st.d || sim_r != aperture_r) {
      sim.reset();
      sim = std::make_unique<Simulator>(rt, c, prec);
      sim_z = st.z;
      sim_d = st.d;
      sim_r = aperture_r;
      ++t.simulators_built;
      ++sim_generation;
    } else if (sim_ax != c.aperture_offset_x_m || sim_ay != c.aperture_offset_y_m) {
      sim->set_optical_axis(c.aperture_offset_x_m, c.aperture_offset_y_m);
      ++sim_generation;
    }
    sim_ax = c.aperture_offset_x_m;
    sim_ay = c.aperture_offset_y_m;
    return *sim;
  }

  // Parameters whose gradient entries and Jacobian columns are central differences: z, d and the
  // relief's offset change the configuration (a new simulator; the offset moves the optical axis),
  // the registration only the integration of the native stack (no new PSF). The others go through
  // the adjoint.
  static bool by_differences(Kind k) {
    return k == Kind::Z || k == Kind::D || k == Kind::DX || k == Kind::DY || k == Kind::SX || k == Kind::SY;
  }

  // The PSF stack (bands x S x S) at a state; the simulator keeps its state for the adjoint. With
  // the registration fitted: the native stack integrated by the moved pixel grid (fit.hpp), the
  // PSF computed only when the geometry or the heights differ from the last one's.
  RealStack psf(const State& st) {
    Simulator& s_ = simulator(st);
    Map2D h = heights(st);
    // Levels move freely and level 0 is held, so a level can pass below it: the map then has
    // negative heights, which no simulator takes. Adding one constant to every height is a piston
    // (the same phase over the whole aperture, band by band: the same PSF), so the lowest height is
    // lifted to 0. Its gradient is zero, as the PSF's is to a piston.
    const double lowest = *std::min_element(h.data.begin(), h.data.end());
    if (lowest < 0)
      for (double& v : h.data) v -= lowest;
    if (registration && native_build == sim_generation && native.planes && h.data == native_heights.data)
      return integrate_registered(native, s_.config(), st.sx, st.sy);
    s_.set_heights(h);
    s_.compute_psf();
    ++t.psf_evaluations;
    if (!registration) return s_.psf_sensor();
    native = s_.psf_native();
    native_heights = std::move(h);
    native_build = sim_generation;
    return integrate_registered(native, s_.config(), st.sx, st.sy);
  }

  // What the loss compares: the PSF stack, or its observation (FitOptions::observation).
  RealStack model(const State& st) { return opt.observation ? opt.observation->map(psf(st)) : psf(st); }

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
    const RealStack psf_stack = psf(st);
    const RealStack m = opt.observation ? opt.observation->map(psf_stack) : psf_stack;
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
    const bool any_adjoint = std::any_of(ps.begin(), ps.end(), [](const Param& q) { return !by_differences(q.kind); });
    if (!any_adjoint) {  // z, d and the registration only: no adjoint to take
      t.vjp_s += since(t0);
      if (fd_distances) fd_distance_gradient(theta, meas, grad);
      return loss;
    }
    // With an observation, the residual is carried back through it onto the PSF stack first.
    const RealStack g_psf = opt.observation ? opt.observation->vjp(psf_stack, r) : RealStack();
    const RealStack& g_stack = opt.observation ? g_psf : r;
    const Map2D g_h = registration
                          ? sim->psf_native_vjp(integrate_registered_adjoint(g_stack, native, sim->config(), st.sx, st.sy))
                          : sim->psf_sensor_vjp(g_stack);
    ++t.vjps;
    // Through the relief's whole-pixel move (a move of the map: its transpose).
    const std::vector<double> g_h0 = offset ? move_relief_adjoint(base_config(st), g_h, st.dx_m, st.dy_m).data : g_h.data;
    std::vector<double> g_lev(design.levels_m.size(), 0.0), g_mask(masks0.size(), 0.0), g_ox, g_oy;
    double g_scale = 0;
    if (scale_fitted) {
      const std::vector<double> base = unscaled(st);
      for (std::size_t i = 0; i < n * n; ++i) g_scale += g_h0[i] * base[i];
    }
    if (overlay) {
      // H0 = scale (top - sum_m e_m a_m): dL/dtop, dL/de_m, and each overlay through d a_m / d o.
      double top = 0, g_top = 0;
      const std::vector<double> e = fit_detail::mask_etch_depths(mask_set, st.lev, st.masks, top);
      std::vector<double> g_unscaled(n * n), g_e;
      for (std::size_t i = 0; i < n * n; ++i) g_unscaled[i] = st.scale * g_h0[i];
      fit_detail::mask_relief_vjp(mask_set, e, st.ox_m, st.oy_m, cfg.pitch_m, g_unscaled, g_top, g_e, g_ox, g_oy);
      fit_detail::mask_etch_depths_vjp(mask_set, g_top, g_e, g_lev, g_mask);
    } else if (quantized) {
      for (std::size_t i = 0; i < n * n; ++i) g_lev[std::size_t(level_of[i])] += st.scale * g_h0[i];
      for (std::size_t j = 0; j < g_mask.size(); ++j)
        for (std::size_t l = 0; l < g_lev.size(); ++l)
          if (l & (std::size_t(1) << j)) g_mask[j] += g_lev[l];
    }
    for (std::size_t k = 0; k < ps.size(); ++k) {
      switch (ps[k].kind) {
        case Kind::Level: grad[k] = g_lev[std::size_t(ps[k].index)]; break;
        case Kind::Mask: grad[k] = g_mask[std::size_t(ps[k].index)]; break;
        case Kind::OX: grad[k] = g_ox[std::size_t(ps[k].index)]; break;
        case Kind::OY: grad[k] = g_oy[std::size_t(ps[k].index)]; break;
        case Kind::Scale: grad[k] = g_scale; break;
        case Kind::DX:
        case Kind::DY:
        case Kind::SX:
        case Kind::SY:
        case Kind::Z:
        case Kind::D: break;
      }
    }
    t.vjp_s += since(t0);
    if (fd_distances) fd_distance_gradient(theta, meas, grad);
    return loss;
  }

  // The z, d, offset and registration entries of dL/dtheta by central differences of the loss.
  void fd_distance_gradient(const std::vector<double>& theta, const RealStack& meas, std::vector<double>& grad) {
    const auto t0 = std::chrono::steady_clock::now();
    for (std::size_t k = 0; k < ps.size(); ++k) {
      if (!by_differences(ps[k].kind)) continue;
      const double h = step(k, theta);
      std::vector<double> a = theta, b = theta;
      a[k] += h;
      b[k] -= h;
      try {
        grad[k] = (half_sq(model(state(a)), meas) - half_sq(model(state(b)), meas)) / (2 * h);
      } catch (const InputError&) {  // one side outside the valid range: the other, from theta
        double f0 = half_sq(model(state(theta)), meas), fs = 0, sgn = 1;
        try {
          fs = half_sq(model(state(a)), meas);
        } catch (const InputError&) {
          fs = half_sq(model(state(b)), meas);
          sgn = -1;
        }
        grad[k] = sgn * (fs - f0) / h;
      }
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
      case Kind::OX:
      case Kind::OY: return opt.fd_px * cfg.pitch_m;
    }
    return 0;
  }

  // J (m x p) by differences of the model (fit_jacobian.cpp): z, d and the registration last (they
  // rebuild the simulator or re-integrate), so the simulator of theta serves every other column;
  // with the model at theta given (at_theta), the adjoint's parameters and the offset one-sided
  // from it (one evaluation each: what a Levenberg-Marquardt step needs of J^T J); an overlay's
  // differences inside its pixel cell, the offset's on its side of a half-pixel switch.
  Eigen::MatrixXd jacobian(const std::vector<double>& theta, const RealStack* at_theta = nullptr) {
    const auto t0 = std::chrono::steady_clock::now();
    std::vector<fit_detail::JacobianColumn> cols(ps.size());
    for (std::size_t k = 0; k < ps.size(); ++k) {
      fit_detail::JacobianColumn& c = cols[k];
      const Kind kind = ps[k].kind;
      c.step = step(k, theta);
      c.late = by_differences(kind);
      c.one_sided = !by_differences(kind) || kind == Kind::DX || kind == Kind::DY;
      c.pitch_m = cfg.pitch_m;
      if (kind == Kind::OX || kind == Kind::OY) c.scheme = fit_detail::JacobianColumn::Scheme::Overlay;
      if (kind == Kind::DX || kind == Kind::DY) {
        c.scheme = fit_detail::JacobianColumn::Scheme::Offset;
        c.axis_m = kind == Kind::DX ? cfg.aperture_offset_x_m : cfg.aperture_offset_y_m;
      }
    }
    const Eigen::MatrixXd j = fit_detail::difference_jacobian([&](const std::vector<double>& x) { return model(state(x)); }, theta, cols,
                                                              cfg.bands * s * s, at_theta);
    t.jacobian_s += since(t0);
    return j;
  }
};

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
  if (m.quantized) m.level_of = fit_detail::design_level_map(design);
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
  if (has("scale")) {
    m.scale_fitted = true;
    add(Kind::Scale, 0, "scale", "", 1.0);
  }
  if (has("z")) add(Kind::Z, 0, "z", "m", cfg.sensor_distance_m);
  if (has("d")) add(Kind::D, 0, "d", "m", cfg.scene_distance_m);
  if (has("offset")) {
    m.offset = true;
    add(Kind::DX, 0, "dx", "m", 0.0);
    add(Kind::DY, 0, "dy", "m", 0.0);
  }
  if (has("shift")) {
    m.registration = true;
    add(Kind::SX, 0, "sx", "px", 0.0);
    add(Kind::SY, 0, "sy", "px", 0.0);
  }
  if (has("overlay")) {
    m.overlay = true;
    m.mask_set = fit_mask_set(design, m.use_masks);
    const std::vector<std::string> o = overlay_parameter_names(design, parameters);  // ox2, oy2, ox3, ...: masks 1 .. K-1
    for (std::size_t k = 1; k < m.mask_set.open.size(); ++k) {
      add(Kind::OX, int(k), o.at(2 * (k - 1)), "m", 0.0);
      add(Kind::OY, int(k), o.at(2 * (k - 1) + 1), "m", 0.0);
    }
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
bool AsBuiltModel::adjoint_parameter(std::size_t i) const { return !Impl::by_differences(impl_->ps.at(i).kind); }
RealStack AsBuiltModel::evaluate(const std::vector<double>& theta) {
  const auto t0 = std::chrono::steady_clock::now();
  RealStack r = impl_->model(impl_->state(theta));
  impl_->t.psf_s += since(t0);
  return r;
}
RealStack AsBuiltModel::evaluate_psf(const std::vector<double>& theta) {
  const auto t0 = std::chrono::steady_clock::now();
  RealStack r = impl_->psf(impl_->state(theta));
  impl_->t.psf_s += since(t0);
  return r;
}
RealStack AsBuiltModel::observe(const RealStack& psf) const {
  return impl_->opt.observation ? impl_->opt.observation->map(psf) : psf;
}
bool AsBuiltModel::observed() const { return impl_->opt.observation != nullptr; }
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
Eigen::MatrixXd AsBuiltModel::jacobian(const std::vector<double>& theta, const RealStack* at_theta) {
  return impl_->jacobian(theta, at_theta);
}

}  // namespace qdo
