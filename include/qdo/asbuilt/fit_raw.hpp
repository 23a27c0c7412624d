// The as-built fit in the measurement domain (REFERENCE §8): the parameters of fit.hpp fitted to
// the raw point-source frames themselves (calibrate.hpp: reduce_psf_frames), through the sensor
// model, each pixel weighted by its Poisson-Gaussian variance; no calibrated stack, and so none
// of its bias (signal mask, colour combination, background), enters.
//
// The model of band b's raw window (S x S sensor pixels, dark subtracted, full-scale units):
//   D_b(p) ~ a_b * G_b(p) * PSF_b(p; theta)
// PSF_b: the fit's sensor-grid PSF at theta (fit.hpp's model, each band summing to 1 over the
// window); G_b(p) = the response of pixel p's mosaic colour at band b over the band's largest
// colour, times the flat field of the white frames when given (their colour gains and pixel
// response; 1 without); a_b: the band's source power (the monochromator's power times the
// exposure, unknown), solved in closed form at every evaluation:
//   a_b = sum_p w G PSF D / sum_p w G^2 PSF^2,   w = 1 / V_b(p),
// over the usable pixels (reduce_psf_frames: not hot, colour measured, an exposure left, not
// clipped). The residual of a usable pixel is (a_b G PSF - D) / sqrt(V); the fit minimises half
// their squared sum (chi^2 / 2) by fit_as_built's Levenberg-Marquardt, starts, Jacobian and
// jackknife (FitObservation). With a_b at its optimum the derivative of the loss in a_b is 0, so
// the adjoint gradient with respect to PSF_b(p) is a_b G w^(1/2) times the residual (variable
// projection); the Jacobian's columns are differences of the projected residuals (a_b re-solved).
// sigma: Cov = s^2 (J^T J)^-1 with J the Jacobian of the weighted residuals and s^2 = chi^2 /
// (usable pixels - bands - p), the reduced chi^2: 1 when the variances and the model hold, and
// the curvature sigma then scaled by it otherwise.
// Re-weighting: the first pass weighs each pixel's shot noise by the signal its 8 neighbours
// predict (reduce_psf_frames), which on a speckled PSF is off where the PSF changes from pixel to
// pixel. Each further pass (reweight_passes) takes the shot noise of the signal the fitted model
// expects, a_b G PSF(theta) (never the pixel's own value), and fits again from the last pass's
// values (their lateral start alone, no new scan).
#pragma once
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/asbuilt/fit.hpp"
#include "qdo/physics/calibrate.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

// The observation of the raw windows for fit_as_built, and its target. target: bands x S x S,
// w^(1/2) D (0 where not usable); the map of a PSF stack (bands x S x S): w^(1/2) a_b G PSF.
// An InputError when the windows are not cfg.bands x S x S.
FitObservation raw_fit_observation(const SystemConfig& cfg, const RawPsfWindows& windows, RealStack& target);

// a_b of a PSF stack (bands x S x S) against the windows: one per band, full-scale units per unit
// of the band's unit-sum PSF at the band's largest colour (the sweep's amplitude).
std::vector<double> raw_source_powers(const RawPsfWindows& windows, const RealStack& psf);

struct RawFitResult {
  // fit_as_built's result, with model_psf and design_psf the PSF stacks (bands x S x S, unit sum)
  // at the fit and at the design, and residual_rel_* per band |w^(1/2) (a G PSF - D)| / |w^(1/2) D|;
  // source_power: a_b at the fit.
  FitResult fit;
  // bands x S x S: each usable pixel's own estimate of the fitted band's PSF, D / (a_b G); 0 where
  // not usable (the report's "measured" panel).
  RealStack measured_psf;
  std::size_t usable_pixels = 0;  // the residuals (pixels of all bands) that are data
};

// The windows weighed again: each usable pixel's variance read_variance + shot_per_signal x
// max(expected, 0), expected (bands x S x S, full-scale units) the signal a model predicts there.
RawPsfWindows reweight_raw_windows(const RawPsfWindows& windows, const RealStack& expected);

// The fit of fit.hpp on the raw windows (opt: fit.hpp's; opt.observation is set here). Every
// check of fit_as_built first (parameters, design), then the device work.
// reweight_passes: passes after the first with the model's shot noise, in [0, 5].
RawFitResult fit_as_built_raw(Runtime& rt, const SystemConfig& cfg, Precision p, const Design& design,
                              const RawPsfWindows& windows, const FitOptions& opt, int reweight_passes = 1);

}  // namespace qdo
