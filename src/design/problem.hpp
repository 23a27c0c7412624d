// The problem of a design run (private to src/design): what make_problem prepares before any
// writing, the objective of each step, and the initial parameters.
#pragma once
#include <Eigen/Dense>

#include <memory>
#include <vector>

#include "qdo/design/design.hpp"
#include "qdo/design/design_run_options.hpp"
#include "qdo/design/joint.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/runtime/types.hpp"
#include "qdo/decode/wiener.hpp"
#include "qdo/decode/wiener_device.hpp"

namespace qdo {

struct Problem {
  Eigen::MatrixXd srf;
  wiener::SpectralPrior prior;
  std::vector<RealStack> scenes;
  RealStack target;                         // psf-target: point 0's target (a one-point run's)
  std::vector<PsfObjective> point_targets;  // psf-target: the objective of matching point p's target, p < P
  JointData joint;  // objective network: the scenes the network trains and validates on
};

// The run's problem: the sensor response, and per objective the training scenes (S x S patches at
// the sensor pitch, S = the sensor PSF size, so prior, PSF and scenes share one grid) with their
// prior (wiener objectives; network: the network's scenes, qdo/design/joint.hpp, and their patches'
// prior), or the target's sensor PSF stack (psf-target). Reads data before any writing.
// psf-target over object points: the target at point p is the target design's PSF at point p
// (point_config(cfg, p)); lens:NM is then the lens focused for that point's distance, so the
// targets are a sharp focus at every depth (and the chief-ray image off the axis).
Problem make_problem(Runtime& rt, const DesignRunOptions& o);

// The Wiener expected-error objective on the device for this run, when it asks for one
// (objective wiener, wiener_on device) and the device has float64 for the C x C solve; null
// otherwise (the CPU objective then runs).
std::unique_ptr<wiener::DeviceObjective> make_device_objective(Runtime& rt, const DesignRunOptions& o, const Problem& pb);

// The step's objective (the training batch of wiener-mse and wiener-mae drawn from the seed and
// `step`); `dev` (from make_device_objective) evaluates the wiener objective when given.
PsfObjective make_objective(const DesignRunOptions& o, const Problem& pb, long step, wiener::DeviceObjective* dev = nullptr);
// The same for each object point of the run (Designer::range_step): psf-target matches point p's
// target; the Wiener objectives are the same at every point (the step's batch shared).
PointObjective make_point_objective(const DesignRunOptions& o, const Problem& pb, long step, wiener::DeviceObjective* dev = nullptr);

// initial_params (the run's initial design): qdo/design/design_run_options.hpp.

}  // namespace qdo
