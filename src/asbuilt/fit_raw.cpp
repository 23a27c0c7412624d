// The as-built fit on the raw frames (fit_raw.hpp): the observation of a PSF stack through the
// sensor model with the source powers solved in closed form, and the fit that uses it.
#include "qdo/asbuilt/fit_raw.hpp"

#include <algorithm>
#include <cmath>
#include <memory>
#include <string>

#include "qdo/runtime/error.hpp"

namespace qdo {

namespace {

// What the observation's closures share: per band and pixel (bands x S x S, row-major) the
// weight's square root w^(1/2) = 1 / sqrt(V) (0 where not usable), the gain G and the signal D.
struct RawTerms {
  std::size_t bands = 0, plane = 0;
  std::vector<double> sqrt_w, gain, signal;

  // a_b of a stack: sum w G P D / sum w G^2 P^2 over the band's usable pixels (0 for a band the
  // stack leaves dark there).
  std::vector<double> powers(const RealStack& psf) const {
    std::vector<double> a(bands, 0.0);
    for (std::size_t b = 0; b < bands; ++b) {
      double num = 0, den = 0;
      for (std::size_t i = b * plane; i < (b + 1) * plane; ++i) {
        const double gp = sqrt_w[i] * gain[i] * psf.data[i];  // w^(1/2) G P
        num += gp * sqrt_w[i] * signal[i];
        den += gp * gp;
      }
      a[b] = den > 0 ? num / den : 0.0;
    }
    return a;
  }

  void check(const RealStack& psf) const {
    if (psf.planes != bands || psf.plane_size() != plane)
      throw Error("raw fit observation: a stack of " + shape(psf) + ", expected " + std::to_string(bands) +
                  " planes of " + std::to_string(plane));
  }

  // w^(1/2) a_b G x for a stack x (bands x S x S), with a_b those of psf.
  RealStack weighted(const RealStack& psf, const RealStack& x) const {
    check(psf);
    check(x);
    const std::vector<double> a = powers(psf);
    RealStack out(x.planes, x.rows, x.cols, 0.0);
    for (std::size_t b = 0; b < bands; ++b)
      for (std::size_t i = b * plane; i < (b + 1) * plane; ++i) out.data[i] = sqrt_w[i] * a[b] * gain[i] * x.data[i];
    return out;
  }
};

// The terms of windows (bands x S x S each); an InputError when they are not that shape.
std::shared_ptr<RawTerms> make_terms(const RawPsfWindows& w, std::size_t bands, std::size_t s) {
  for (const RealStack* st : {&w.signal, &w.variance, &w.gain})
    if (st->planes != bands || st->rows != s || st->cols != s)
      throw InputError("the raw frames' windows are " + shape(*st) + "; the configuration needs bands x S x S = " +
                       shape(bands, s, s) + " (reduce_psf_frames with this configuration)");
  auto t = std::make_shared<RawTerms>();
  t->bands = bands;
  t->plane = s * s;
  const std::size_t m = bands * s * s;
  t->sqrt_w.assign(m, 0.0);
  t->gain.assign(m, 0.0);
  t->signal.assign(m, 0.0);
  for (std::size_t i = 0; i < m; ++i) {
    const double v = w.variance.data[i], g = w.gain.data[i], d = w.signal.data[i];
    if (!(g > 0) || !(v > 0) || !std::isfinite(v) || !std::isfinite(d)) continue;  // not usable: no residual
    t->sqrt_w[i] = 1 / std::sqrt(v);
    t->gain[i] = g;
    t->signal[i] = d;
  }
  return t;
}

std::size_t usable_of(const RawTerms& t) {
  std::size_t n = 0;
  for (double v : t.sqrt_w) n += v > 0 ? 1 : 0;
  return n;
}

}  // namespace

FitObservation raw_fit_observation(const SystemConfig& cfg, const RawPsfWindows& windows, RealStack& target) {
  const std::shared_ptr<const RawTerms> t = make_terms(windows, cfg.bands, cfg.sensor_size_px());
  const std::size_t s = cfg.sensor_size_px();
  target = RealStack(cfg.bands, s, s, 0.0);
  for (std::size_t i = 0; i < target.data.size(); ++i) target.data[i] = t->sqrt_w[i] * t->signal[i];
  FitObservation obs;
  obs.map = [t](const RealStack& psf) { return t->weighted(psf, psf); };
  // At the optimal a_b, d loss / d a_b = 0: the gradient is that at fixed a_b.
  obs.vjp = [t](const RealStack& psf, const RealStack& residual) { return t->weighted(psf, residual); };
  obs.residuals = usable_of(*t);
  obs.nuisance = cfg.bands;  // one a_b per band
  obs.noise_units = true;    // each residual over its Poisson-Gaussian sd
  return obs;
}

std::vector<double> raw_source_powers(const RawPsfWindows& windows, const RealStack& psf) {
  const std::shared_ptr<const RawTerms> t = make_terms(windows, windows.signal.planes, windows.signal.rows);
  t->check(psf);
  return t->powers(psf);
}

RawPsfWindows reweight_raw_windows(const RawPsfWindows& windows, const RealStack& expected) {
  const RawPsfWindows& w = windows;
  for (const RealStack* st : {&w.read_variance, &w.shot_per_signal, &expected})
    if (st->planes != w.variance.planes || st->plane_size() != w.variance.plane_size())
      throw InputError("reweight_raw_windows: a stack of " + shape(*st) + "; the windows are " + shape(w.variance));
  RawPsfWindows out = windows;
  for (std::size_t i = 0; i < out.variance.data.size(); ++i)
    if (out.gain.data[i] > 0 && out.variance.data[i] > 0)
      out.variance.data[i] = w.read_variance.data[i] + w.shot_per_signal.data[i] * std::max(expected.data[i], 0.0);
  return out;
}

RawFitResult fit_as_built_raw(Runtime& rt, const SystemConfig& cfg, Precision p, const Design& design,
                              const RawPsfWindows& windows_in, const FitOptions& opt_in, int reweight_passes) {
  FitOptions opt = opt_in;
  if (opt.parameters.empty()) opt.parameters = default_fit_parameters(design);
  check_fit_parameters(cfg, design, opt.parameters);
  if (reweight_passes < 0 || reweight_passes > 5)
    throw InputError("reweight_passes " + std::to_string(reweight_passes) + ": an integer in [0, 5]");
  RawPsfWindows windows = windows_in;
  RealStack target;
  opt.observation = std::make_shared<const FitObservation>(raw_fit_observation(cfg, windows, target));
  RawFitResult out;
  out.usable_pixels = opt.observation->residuals;
  if (out.usable_pixels == 0)
    throw InputError("the raw frames' windows hold no usable pixel (every pixel hot, clipped or of no response)");
  out.fit = fit_as_built(rt, cfg, p, design, target, opt);
  std::vector<double> chi2{out.fit.residual_sigma * out.fit.residual_sigma};
  const bool shot = std::any_of(windows.shot_per_signal.data.begin(), windows.shot_per_signal.data.end(),
                                [](double v) { return v > 0; });
  for (int pass = 0; pass < reweight_passes && shot; ++pass) {
    // The signal the fitted model expects at each pixel, a_b G PSF(theta), for its shot noise.
    const RealStack& psf = out.fit.model_psf;  // fit_as_built's: the observation w^(1/2) a_b G PSF
    RealStack expected(psf.planes, psf.rows, psf.cols, 0.0);
    for (std::size_t i = 0; i < psf.data.size(); ++i) {
      const double v = windows.variance.data[i];
      if (windows.gain.data[i] > 0 && v > 0) expected.data[i] = psf.data[i] * std::sqrt(v);
    }
    windows = reweight_raw_windows(windows, expected);
    FitOptions again = opt;
    again.start.clear();
    for (const FitValue& v : out.fit.values)
      if (v.name != "aperture") again.start.emplace_back(v.name, v.value);
    again.lateral_starts = 1;
    again.refine_starts = 1;
    again.observation = std::make_shared<const FitObservation>(raw_fit_observation(cfg, windows, target));
    if (opt.progress)
      opt.progress("re-weighting (pass " + std::to_string(pass + 2) + "): shot noise of the fitted model's signal, reduced chi^2 " +
                   "of the last pass " + std::to_string(chi2.back()));
    out.fit = fit_as_built(rt, cfg, p, design, target, again);
    chi2.push_back(out.fit.residual_sigma * out.fit.residual_sigma);
  }
  FitResult& r = out.fit;
  r.chi2_reduced_passes = chi2;
  // The PSF stacks themselves (the fit's model_psf and design_psf are their observations): the
  // model again, without the observation, at the fitted and the design values.
  FitOptions plain = opt;
  plain.observation.reset();
  AsBuiltModel m(rt, cfg, p, design, opt.parameters, plain);
  const std::size_t np = m.parameter_names().size();
  std::vector<double> theta(np);
  for (std::size_t k = 0; k < np; ++k) theta[k] = r.values[k].value;
  r.design_psf = m.evaluate(m.design_values());
  m.set_aperture_radius(r.as_built_config.aperture_radius());
  r.model_psf = m.evaluate(theta);
  r.source_power = raw_source_powers(windows, r.model_psf);
  // Each usable pixel's own estimate of the fitted PSF.
  const std::size_t s = cfg.sensor_size_px(), plane = s * s;
  out.measured_psf = RealStack(cfg.bands, s, s, 0.0);
  for (std::size_t b = 0; b < cfg.bands; ++b)
    for (std::size_t i = b * plane; i < (b + 1) * plane; ++i) {
      const double g = windows.gain.data[i], a = r.source_power[b];
      if (g > 0 && windows.variance.data[i] > 0 && a != 0) out.measured_psf.data[i] = windows.signal.data[i] / (a * g);
    }
  return out;
}

}  // namespace qdo
