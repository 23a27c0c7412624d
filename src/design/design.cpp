#include "qdo/design/design.hpp"

#include <algorithm>
#include <cmath>
#include <random>

#include "qdo/physics/adjoint.hpp"
#include "qdo/runtime/error.hpp"

namespace qdo {

DesignMode design_mode_from_string(const std::string& s) {
  if (s == "full") return DesignMode::Full;
  if (s == "do") return DesignMode::DO;
  if (s == "qdo") return DesignMode::QDO;
  if (s == "ste") return DesignMode::STE;
  if (s == "qdo+a" || s == "qdoa") return DesignMode::QDOA;
  if (s == "qdo+m" || s == "qdom") return DesignMode::QDOM;
  reject("mode", s, "one of full, do, qdo, ste, qdo+a, qdo+m");
}

std::string to_string(DesignMode m) {
  switch (m) {
    case DesignMode::Full: return "full";
    case DesignMode::DO: return "do";
    case DesignMode::QDO: return "qdo";
    case DesignMode::STE: return "ste";
    case DesignMode::QDOA: return "qdo+a";
    case DesignMode::QDOM: return "qdo+m";
  }
  return "?";
}

PsfPath psf_path_from_string(const std::string& s) {
  if (s == "auto") return PsfPath::Auto;
  if (s == "2d") return PsfPath::TwoD;
  if (s == "radial") return PsfPath::Radial;
  reject("psf_path", s, "one of auto, 2d, radial");
}

std::string to_string(PsfPath p) {
  switch (p) {
    case PsfPath::Auto: return "auto";
    case PsfPath::TwoD: return "2d";
    case PsfPath::Radial: return "radial";
  }
  return "?";
}

AqDomain aq_domain_from_string(const std::string& s, const std::string& argument) {
  if (s == "pixels") return AqDomain::Pixels;
  if (s == "parameters" || s == "rings") return AqDomain::Parameters;
  reject(argument, s, "pixels (the N x N map) or parameters (the parameterization's values: the ring profile of a radial design, the release's)");
}

std::string to_string(AqDomain d) { return d == AqDomain::Pixels ? "pixels" : "parameters"; }

double parameter_deviation_m(const std::vector<double>& params_m, double h_max_m, const Quantizer& q) {
  if (params_m.empty()) return 0;
  double sum = 0;
  for (double p : params_m) sum += std::fabs(h_max_m * q.quantize(p / h_max_m) - p);
  return sum / double(params_m.size());
}

int mask_count(int levels) {
  int k = 0;
  while ((1 << k) < levels && k < 30) ++k;
  if (levels < 2 || (1 << k) != levels)
    reject("levels", levels, "a power of two >= 2 for qdo+m (k binary-coded masks make 2^k levels)");
  return k;
}

std::vector<double> uniform_mask_depths(const Quantizer& q) {
  const int k = mask_count(q.levels);
  const double denom = q.placement == Placement::Inclusive ? double(q.levels - 1) : double(q.levels);
  std::vector<double> d(static_cast<std::size_t>(k));
  for (int j = 0; j < k; ++j) d[static_cast<std::size_t>(j)] = double(1 << j) / denom;
  return d;
}

std::vector<double> subset_sum_levels(const std::vector<double>& depths, int levels) {
  const int k = mask_count(levels);
  if (depths.size() != static_cast<std::size_t>(k))
    reject("mask depths", depths.size(), "k = " + to_str(k) + " values for " + to_str(levels) + " levels");
  std::vector<double> u(static_cast<std::size_t>(levels), 0.0);
  for (int l = 0; l < levels; ++l)
    for (int j = 0; j < k; ++j)
      if (l & (1 << j)) u[static_cast<std::size_t>(l)] += depths[static_cast<std::size_t>(j)];
  return u;
}

void Adam::step(std::vector<double>& params, const std::vector<double>& grad, double lr_now, double lo, double hi) {
  if (grad.size() != params.size()) reject("grad.size()", grad.size(), "the parameter count " + to_str(params.size()));
  if (m.size() != params.size()) {
    m.assign(params.size(), 0.0);
    v.assign(params.size(), 0.0);
  }
  ++t;
  const double c1 = 1.0 - std::pow(beta1, double(t)), c2 = 1.0 - std::pow(beta2, double(t));
  const double lr_t = lr_now * std::sqrt(c2) / c1;  // keras_form
  for (std::size_t i = 0; i < params.size(); ++i) {
    m[i] = beta1 * m[i] + (1 - beta1) * grad[i];
    v[i] = beta2 * v[i] + (1 - beta2) * grad[i] * grad[i];
    if (keras_form) params[i] -= lr_t * m[i] / (std::sqrt(v[i]) + epsilon);
    else params[i] -= lr_now * (m[i] / c1) / (std::sqrt(v[i] / c2) + epsilon);
    params[i] = std::min(hi, std::max(lo, params[i]));
  }
}

void DesignOptions::validate() const {
  Quantizer q = quantizer;
  q.offsets.clear();
  q.validate();
  if (steps_per_epoch < 1) reject("steps_per_epoch", steps_per_epoch, ">= 1");
  if (points_per_step < 1) reject("points_per_step", points_per_step, ">= 1 (object points per step, at most their number)");
  if (!(t0_epochs >= 0) || !std::isfinite(t0_epochs)) reject("t0_epochs", t0_epochs, "finite and >= 0");
  if (!(t1_epochs > t0_epochs) || !std::isfinite(t1_epochs))
    reject("t1_epochs", t1_epochs, "finite and > t0_epochs = " + to_str(t0_epochs));
  for (const auto& [name, v] : {std::pair<const char*, double>{"lr_optics", lr_optics}, {"lr_offsets", lr_offsets},
                                {"beta_aq", beta_aq}, {"height_noise_m", height_noise_m}})
    if (!(v >= 0) || !std::isfinite(v)) reject(name, v, "finite and >= 0");
  if (!(lr_decay_per_epoch > 0 && lr_decay_per_epoch <= 1))
    reject("lr_decay_per_epoch", lr_decay_per_epoch, "a factor per decay period in (0, 1] (1: no decay)");
  if (!(lr_decay_steps >= 0) || !std::isfinite(lr_decay_steps))
    reject("lr_decay_steps", lr_decay_steps, "finite and >= 0 (steps per decay period; 0: one epoch)");
  if (!(adam_epsilon > 0) || !std::isfinite(adam_epsilon) || adam_epsilon > 1) reject("adam_epsilon", adam_epsilon, "in (0, 1]");
  if (mode == DesignMode::QDOM) mask_count(quantizer.levels);
  if (psf_path == PsfPath::Radial && parameterization != Parameterization::Radial)
    reject("psf_path", "radial", "auto or 2d unless the parameterization is radial (the radial engine needs ring heights)");
  radial.validate();
}

double DesignOptions::lr_factor(long step) const {
  const double period = lr_decay_steps > 0 ? lr_decay_steps : double(steps_per_epoch);
  const double x = double(step) / period;
  return std::pow(lr_decay_per_epoch, lr_staircase ? std::floor(x) : x);
}

Designer::Designer(HeightMapPsfSource& sim, const DesignOptions& opt) : Designer(std::vector<HeightMapPsfSource*>{&sim}, opt) {}

namespace {
HeightMapPsfSource& first_source(const std::vector<HeightMapPsfSource*>& points) {
  if (points.empty() || !points[0]) reject("object points", 0, "at least one PSF source (one per object point)");
  return *points[0];
}
}  // namespace

Designer::Designer(const std::vector<HeightMapPsfSource*>& points, const DesignOptions& opt)
    : srcs_(points), sim_(first_source(points)), opt_(opt), h_max_(sim_.config().h_max_m()), radial_(points.size()) {
  opt_.quantizer.offsets.clear();
  opt_.validate();
  const SystemConfig& c0 = sim_.config();
  for (std::size_t p = 0; p < srcs_.size(); ++p) {
    if (!srcs_[p]) reject("object point " + to_str(p), "(no source)", "a PSF source");
    const SystemConfig& c = srcs_[p]->config();
    if (srcs_.size() > 1 && c.point_count() != 1)
      reject("object point " + to_str(p), to_str(c.point_count()) + " points",
             "a source of one object point (point_config(cfg, p)) in a design over several points");
    if (c.n != c0.n || c.pitch_m != c0.pitch_m || c.bands != c0.bands || c.sensor_size_px() != c0.sensor_size_px() ||
        srcs_[p]->precision() != sim_.precision() || c.h_max_m() != h_max_)
      reject("object point " + to_str(p), srcs_[p]->describe(),
             "a source on the first one's grid, bands, sensor, material and precision (one DOE seen from every point)");
    for (const ObjectPoint& pt : c.points()) all_on_axis_ = all_on_axis_ && pt.on_axis();
  }
  if (opt_.points_per_step > srcs_.size())
    reject("points_per_step", opt_.points_per_step, "1 to the number of object points P = " + to_str(srcs_.size()));
  if (opt_.psf_path == PsfPath::Radial && !all_on_axis_)
    reject("psf_path", "radial", "auto or 2d when an object point is off the axis (the radial engine serves on-axis points)");
}

bool Designer::uses_radial() const {
  return opt_.psf_path == PsfPath::Radial ||
         (opt_.psf_path == PsfPath::Auto && opt_.parameterization == Parameterization::Radial && all_on_axis_);
}

RadialEngine* Designer::radial_engine(std::size_t point) {
  if (!uses_radial()) return nullptr;
  if (point >= srcs_.size()) reject("object point", point, "an index below " + to_str(srcs_.size()));
  std::unique_ptr<RadialEngine>& e = radial_[point];
  if (!e) e = std::make_unique<RadialEngine>(srcs_[point]->runtime(), srcs_[point]->config(), srcs_[point]->precision(), opt_.radial);
  return e.get();
}

std::vector<std::size_t> Designer::step_points(long step) const {
  const std::size_t n = srcs_.size(), k = std::max<std::size_t>(1, opt_.points_per_step);
  std::vector<std::size_t> all(n);
  for (std::size_t i = 0; i < n; ++i) all[i] = i;
  if (k >= n) return all;
  // A partial Fisher-Yates shuffle with its own stream (seed, step): not the height-noise draws.
  std::mt19937_64 rng((opt_.seed + 0x5DEECE66Dull) * 0xBF58476D1CE4E5B9ull + std::uint64_t(step));
  for (std::size_t i = 0; i < k; ++i) {
    const std::size_t j = i + std::size_t(rng() % std::uint64_t(n - i));
    std::swap(all[i], all[j]);
  }
  all.resize(k);
  std::sort(all.begin(), all.end());
  return all;
}

std::size_t Designer::level_parameter_count() const {
  return opt_.mode == DesignMode::QDOM ? static_cast<std::size_t>(mask_count(opt_.quantizer.levels))
                                       : static_cast<std::size_t>(opt_.quantizer.levels);
}

DesignState Designer::initial_state(const std::vector<double>& params_m) const {
  if (params_m.size() != parameter_count(opt_.parameterization, sim_.config().n))
    reject("params_m.size()", params_m.size(), "exactly " + to_str(parameter_count(opt_.parameterization, sim_.config().n)));
  DesignState s;
  for (double p : params_m) s.w.push_back(std::min(1.0, std::max(-1.0, 2.0 * p / h_max_ - 1.0)));
  if (opt_.mode == DesignMode::QDOM) s.offsets = uniform_mask_depths(opt_.quantizer);
  else s.offsets.assign(static_cast<std::size_t>(opt_.quantizer.levels), 0.0);
  s.adam_w.lr = opt_.lr_optics;
  s.adam_a.lr = opt_.lr_offsets;
  return s;
}

double Designer::alpha_at(long step) const {
  const double spe = double(opt_.steps_per_epoch);
  return alpha_schedule(double(step), opt_.t0_epochs * spe, opt_.t1_epochs * spe);
}

std::vector<double> Designer::params_m(const DesignState& s) const {
  std::vector<double> p;
  p.reserve(s.w.size());
  for (double w : s.w) p.push_back(h_max_ * (w + 1.0) / 2.0);
  return p;
}

Quantizer Designer::quantizer(const DesignState& s) const {
  Quantizer q = opt_.quantizer;
  if (opt_.mode == DesignMode::QDOA) q.offsets = s.offsets;
  if (opt_.mode == DesignMode::QDOM) q.level_table = subset_sum_levels(s.offsets, q.levels);
  return q;
}

Map2D Designer::training_heights(const DesignState& s) const {
  const Map2D hf = expand_parameters(opt_.parameterization, params_m(s), sim_.config().n, h_max_);
  switch (opt_.mode) {
    case DesignMode::Full:
    case DesignMode::DO: return hf;
    case DesignMode::STE: return quantize_heights(hf, h_max_, quantizer(s), 1.0);
    case DesignMode::QDO:
    case DesignMode::QDOA:
    case DesignMode::QDOM: return quantize_heights(hf, h_max_, quantizer(s), alpha_at(s.step));
  }
  return hf;
}

Map2D Designer::fabricated_heights(const DesignState& s) const {
  const Map2D hf = expand_parameters(opt_.parameterization, params_m(s), sim_.config().n, h_max_);
  if (opt_.mode == DesignMode::Full) return hf;
  return quantize_heights(hf, h_max_, quantizer(s), 1.0);
}

Designer::Gradient Designer::gradient(const DesignState& s, const PsfObjective& objective,
                                      const DevicePsfObjective* device) {
  const PointObjective one = [&objective](std::size_t, const RealStack& psf, RealStack& grad) { return objective(psf, grad); };
  return range_gradient(s, {0}, one, device);
}

Designer::Gradient Designer::range_gradient(const DesignState& s, const std::vector<std::size_t>& points,
                                            const PointObjective& objective, const DevicePsfObjective* device) {
  if (points.empty()) reject("points", "(none)", "at least one object point per step");
  for (std::size_t i = 0; i < points.size(); ++i) {
    if (points[i] >= srcs_.size()) reject("points", points[i], "indices below the number of object points " + to_str(srcs_.size()));
    for (std::size_t j = 0; j < i; ++j)
      if (points[j] == points[i]) reject("points", points[i], "distinct indices (each point once per step)");
  }
  const SystemConfig& cfg = sim_.config();
  const std::size_t n = cfg.n;
  const std::vector<double> p = params_m(s);
  const Map2D hf = expand_parameters(opt_.parameterization, p, n, h_max_);
  const Quantizer q = quantizer(s);
  const bool quantized = opt_.mode == DesignMode::QDO || opt_.mode == DesignMode::QDOA || opt_.mode == DesignMode::STE ||
                         opt_.mode == DesignMode::QDOM;
  const bool qdom = opt_.mode == DesignMode::QDOM;
  const double alpha = opt_.mode == DesignMode::STE ? 1.0 : quantized ? alpha_at(s.step) : 0.0;
  Map2D h = training_heights(s);
  std::mt19937_64 rng(opt_.seed * 0x9E3779B97F4A7C15ull + std::uint64_t(s.step));
  std::uniform_real_distribution<double> noise(-opt_.height_noise_m, opt_.height_noise_m);
  const bool radial = uses_radial();
  StepReport rep;
  rep.step = s.step;
  rep.alpha = alpha;
  rep.points = points;
  // The step's heights, drawn once and seen from every point: the ring heights of the same
  // blended/quantized map on the radial path (noise drawn per ring: it cannot be per pixel), the
  // pixel map on the 2-D path.
  std::vector<double> rings;
  if (radial) {
    rings = ring_heights_of_map(h);
    if (opt_.height_noise_m > 0)
      for (double& v : rings) v = std::min(2 * h_max_, std::max(0.0, v + noise(rng)));
  } else if (opt_.height_noise_m > 0) {
    for (double& v : h.data) v = std::min(2 * h_max_, std::max(0.0, v + noise(rng)));
  }
  const double share = 1.0 / double(points.size());
  Map2D gh;
  double loss_sum = 0;
  for (std::size_t point : points) {
    HeightMapPsfSource& src = *srcs_[point];
    RadialEngine* engine = radial ? radial_engine(point) : nullptr;
    if (engine) {
      engine->compute_psf(rings);
    } else {
      src.set_heights(h);
      src.compute_psf();
    }
    double loss = 0;
    Map2D gp;
    if (device) {
      // PSF, objective and the PSF adjoint on the device: only the heights go up and dL/dH comes back.
      const cl::Buffer& psf_dev = engine ? engine->psf_sensor_buffer() : src.psf_sensor_buffer();
      const std::size_t bytes = cfg.bands * cfg.sensor_size_px() * cfg.sensor_size_px() *
                                (sim_.precision() == Precision::F64 ? sizeof(double) : sizeof(float));
      if (!device_grad_() || device_grad_.getInfo<CL_MEM_SIZE>() != bytes)
        device_grad_ = cl::Buffer(sim_.runtime().context(), CL_MEM_READ_WRITE, bytes);
      loss = (*device)(psf_dev, device_grad_);
      gp = engine ? spread_ring_gradient(engine->psf_sensor_vjp(device_grad_), n) : src.psf_sensor_vjp(device_grad_);
    } else {
      const RealStack psf = engine ? engine->psf_sensor() : src.psf_sensor();
      RealStack g(psf.planes, psf.rows, psf.cols);
      loss = objective(point, psf, g);
      // dL/dH on the N x N map; on the radial path the per-ring gradient spread evenly over each ring's
      // pixels, so the per-pixel quantizer adjoint and expand_parameters_vjp below give it back per ring.
      gp = engine ? spread_ring_gradient(engine->psf_sensor_vjp(g), n) : src.psf_sensor_vjp(g);
    }
    rep.point_loss.push_back(loss);
    if (points.size() == 1) {  // one point: its loss and gradient as they are (bit-identical to a one-point design)
      loss_sum = loss;
      gh = std::move(gp);
      continue;
    }
    loss_sum += loss;
    if (gh.data.empty()) gh = Map2D(gp.rows, gp.cols, 0.0);
    for (std::size_t i = 0; i < gh.data.size(); ++i) gh.data[i] += share * gp.data[i];
  }
  rep.loss = points.size() == 1 ? loss_sum : loss_sum / double(points.size());

  Map2D ghf = gh;
  std::vector<double> ga(static_cast<std::size_t>(q.levels), 0.0);
  std::vector<double> gu(static_cast<std::size_t>(q.levels), 0.0);  // dL/du_l (qdo+m)
  if (quantized) {
    const auto qv = ref::quantize_vjp(hf, h_max_, q, alpha, gh, opt_.mode == DesignMode::STE);
    ghf = qv.g_full;
    ga = qv.g_offsets;
    gu = qv.g_levels;
  }
  // L_aq = mean((F(Q(u)) - u)^2) on normalised heights u = H_f / h_max, Q(u)'s index held constant
  // (round has no gradient), over the N x N pixels or the parameterization's values (aq_domain).
  // Its gradient reaches u and the level values: the offsets (qdo+a, the pinned one excepted) or
  // the subset-sum levels (qdo+m).
  std::vector<double> gp_aq;  // dL/dparams (metres) of the parameters domain
  if ((opt_.mode == DesignMode::QDOA || qdom) && opt_.beta_aq > 0) {
    const bool on_params = opt_.aq_domain == AqDomain::Parameters;
    const std::vector<double>& samples = on_params ? p : hf.data;
    if (on_params) gp_aq.assign(p.size(), 0.0);
    const double denom = q.placement == Placement::Inclusive ? double(q.levels - 1) : double(q.levels);
    const double np = double(samples.size());
    const int pinned = q.pinned_level();
    double laq = 0;
    for (std::size_t i = 0; i < samples.size(); ++i) {
      const double u = samples[i] / h_max_;
      const int l = q.level_index(u);
      const double r = q.level_value(l) - u;
      laq += r * r / np;
      (on_params ? gp_aq[i] : ghf.data[i]) += opt_.beta_aq * (-2.0 * r / np) / h_max_;
      if (qdom) gu[static_cast<std::size_t>(l)] += opt_.beta_aq * 2.0 * r / np;
      else if (l != pinned) ga[static_cast<std::size_t>(l)] += opt_.beta_aq * 2.0 * r / np * 0.5 / denom;
    }
    rep.loss_aq = laq;
  }
  if (opt_.mode != DesignMode::Full) rep.deviation_m = parameter_deviation_m(p, h_max_, q);
  std::vector<double> gw = ref::expand_parameters_vjp(opt_.parameterization, p, n, h_max_, ghf);
  for (std::size_t i = 0; i < gp_aq.size(); ++i) gw[i] += gp_aq[i];
  for (double& v : gw) v *= h_max_ / 2.0;
  if (qdom) {  // chain dL/du_l to the mask depths: du_l/ddelta_j = bit j of l
    const std::size_t k = static_cast<std::size_t>(mask_count(q.levels));
    ga.assign(k, 0.0);
    for (std::size_t l = 0; l < gu.size(); ++l)
      for (std::size_t j = 0; j < k; ++j)
        if (l & (std::size_t(1) << j)) ga[j] += gu[l];
  } else {
    ga[static_cast<std::size_t>(q.pinned_level())] = 0.0;  // the pinned level is fixed
  }
  rep.loss += opt_.mode == DesignMode::QDOA || qdom ? opt_.beta_aq * rep.loss_aq : 0.0;
  return {rep, gw, ga};
}

StepReport Designer::step(DesignState& s, const PsfObjective& objective, const DevicePsfObjective* device) {
  const PointObjective one = [&objective](std::size_t, const RealStack& psf, RealStack& grad) { return objective(psf, grad); };
  return update(s, range_gradient(s, {0}, one, device));
}

StepReport Designer::range_step(DesignState& s, const PointObjective& objective, const DevicePsfObjective* device) {
  return update(s, range_gradient(s, step_points(s.step), objective, device));
}

StepReport Designer::update(DesignState& s, Gradient g) {
  const double factor = opt_.lr_factor(s.step);
  g.report.lr = opt_.lr_optics * factor;
  for (Adam* a : {&s.adam_w, &s.adam_a}) {  // the run's form (not stored in checkpoints)
    a->epsilon = opt_.adam_epsilon;
    a->keras_form = opt_.adam_keras_form;
  }
  s.adam_w.step(s.w, g.g_w, g.report.lr, -1.0, 1.0);
  if (opt_.mode == DesignMode::QDOA) {
    const double lim = opt_.quantizer.levels == 2 ? 0.2 : 1.0;
    s.adam_a.step(s.offsets, g.g_offsets, opt_.lr_offsets * factor, -lim, lim);
    s.offsets[static_cast<std::size_t>(opt_.quantizer.pinned_level())] = 0.0;
    // With the top pinned, level 0 stays at or above H = 0 (a relief below the base plate has no
    // height in qdo; the release's deepest etch may pass h_max by up to 0.5 / (L - 1) instead).
    if (opt_.quantizer.pin_top) s.offsets[0] = std::max(0.0, s.offsets[0]);
  }
  if (opt_.mode == DesignMode::QDOM) {
    // Depths stay >= 0 and their sum (the deepest etch) within h_max: scale down when above.
    s.adam_a.step(s.offsets, g.g_offsets, opt_.lr_offsets * factor, 0.0, 1.0);
    double sum = 0;
    for (double v : s.offsets) sum += v;
    if (sum > 1.0)
      for (double& v : s.offsets) v /= sum;
  }
  ++s.step;
  return g.report;
}

PsfObjective psf_target_objective(const RealStack& target) {
  return [target](const RealStack& psf, RealStack& grad) {
    if (psf.size() != target.size())
      reject("target PSF", to_str(target.planes) + " x " + to_str(target.rows) + " x " + to_str(target.cols),
             "the sensor PSF shape " + to_str(psf.planes) + " x " + to_str(psf.rows) + " x " + to_str(psf.cols));
    const double scale = double(psf.rows * psf.cols) * double(psf.rows * psf.cols) / double(psf.size());
    double loss = 0;
    grad = RealStack(psf.planes, psf.rows, psf.cols);
    for (std::size_t i = 0; i < psf.size(); ++i) {
      const double d = psf.data[i] - target.data[i];
      loss += scale * d * d;
      grad.data[i] = 2.0 * scale * d;
    }
    return loss;
  };
}

}  // namespace qdo
