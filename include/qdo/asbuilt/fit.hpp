// The as-built DOE (REFERENCE §8): from a design and a measured sensor-grid PSF
// stack, fit the parameters a fab and an assembly get wrong, by Levenberg-Marquardt on the
// least-squares misfit of the stacks, with Gauss-Newton uncertainties.
//
// The model of the measured stack (bands x S x S, each band summing to 1):
//   H0(i)  = scale * lev[l(i)]            quantized design: l(i) = the design level nearest pixel
//                                         i's height (Design::levels_m); lev = the level depths,
//                                         or the subset sums of k mask depths (QDO+M)
//          = scale * h(i)                 a design that is not quantized
//   H, cfg' = move_relief(cfg with z, d; H0, dx, dy)   with the offset fitted (optics.hpp): the
//                                         relief moved by (dx, dy) metres against the aperture and
//                                         the sensor exactly: whole pixels in the map (zero relief
//                                         brought in, every pixel on its level), the rest (within
//                                         half a pixel) as the optical axis -- the aperture, the
//                                         point source, the sensor window -- moved the other way
//                                         (aperture_offset_m), the aperture area-weighted
//                                         (aperture_edge "area") at every offset, so the model is
//                                         continuous in it -- but for the light of one DOE column at
//                                         the sensor window's edge, which the window, centred on the
//                                         axis, finds beyond the native N x N crop on one side of
//                                         each half-pixel switch (suite fit: 0.4 % on a lens filling
//                                         its window); without the offset H = H0, cfg' = cfg
//   model  = Simulator(cfg').psf_sensor(H)   (bands x S x S); with the registration
//            (sx, sy) fitted, integrate_registered(psf_native(H), sx, sy) instead: the native
//            stack integrated by a pixel grid displaced by (sx, sy) sensor px (the grid's
//            sub-pixel position against the axis, not a resampling of the sampled stack)
// Loss L = 1/2 sum (model - measured)^2 over bands x S x S (equal weights: every pixel's residual
// is treated as one noise draw of one variance, estimated from the fit).
//
// Parameter names (FitOptions::parameters):
//   levels    the L - 1 level heights of levels 1 .. L-1 (metres); level 0 stays at its design
//             value: adding one constant to every level is a piston (the same PSF), so only
//             L - 1 are identifiable; a level no pixel takes is held too. Needs a quantized
//             design (Design::levels_m).
//   masks     the k = log2(L) mask depths of a QDO+M design (levels = subset sums, level 0 = 0).
//   scale     one factor on every height (not with levels or masks: exactly degenerate with them).
//   z         the DOE-sensor distance (metres).
//   d         the object distance (metres; a finite scene_distance_m). Nearly degenerate with z
//             (REFERENCE §7: 1/z' = 1/z + 1/d): the default fits z and holds d.
//   offset    dx, dy: the relief's lateral offset against the aperture (metres).
//   shift     sx, sy: registration of the measured stack (sensor pixels; the sensor grid's
//             position against the optical axis, REFERENCE §8). Nearly degenerate with offset:
//             the offset moves the image by as much, and only the rim the aperture cuts from the
//             relief tells them apart (none when the aperture filled the window); the default set
//             fits offset and holds shift, and a fit of both reports the pair as degenerate when
//             their correlation exceeds 0.95.
//   aperture  the aperture radius (metres). The aperture is a set of DOE samples (config.hpp:
//             aperture_inside_px2), piecewise constant in the radius (area-weighted and continuous
//             with the offset fitted; the same walk serves): it is fitted by a walk of
//             the loss over radii in half-pixel steps, downhill until the loss rises (the others
//             held at their fit, then fitted again when the radius moved; 3 rounds at most), its
//             value and sigma from the parabola through the minimum and its neighbours; it takes
//             no part in the correlation. The first walk runs at the start values, before the rest.
//   overlay   oxM, oyM (metres) for every lithography mask M after the first (fit_mask_set: the
//             masks a fab makes the design with; the first defines the alignment marks, and the
//             relief's offset moves them all): each mask's own lateral misplacement. The relief is
//             then H0(i) = scale * (top - sum_m e_m a_m(i)), a_m the area of pixel i that mask m's
//             opening, moved by (oxM, oyM), covers (shift_bilinear of its 0/1 map: exact for an
//             opening made of whole pixels) and e_m its etch depth (from the levels or masks fitted,
//             else the design's): at zero overlay every pixel is on its level, and a misplaced mask
//             leaves edge pixels between two levels, area-averaged as qdo fabricate renders them.
//             Gradient through the adjoint (d a_m / d o piecewise constant: shift_bilinear_derivative,
//             the right derivative on a whole DOE pixel). The relief is linear in an overlay between
//             whole DOE pixels and kinks at each, so the Jacobian's differences stay inside the
//             current cell; a step stops at the next whole pixel in its direction; on one (the
//             start, 0, is one) the step takes the right cell's column, or the left's when it goes
//             left, or holds the overlay where the step with either goes back across (the minimum
//             on the kink). The loss has a minimum in the cells on both sides of a kink, and the
//             first steps choose a side while the rest is still far off: after the fit each overlay
//             is tried mirrored about its nearest whole pixel and fitted again (2 x
//             refine_iterations), kept where the loss is lower (two rounds). Needs a quantized
//             design with 2 masks or more.
// Start: the design values, except the lateral ones: shift (when fitted, else offset, divided by
// the magnification 1 + z/d and in metres) starts at the centroid difference of the measured and
// design stacks (several lateral starts by default: FitOptions::lateral_starts).
// Gradients: the height parameters (levels, masks, scale) through the simulator's adjoint
// (psf_sensor_vjp, or psf_native_vjp after integrate_registered_adjoint) chained through the
// whole-pixel move's transpose (move_relief_adjoint); z, d and the offset by central differences
// in double (they change the configuration: the offset moves the optical axis), the registration
// by central differences of the integration (no new PSF). The Gauss-Newton matrix
// J^T J of each step uses Jacobian columns by one-sided differences of the model from the current
// stack (1 evaluation per parameter; z, d, the offset and the registration central), the
// uncertainties at the end central ones.
// Uncertainties: Cov = s^2 (J^T J)^-1, s^2 = 2 L / (m - p) (m residuals, p parameters); and a
// jackknife over groups of contiguous bands (FitOptions::jackknife_groups), linearised at the fit:
// for each group the Gauss-Newton step of the fit without it, from the Jacobian and residuals at
// the fit (no new model evaluation); sigma_jk^2 = (G - 1) / G sum_g (step_g - mean)^2.
// Another data term (FitObservation, FitOptions::observation; fit_raw.hpp's raw frames): the fit
// compares obs.map(model) with the measured argument instead of the model stack itself, the
// adjoint taking obs.vjp, the Jacobian the differences of the observed images; s^2 counts
// obs.residuals - obs.nuisance residuals.
#pragma once
#include <Eigen/Dense>

#include <cstddef>
#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/data/io.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

// Every name fit_as_built accepts, in the order of the parameter vector.
std::vector<std::string> fit_parameter_names();

// The lithography masks of a quantized design as the overlay parameter models them (fab.hpp's
// schemes, made from the design's level map: each pixel on the level nearest its height):
// binary (with masks fitted, a QDO+M design): mask j (j = 0 .. log2(L) - 1) opens the pixels whose
// level has bit j at 0 and etches mask j's depth; nested (otherwise): over the U used levels sorted
// by design height, highest first, mask m (m = 1 .. U - 1, index m - 1) opens every pixel at the
// m-th or a lower one and etches the step between the (m-1)-th and the m-th. Names "mask 1" ..,
// as qdo fabricate's.
struct FitMaskSet {
  bool binary = false;
  std::size_t n = 0;
  std::vector<std::vector<std::uint8_t>> open;  // K maps, each N x N row-major, 1 where the mask is open (etched)
  std::vector<std::size_t> order;               // nested: the used levels' indices, highest first (K + 1 of them)
};
FitMaskSet fit_mask_set(const Design& design, bool binary);
// Whether a fitted value's name is a mask's overlay ("ox2", "oy3", ...).
bool is_overlay_parameter(const std::string& name);
// The overlay's parameter names of a design and a parameter set: "ox2", "oy2", .. for masks 2 .. K
// (empty without "overlay").
std::vector<std::string> overlay_parameter_names(const Design& design, const std::vector<std::string>& parameters);
// The default set for a design: levels,z,offset when it is quantized, else scale,z,offset.
std::vector<std::string> default_fit_parameters(const Design& design);

// What a measurement records of a model PSF stack, when the fit compares that instead of the
// stack itself (fit_raw.hpp: the raw frames through the sensor model). The loss is then
// 1/2 |map(model) - measured|^2, measured being fit_as_built's stack argument (the target).
struct FitObservation {
  // The observed image of a model PSF stack: bands x S x S -> bands x S x S (the target's layout).
  std::function<RealStack(const RealStack& psf)> map;
  // d loss / d psf at psf given residual = map(psf) - target (both bands x S x S).
  std::function<RealStack(const RealStack& psf, const RealStack& residual)> vjp;
  std::size_t residuals = 0;  // the target's entries that are data (the rest are 0 in map and target)
  // Unknowns solved inside map (not in the fit's vector): s^2 = 2 L / (residuals - nuisance - p).
  std::size_t nuisance = 0;
  // The residuals are in noise units (each divided by its noise sd): s^2 is then the reduced chi^2,
  // and one over kReducedChi2Reliable marks sigma unreliable (FitResult::sigma_reliable).
  bool noise_units = false;
};
// The largest reduced chi^2 of a fit in noise units whose sigma still reads as an error: the
// variances are themselves estimates (the darks' spread, the expected signal's shot noise), good to
// a few per cent (1.00 .. 1.02 on cameras inside the model, EXPERIMENTS.md); above it the model
// misses something larger than the noise, and sigma scaled by the reduced chi^2 does not bound the
// bias that leaves.
constexpr double kReducedChi2Reliable = 1.05;

struct FitOptions {
  std::vector<std::string> parameters;  // names above; empty: default_fit_parameters
  // Start values by the fitted names ("level1", "z", "dx", "sx", ... in their units: metres or
  // sensor px) in place of the design's (and the centroid start); a name not fitted is an
  // InputError. For a start from an earlier fit, or a known assembly. With lateral_starts > 1 a
  // lateral start given here is one candidate of the grid.
  std::vector<std::pair<std::string, double>> start;
  // Lateral starts tried (when offset or shift is fitted). 0 (automatic): for the offset, scans
  // of dx (dy held) then of dy (dx held), twice, a quarter of a DOE pixel apart over
  // +-(|centroid| + 1.5 DOE px) (+-2 DOE px with shift fitted too): a safeguard against basins a
  // fraction of a pixel apart (the bilinear blend of heights qdo once moved reliefs with had them;
  // with the exact move the centroid start alone found the truth on a trained DOE's speckled PSF,
  // suite fit); for the shift alone a grid half a sensor px apart over +-(|centroid| + 1) px,
  // at most 15 x 15. The mirrors of the lowest start are evaluated too. 1 = the centroid
  // difference only. K > 1 = K x K starts over +-(|centroid| + lateral_span_px) sensor px (with
  // shift fitted too, +-lateral_span_px / 2). The offset's starts are in metres (divided by the
  // magnification); with shift fitted too, each offset start takes its best whole-pixel
  // registration within +-3 px of the centroid's.
  int lateral_starts = 0;
  double lateral_span_px = 1.0;
  // With a grid or scans: short fits (refine_iterations each) from refine_starts starts in
  // different basins (at least a quarter of a DOE pixel apart for the offset, a sensor px for the
  // shift): the lowest, its three mirrors (mirror minima the loss at the start does not tell
  // apart), then
  // the next lowest; the fit goes on from the one that ends lowest, its iterations counted in the
  // budget. refine_starts < 2: the lowest start alone.
  int refine_starts = 4;
  int refine_iterations = 3;
  int max_iterations = 30;             // LM iterations, >= 1
  double tolerance = 1e-7;             // stop when the relative loss decrease of an accepted step is below this
  // Groups of contiguous bands for the jackknife sigma (FitValue::sigma_jackknife); < 2: none.
  int jackknife_groups = 8;
  double step_sigmas = 1e-3;           // ... or when an accepted step moves no parameter by more than this many sigmas
  double lambda0 = 1e-3;               // initial Marquardt damping (relative to diag(J^T J))
  // Central-difference steps: z and d relative (x value), heights metres, offsets and shifts pixels.
  double fd_rel_distance = 2e-4;
  double fd_height_m = 1e-9;
  double fd_px = 1e-3;
  // A progress line per iteration ("" lines skipped); stderr-free: the caller prints.
  std::function<void(const std::string&)> progress;
  // The data term: none (the measured stack itself), or an observation of the model (fit_raw.hpp).
  std::shared_ptr<const FitObservation> observation;
};

// One fitted scalar. For levels and masks, name is "level1" .., "mask0" ..; offsets "dx", "dy";
// shifts "sx", "sy".
struct FitValue {
  std::string name, unit;              // unit: "m", "px" or "" (scale)
  double design = 0;                   // the design (nominal) value
  double value = 0;                    // fitted
  double sigma = 0;                    // 1-sigma from the Gauss-Newton curvature
  std::string gradient;                // "adjoint", "central differences" or "scan"
  // 1-sigma from the jackknife over band groups (FitOptions::jackknife_groups; NaN when not
  // computed, e.g. the aperture): the spread of the fit when each group of bands is left out.
  double sigma_jackknife = std::numeric_limits<double>::quiet_NaN();
};

struct FitTimes {
  double psf_s = 0;       // model evaluations (PSF chain + shifts) outside the Jacobian
  double vjp_s = 0;       // adjoint gradients
  double jacobian_s = 0;  // Jacobian columns by central differences
  double solve_s = 0;     // normal equations and covariance
  double scan_s = 0;      // aperture scan
  long psf_evaluations = 0, vjps = 0, simulators_built = 0;
};

struct FitResult {
  std::vector<FitValue> values;        // the continuous parameters (Jacobian order), then aperture
  Eigen::MatrixXd correlation;         // p x p over the continuous parameters
  // Pairs (i, j) with |correlation| > 0.95: what the data cannot separate.
  std::vector<std::pair<std::size_t, std::size_t>> degenerate;
  double condition = 0;                // of J^T J scaled to unit diagonal
  double loss_design = 0, loss_initial = 0, loss_final = 0;
  double residual_sigma = 0;           // s, per pixel
  int jackknife_groups = 0;            // the band groups of sigma_jackknife (0: not computed)
  // Whether the curvature sigma can be read as an error: the jackknife was computed and no
  // physical parameter's jackknife sigma is over 3 x its curvature sigma (the band groups disagree
  // by more than it allows: the model misses something that differs between wavelengths; the
  // registration sx, sy is a nuisance, not checked), or the fit left no residual (relative
  // residual below 1e-6 in every band); and, for residuals in noise units (raw frames), the
  // reduced chi^2 at most kReducedChi2Reliable.
  bool sigma_reliable = false;
  std::string sigma_unreliable_because;  // why not, in words ("" when reliable or no jackknife)
  std::vector<double> residual_rel_design, residual_rel_fit;  // per band: |model - measured| / |measured|
  std::vector<double> loss_history;    // loss after each iteration (index 0 = start)
  int iterations = 0;
  bool converged = false;
  std::vector<std::size_t> unused_levels;  // levels held because no pixel takes them
  // The start of shift (or, without it, offset): the mean centroid difference measured - design,
  // sensor px (columns, rows), over each band's pixels above 10 % of its peak.
  std::pair<double, double> centroid_shift_px{0, 0};
  Design as_built;                     // the fitted relief (levels_m = the fitted levels when quantized)
  SystemConfig as_built_config;        // z, d, aperture as fitted
  RealStack model_psf, design_psf;     // bands x S x S: the fitted model, and the design's nominal stack
  // With raw frames (fit_raw.hpp): each band's source power a_b at the fit; empty for a stack.
  std::vector<double> source_power;
  // With raw frames: the reduced chi^2 of each weighting pass (fit_raw.hpp: the first with the
  // neighbours' shot noise, then the fitted model's); the last is residual_sigma^2. Empty for a stack.
  std::vector<double> chi2_reduced_passes;
  FitTimes times;
};

// The measured stack must be cfg.bands x S x S, finite (values may be negative: noise). The
// design must match cfg's grid (N, pitch). InputError before any device work for an unknown or
// repeated parameter name, levels/masks without a quantized design, masks on a level table that is
// not subset sums of log2(L) depths with level 0 = 0, scale with levels or masks, d with an
// object at infinity, an empty set.
// The same checks alone (no device): for commands that check every input before they start.
void check_fit_parameters(const SystemConfig& cfg, const Design& design, const std::vector<std::string>& parameters);
FitResult fit_as_built(Runtime& rt, const SystemConfig& cfg, Precision p, const Design& design, const RealStack& measured,
                       const FitOptions& opt);

// The pieces, for tests and the bench. The model at a parameter vector (the layout of
// parameter_names(); aperture excluded).
class AsBuiltModel {
 public:
  AsBuiltModel(Runtime& rt, const SystemConfig& cfg, Precision p, const Design& design, const std::vector<std::string>& parameters,
               const FitOptions& opt = {});
  ~AsBuiltModel();
  AsBuiltModel(const AsBuiltModel&) = delete;
  AsBuiltModel& operator=(const AsBuiltModel&) = delete;

  const std::vector<std::string>& parameter_names() const;  // "level1", "z", "dx", ...
  const std::vector<std::string>& parameter_units() const;
  std::vector<double> design_values() const;                 // the nominal vector
  // Whether parameter i's gradient comes from the adjoint (else central differences).
  bool adjoint_parameter(std::size_t i) const;
  // The model stack at theta (bands x S x S); with an observation (FitOptions::observation) its
  // observed image, which the loss compares.
  RealStack evaluate(const std::vector<double>& theta);
  // The model PSF stack at theta (bands x S x S), never observed; and the observation of a stack
  // (the stack itself without one).
  RealStack evaluate_psf(const std::vector<double>& theta);
  RealStack observe(const RealStack& psf) const;
  bool observed() const;
  // L(theta) = 1/2 |model - measured|^2 and dL/dtheta (adjoint where adjoint_parameter, else
  // central differences).
  double loss_gradient(const std::vector<double>& theta, const RealStack& measured, std::vector<double>& grad);
  double loss(const std::vector<double>& theta, const RealStack& measured);
  // The same with the z and d entries left 0 (what the fit takes from the Jacobian instead).
  // model_out: the model stack at theta, when given.
  double adjoint_gradient(const std::vector<double>& theta, const RealStack& measured, std::vector<double>& grad,
                          RealStack* model_out = nullptr);
  // d model / d theta: (bands x S x S) x p, column k by central differences along parameter k;
  // with at_theta (the model stack at theta, bands x S x S) by one-sided differences from it,
  // except z and d (central: their columns give the fit their gradient).
  Eigen::MatrixXd jacobian(const std::vector<double>& theta, const RealStack* at_theta = nullptr);
  // The relief of theta (N x N metres) and the configuration (z, d, aperture radius).
  Map2D heights(const std::vector<double>& theta) const;
  SystemConfig config(const std::vector<double>& theta) const;
  // The aperture radius used by evaluate() (metres; default: cfg's).
  void set_aperture_radius(double r_m);
  double aperture_radius() const;
  // The level table of theta (empty for a design that is not quantized).
  std::vector<double> levels(const std::vector<double>& theta) const;
  FitTimes& times();
  // With levels: the level indices no DOE pixel takes (held at their design values, not parameters).
  const std::vector<std::size_t>& unused_levels() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// The registration (sx, sy) of the model (sensor px, sx along columns): the native PSF stack
// (planes x N x N on the DOE grid, each plane summing to 1, as Simulator::psf_native) integrated by
// the sensor's pixels (planes x S x S, row-major) with the pixel grid moved so that the content
// moves by (sx, sy), each plane then divided by its sum; at (0, 0) what the simulator's
// psf_sensor is. Its adjoint maps a gradient on that output to one on the native stack.
RealStack integrate_registered(const RealStack& native, const SystemConfig& cfg, double sx, double sy);
RealStack integrate_registered_adjoint(const RealStack& g_out, const RealStack& native, const SystemConfig& cfg, double sx, double sy);

// Bilinear shift of each plane of a planes x rows x cols stack by (sx, sy) pixels (sx along
// columns): out(y, x) = in(y - sy, x - sx), zero outside; row-major. (The fit's starts move a
// sensor stack by whole pixels with it; the relief is moved by optics.hpp move_relief.)
std::vector<double> shift_bilinear(const std::vector<double>& in, std::size_t planes, std::size_t rows, std::size_t cols, double sx,
                                   double sy);
// Its derivative d out / d sx (axis 1) or d sy (axis 0) at (sx, sy), the same layout; piecewise
// constant in the shift, the right derivative where it is a whole number of pixels.
std::vector<double> shift_bilinear_derivative(const std::vector<double>& in, std::size_t planes, std::size_t rows, std::size_t cols,
                                              double sx, double sy, int axis);

}  // namespace qdo
