// Host-side design optimisation: Adam over the DOE parameters (and the adaptive level offsets),
// with the quantization modes of REFERENCE §2, driven by any differentiable objective of the
// sensor PSF stack. The PSF comes from a HeightMapPsfSource (psf_source.hpp: the Simulator's 2-D
// path) or, for radial designs, the radial engine; gradients from the source's psf_sensor_vjp
// (OpenCL adjoint) and the host adjoints of the quantizer and the parameterization (qdo/physics/adjoint.hpp).
#pragma once
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "qdo/physics/doe.hpp"
#include "qdo/physics/radial.hpp"
#include "qdo/physics/psf_source.hpp"

namespace qdo {

// full: optimise and evaluate in full precision. do: optimise in full precision; quantize only
// at evaluation (the paper's conventional deep optics). qdo: alpha-blended quantization with the
// cubic schedule. ste: hard quantization with the straight-through estimator. qdo+a: blend plus
// trainable per-level offsets and the adaptive-quantization loss beta * L_aq. qdo+m (mask-
// constrained, beyond the paper): blend plus level values that are subset sums of k = log2(L)
// trainable etch depths, u_l = sum_j bit_j(l) * delta_j (normalised, delta_j >= 0, sum <= 1),
// so the L = 2^k levels come from k binary-coded masks; initialised uniform (delta_j =
// 2^j / (L - 1) inclusive, 2^j / L wrapped), trained through the quantizer's level-value
// gradient (dL/ddelta_j = sum over levels l with bit j set of dL/du_l) with beta * L_aq as qdo+a.
enum class DesignMode { Full, DO, QDO, STE, QDOA, QDOM };
DesignMode design_mode_from_string(const std::string& s);
std::string to_string(DesignMode m);

// Which PSF engine Designer::gradient uses. twod: the 2-D source (the Simulator's FFT path) on the N x N pixel map.
// radial: the rotationally symmetric engine (qdo/physics/radial.hpp) on the N/2 ring heights, no 2-D FFT;
// only for Parameterization::Radial and on-axis object points. auto: radial when the
// parameterization is radial and every object point of the design is on the axis, else 2-D.
// The radial path feeds the engine the per-ring values of the same blended/quantized N x N map and
// spreads its per-ring gradient back over the ring's pixels, so the quantizer, blend, L_aq and
// parameterization adjoints are exactly those of the 2-D path. Per-pixel height noise cannot be
// radial: with height_noise_m > 0 the radial path draws one uniform value per ring (same generator
// and seed). Evaluation and export (fabricated_heights, design_run's final report) stay on the 2-D
// pixel path.
enum class PsfPath { Auto, TwoD, Radial };
PsfPath psf_path_from_string(const std::string& s);  // "auto", "2d", "radial"
std::string to_string(PsfPath p);

// Adam (Kingma & Ba) with bias correction; one instance per parameter group.
struct Adam {
  double lr = 0.01, beta1 = 0.9, beta2 = 0.999, epsilon = 1e-8;
  // The form of epsilon: false, the paper's params -= lr * mhat / (sqrt(vhat) + eps); true, TF/Keras'
  // ("epsilon hat"): params -= lr * sqrt(1 - beta2^t) / (1 - beta1^t) * m / (sqrt(v) + eps).
  bool keras_form = false;
  std::vector<double> m, v;
  long t = 0;
  // One update at learning rate lr_now (the form above), then clip to [lo, hi].
  void step(std::vector<double>& params, const std::vector<double>& grad, double lr_now, double lo, double hi);
};

// What L_aq (qdo+a, qdo+m) averages over: the N x N pixel map (each ring weighted by its pixel
// count, the corners outside the aperture included) or the parameterization's own values (the
// release: its 1-D ring profile of N/2 values for a radial design, each ring once; the quarter
// for quad; the pixels for 2d).
enum class AqDomain { Pixels, Parameters };
AqDomain aq_domain_from_string(const std::string& s, const std::string& argument = "aq_domain");
std::string to_string(AqDomain d);

struct DesignOptions {
  DesignMode mode = DesignMode::QDOA;
  Parameterization parameterization = Parameterization::Radial;
  Quantizer quantizer;                 // levels, placement, pin_top (offsets are trained in qdo+a)
  std::size_t steps_per_epoch = 10;
  double t0_epochs = 5, t1_epochs = 40;  // alpha schedule (REFERENCE §2)
  double lr_optics = 0.01;             // on the normalised weights w in [-1, 1]
  double lr_offsets = 0.01;
  // Learning-rate decay: lr(t) = lr * lr_decay_per_epoch^(t / D), D = lr_decay_steps steps (0: one
  // epoch, steps_per_epoch), the exponent floored when lr_staircase (qdo's per-epoch decay) or not
  // (continuous: the release's ExponentialDecay(decay_steps=500, decay_rate=0.8)). The factor is
  // per D steps; the name is kept for config.json. Both Adams (and a network decoder's) follow it.
  double lr_decay_per_epoch = 0.8;
  double lr_decay_steps = 0;
  bool lr_staircase = true;
  double adam_epsilon = 1e-8;          // Adam's epsilon (Keras' default 1e-7 in the release)
  bool adam_keras_form = false;        // Adam::keras_form
  AqDomain aq_domain = AqDomain::Pixels;
  double beta_aq = 0.01;               // weight of L_aq (qdo+a)
  double height_noise_m = 0;           // uniform fabrication noise +-height_noise_m per step (0: off)
  std::uint64_t seed = 0;
  PsfPath psf_path = PsfPath::Auto;    // PSF engine of gradient() (see PsfPath)
  RadialOptions radial;                // sampling of the radial engine (qdo/physics/radial.hpp)
  // Designs over a range of object points (Designer's list of PSF sources, one per point): how many
  // of the P points each step trains on, 1 .. P (P: all of them every step). Drawn without
  // replacement from a generator seeded with (seed, step) (Designer::step_points), so a resumed
  // run draws what an uninterrupted one does. A one-point design takes 1.
  std::size_t points_per_step = 1;
  // InputError naming the field, the value and what is allowed: levels and placement, steps
  // >= 1, 0 <= t0 < t1, points_per_step >= 1, learning rates, beta and height noise finite and >= 0, decay in (0, 1],
  // qdo+m levels a power of two, the radial PSF path only for radial designs.
  void validate() const;
  // The learning-rate factor at step t (lr_decay_per_epoch^(t / D), floored when lr_staircase).
  double lr_factor(long step) const;
};

// Optimisation state: everything a checkpoint needs to resume bit-identically.
struct DesignState {
  std::vector<double> w;               // normalised weights in [-1, 1], H = h_max (w + 1) / 2
  std::vector<double> offsets;         // L adaptive offsets (qdo+a), a_0 = 0; in qdo+m the k
                                       // normalised mask depths delta_j (heights / h_max)
  Adam adam_w, adam_a;
  long step = 0;
  // Network runs (DesignRunOptions::decoder a network): the network's state at this step, a file
  // in the run folder (path relative to it) and the FNV-1a 64 checksum of its bytes. Empty otherwise.
  std::string network_file, network_checksum;
};

// qdo+m helpers. Number of binary-coded masks for L levels (L must be a power of two >= 2;
// InputError otherwise), the uniform initial depths for a quantizer's placement, and the L level
// values u_l = sum_j bit_j(l) depths[j] (normalised).
int mask_count(int levels);
std::vector<double> uniform_mask_depths(const Quantizer& q);
std::vector<double> subset_sum_levels(const std::vector<double>& depths, int levels);

// Objective: given the sensor PSF stack (bands x S x S), return the loss and write dL/dpsf.
using PsfObjective = std::function<double(const RealStack& psf_sensor, RealStack& grad)>;
// The same on the device: psf_sensor is PsfSource::psf_sensor_buffer() (bands x S x S reals of the
// source's precision, row-major); dL/dpsf is written into grad (same shape, layout and
// precision). Returns the loss. Keeps the PSF and its gradient off the host (wiener::DeviceObjective).
using DevicePsfObjective = std::function<double(const cl::Buffer& psf_sensor, cl::Buffer& grad)>;

struct StepReport {
  long step = 0;
  double loss = 0, loss_aq = 0, alpha = 0, lr = 0;
  // The quantization deviation of the step's state: mean |H_q - H_f| in metres over the
  // parameterization's values (the release's ring profile for a radial design), H_q hard-quantized
  // with the step's levels. 0 in modes full and do.
  double deviation_m = 0;
  // The object points the step trained on (indices into the Designer's sources, ascending) and the
  // objective at each (without beta L_aq): loss = mean(point_loss) + beta L_aq.
  std::vector<std::size_t> points;
  std::vector<double> point_loss;
};

// The objective of a design over object points: point p's sensor PSF stack (bands x S x S) ->
// the loss, dL/dpsf written into grad (same shape). Called once per sampled point and step.
using PointObjective = std::function<double(std::size_t point, const RealStack& psf_sensor, RealStack& grad)>;

class Designer {
 public:
  // `psf` (the 2-D path; its runtime, configuration and precision also build the radial engine) must
  // outlive the designer.
  Designer(HeightMapPsfSource& psf, const DesignOptions& opt);
  // A design over a range of object points: one source per point (each one
  // point's configuration, e.g. point_config(cfg, p): same grid, bands and sensor, one object
  // point; each yields bands planes), all driven by the one height map. Each must outlive the
  // designer. InputError when the list is empty, the sources' grids, bands or sensor sizes differ,
  // a source holds several points, points_per_step is not in 1 .. P, or psf_path is radial while
  // a point is off the axis.
  Designer(const std::vector<HeightMapPsfSource*>& points, const DesignOptions& opt);
  std::size_t point_count() const { return srcs_.size(); }
  // The points step `step` trains on: all of them (0 .. P-1) when points_per_step = P, else
  // points_per_step distinct indices drawn from a generator seeded with (seed, step), ascending.
  std::vector<std::size_t> step_points(long step) const;
  // A fresh state: w from an initial height map's parameters (metres), offsets zero.
  DesignState initial_state(const std::vector<double>& params_m) const;
  // Loss and gradients at the state (forward on the device, adjoint on the device, host adjoints
  // of the quantizer and parameterization): dL/dw (size of w) and dL/da (L offsets).
  struct Gradient {
    StepReport report;
    std::vector<double> g_w, g_offsets;
  };
  // With `device` given, it is evaluated on the PSF where it lies, on the 2-D and the radial path
  // (no host copy of the PSF or its gradient; the same numbers as `objective` would give on the
  // downloaded PSF when both compute the same loss), and `objective` is not called.
  // On a design over points: point 0's (the first source's).
  Gradient gradient(const DesignState& s, const PsfObjective& objective, const DevicePsfObjective* device = nullptr);
  // The range objective at the state: the mean over `points` (indices of the sources, distinct) of
  // the objective on each point's PSF stack, its gradient the mean of the per-point gradients
  // (plus beta L_aq and its gradient once, as in gradient()). The heights, the blend and the height
  // noise draw are the step's, shared by every point. `device`, when given, evaluates every
  // point's stack on the device and `objective` is not called. With points = {0} on one source
  // it is gradient() exactly.
  Gradient range_gradient(const DesignState& s, const std::vector<std::size_t>& points, const PointObjective& objective,
                          const DevicePsfObjective* device = nullptr);
  // One optimiser step (gradient, then Adam on each group); returns the loss before the update.
  StepReport step(DesignState& s, const PsfObjective& objective, const DevicePsfObjective* device = nullptr);
  // One optimiser step on the points step_points(s.step) (range_gradient, then Adam): on one
  // source, step() exactly.
  StepReport range_step(DesignState& s, const PointObjective& objective, const DevicePsfObjective* device = nullptr);
  // The heights the current state means at step s (blended, noise-free) and the design as it
  // would be fabricated (hard-quantized unless mode is full).
  Map2D training_heights(const DesignState& s) const;
  Map2D fabricated_heights(const DesignState& s) const;
  std::vector<double> params_m(const DesignState& s) const;   // H_f parameters in metres
  Quantizer quantizer(const DesignState& s) const;            // with the trained offsets (qdo+a) or
                                                              // the subset-sum level table (qdo+m)
  // Size of DesignState::offsets: L (qdo+a and the others), k = log2(L) (qdo+m).
  std::size_t level_parameter_count() const;
  double alpha_at(long step) const;
  // Whether gradient() runs the radial engine (psf_path radial, or auto with a radial
  // parameterization and every point on the axis).
  bool uses_radial() const;
  // Point p's radial engine (built on first use, on that source's runtime, configuration and
  // precision); nullptr on the 2-D path.
  RadialEngine* radial_engine(std::size_t point = 0);

 private:
  StepReport update(DesignState& s, Gradient g);  // Adam on each group with the step's gradient; ++s.step
  std::vector<HeightMapPsfSource*> srcs_;
  HeightMapPsfSource& sim_;  // srcs_[0]: the grid, runtime and precision of every point
  DesignOptions opt_;
  double h_max_;
  bool all_on_axis_ = true;
  std::vector<std::unique_ptr<RadialEngine>> radial_;  // one per point, built on first use
  cl::Buffer device_grad_;  // dL/dpsf_sensor of the device objective (bands x S x S reals)
};

// Quantization deviation over the parameterization's values (Table 2 as the release logs it): the
// mean over params (metres) of |h_max Q(p / h_max) - p| with the quantizer's levels (offsets
// included). For a radial design the N/2 rings, each once.
double parameter_deviation_m(const std::vector<double>& params_m, double h_max_m, const Quantizer& q);

// Loss of matching a target PSF stack: mean over bands x S x S of (psf - target)^2, scaled by
// S^2 so it is O(1) for PSFs that sum to 1.
PsfObjective psf_target_objective(const RealStack& target);

}  // namespace qdo
