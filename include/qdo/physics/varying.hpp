// Depth-layered and spatially varying imaging: one linear operator
// with K components, each a spectral PSF stack PSF_k (bands x S x S, axis at (S/2, S/2)) and a
// per-pixel weight map w_k (H x W), in one of two placements:
//
//   source:  blur_b = sum_k PSF_{k,b} * (w_k ⊙ scene_b)   each scene pixel emits through the PSF of
//                                                           its own depth / its interpolated field PSF
//   output:  blur_b = sum_k w_k ⊙ (PSF_{k,b} * scene_b)   the release's rule: each output pixel takes
//                                                           the image blurred with its own depth's PSF
//
// then RGB_c = sum_b srf(c, b) blur_b (the camera's sensor integration, rows of srf summing to 1).
// `*` is the camera's linear convolution: zero outside the scene, output H x W aligned with the
// input. No noise. The same operator serves:
//   depth     K = D layers, w_k one-hot: each pixel's depth goes to the nearest layer in inverse
//             distance (diopters, infinity = 0), depth_layer_weights();
//   field     K = points of a regular field-angle grid, each PSF recentred on the axis (an integer
//             shift per component, set_shifts(); field_grid() gives them), w_k the bilinear hats of
//             the points' image positions, field_grid_weights();
//   low rank  R components of an SVD of the K field PSFs with weights u_r = sum_k a_{k,r} w_k,
//             low_rank_psf() and combine_weights().
// The CPU references (double) are include/qdo/physics/varying_reference.hpp.
//
// Device path (FFT, float32 or float64): one grid of GY x GX = the smallest 7-smooth sizes >= H +
// S/2 (and >= S) per axis; two real bands share one complex transform. Per kept component k:
//   source: weight-multiply, Pb forward transforms (Pb = (bands + 1) / 2), multiply by OTF_k and
//           integrate the bands per frequency, accumulated over k in the frequency domain; then 2
//           inverse transforms for the whole image (R + iG, B);
//   output: the scene's Pb forward transforms once; per k the OTF_k product integrated per
//           frequency, 2 inverse transforms, times w_k, accumulated.
// Components whose weight map is zero everywhere are skipped (no transform, no OTF): exact, they
// contribute exactly nothing. OTFs are built per component when first needed and reused while the
// PSF generation, grid and shift stay the same. Scene, weights and spectra stay on the device;
// one read-back per call.
#pragma once
#include <CL/opencl.hpp>

#include <Eigen/Dense>

#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/physics/psf_source.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

enum class PsfPlacement { Source, Output };
PsfPlacement psf_placement_from_string(const std::string& s);  // "source", "output"; InputError otherwise
std::string to_string(PsfPlacement p);

// What the last images() call computed.
struct VaryingReport {
  PsfPlacement placement = PsfPlacement::Source;
  std::size_t components = 0, height = 0, width = 0, bands = 0;
  std::vector<std::size_t> kept, skipped;       // component indices (weight map nonzero / zero everywhere)
  std::size_t grid_rows = 0, grid_cols = 0;     // FFT grid GY x GX
  std::size_t forward_ffts = 0, inverse_ffts = 0;  // complex GY x GX transforms of this call (OTFs excluded)
  std::size_t otf_builds = 0;                   // component OTFs built in this call (the rest reused)
  std::uint64_t psf_generation = 0;
  std::string to_json() const;                  // one JSON object (the fields above)
};

class VaryingCamera {
 public:
  // Follows `source`'s stack (psf_planes() = K x bands, component-major: plane k * bands + b, e.g. a
  // Simulator whose configuration lists K object points; OTFs rebuilt when psf_generation()
  // changes). Configuration, precision and runtime are the source's; it must outlive the camera.
  // The configuration's convolution must be linear (InputError otherwise).
  explicit VaryingCamera(const PsfSource& source);
  // Standalone with K components: the PSFs come from set_psfs().
  VaryingCamera(Runtime& rt, const SystemConfig& cfg, Precision p, std::size_t components);

  // Host PSFs: (K * bands) x S x S, component-major, finite. Standalone cameras only.
  void set_psfs(const RealStack& psfs);
  // Integer shift (dy, dx) per component (K entries, each |d| < S): component k is used as
  // shift_planes(PSF_k, dy, dx) (point_psf.hpp: out(y, x) = in(y + dy, x + dx), zero filled), so
  // {round(rows_px), round(cols_px)} of chief_ray_offset_px moves an off-axis PSF onto the axis,
  // as recentre_on_chief_ray does. Default: all zero.
  void set_shifts(const std::vector<std::pair<long, long>>& shifts_px);

  // RGB image (3 x H x W) of a scene (bands x H x W, finite) with weight maps (K x H x W, finite).
  // Shapes, values and the PSF's presence are checked before any device work (InputError naming
  // the argument, the value and what is allowed).
  RealStack images(const RealStack& scene, const RealStack& weights, PsfPlacement placement);
  const VaryingReport& last_report() const { return report_; }

  // Adjoint of the last images() call (linear in the scene, in the PSFs and in the weights, each
  // alone): the RGB gradient g_rgb (3 x H x W, finite) -> the gradient on the scene (bands x H x W,
  // when want_scene), on the stored PSFs ((K * bands) x S x S, when want_psfs; skipped components
  // get zeros, as they contribute nothing) and on the weight maps (K x H x W, when want_weights;
  // computed for every component, skipped ones included: a zero weight map still has a
  // gradient, so this costs the skipped components' transforms). Refused without a preceding
  // images() call; Error when the PSF changed since.
  struct Gradient {
    RealStack scene;    // bands x H x W (empty unless want_scene)
    RealStack psfs;     // (K * bands) x S x S (empty unless want_psfs)
    RealStack weights;  // K x H x W (empty unless want_weights)
  };
  Gradient vjp(const RealStack& g_rgb, bool want_scene = true, bool want_psfs = true, bool want_weights = false);

  std::size_t components() const { return k_; }
  const SystemConfig& config() const { return cfg_; }
  Precision precision() const { return prec_; }
  const Eigen::MatrixXd& srf() const { return srf_; }
  std::size_t otf_builds() const { return otf_builds_; }  // since construction

 private:
  void init();
  void check_inputs(const RealStack& scene, const RealStack& weights) const;
  void ensure_otf(std::size_t k);
  cl::Buffer& grow(cl::Buffer& b, std::size_t& cap, std::size_t bytes);
  const cl::Buffer& psf_buffer() const;
  std::uint64_t current_generation() const;

  Runtime& rt_;
  const PsfSource* source_ = nullptr;
  SystemConfig cfg_;
  Precision prec_;
  std::size_t k_ = 0, s_ = 0, rsz_ = 4;
  Eigen::MatrixXd srf_;
  std::vector<std::pair<long, long>> shifts_;
  VaryingReport report_;
  bool vjp_ready_ = false;

  cl::Buffer own_psf_;
  std::uint64_t own_generation_ = 0;
  // Per-component OTF cache key: valid, generation, grid, shift.
  struct OtfKey {
    bool valid = false;
    std::uint64_t gen = 0;
    std::size_t gy = 0, gx = 0;
    std::pair<long, long> shift{0, 0};
  };
  std::vector<OtfKey> otf_keys_;
  std::size_t otf_builds_ = 0;

  cl::Buffer otf_, otf_tmp_, scene_, weights_, wts_, spec_, rgbspec_, rgb_, grgb_, gspec_, gscene_spec_, gpsf_spec_,
      gscene_, gpsf_, gw_;
  std::size_t gw_cap_ = 0, otf_cap_ = 0, otf_tmp_cap_ = 0, scene_cap_ = 0, weights_cap_ = 0, wts_cap_ = 0, spec_cap_ = 0,
              rgbspec_cap_ = 0, rgb_cap_ = 0, grgb_cap_ = 0, gspec_cap_ = 0, gscene_spec_cap_ = 0, gpsf_spec_cap_ = 0,
              gscene_cap_ = 0, gpsf_cap_ = 0;
  cl::Kernel k_place_psf_, k_gather_psf_, k_place_, k_gather_, k_combine_, k_vjp_, k_wgrad_;
};

// ---- Weight builders (host) ----

// One-hot depth weights (K = layer count) x H x W: pixel (y, x) goes to the layer nearest to
// depth_m(y, x) in inverse distance (1/d, infinity = 0 diopters; ties to the lower index).
// depth_m: rows x cols metres (> 0 or +infinity), the scene's size; layers_m: K >= 1 distances (> 0
// or +infinity). InputError before any work for a depth map of another size than rows x cols, and
// for NaN, zero or negative distances (naming the pixel or layer and the value).
RealStack depth_layer_weights(const Map2D& depth_m, const std::vector<double>& layers_m, std::size_t rows,
                              std::size_t cols);

// Bilinear hat weights of a regular grid of image positions: component i * cols_px.size() + j is
// the tensor product of the 1-D hats of row offset rows_px[i] and column offset cols_px[j] (pixels
// from the axis at scene pixel (H/2, W/2)); piecewise linear between neighbouring offsets, constant
// (1 for the outermost, 0 for the others) beyond the outermost ones, summing to 1 at every pixel.
// Offsets: finite, strictly monotone (increasing or decreasing) on each axis. Result:
// (rows_px.size() * cols_px.size()) x H x W.
RealStack field_grid_weights(std::size_t height, std::size_t width, const std::vector<double>& rows_px,
                             const std::vector<double>& cols_px);

// A regular grid of field angles at one distance: point i * theta_x_deg.size() + j is
// {distance_m, theta_x_deg[j], theta_y_deg[i]}; rows_px[i] / cols_px[j] their chief-ray image
// offsets (chief_ray_offset_px, not rounded) and shifts_px[k] the rounded offset of point k (what
// recentres its PSF: VaryingCamera::set_shifts).
struct FieldGrid {
  std::vector<ObjectPoint> points;
  std::vector<double> rows_px, cols_px;
  std::vector<std::pair<long, long>> shifts_px;
};
FieldGrid field_grid(const SystemConfig& cfg, double distance_m, const std::vector<double>& theta_x_deg,
                     const std::vector<double>& theta_y_deg);

// Low-rank decomposition of K component PSFs ((K * bands) x S x S, each component a bands*S*S
// vector V_k) by the eigen-decomposition of the K x K Gram matrix V V^T: psfs = R components
// (R * bands) x S x S, PSF_r = sum_k a_{k,r} V_k, with V_k ~ sum_r a_{k,r} PSF_r (exact at R = K
// when the V_k are independent). coeff: K x R (orthonormal columns); singular: the K singular
// values, descending; truncation_error = ||V - V_R||_F / ||V||_F = sqrt(sum_{r >= R} s_r^2 /
// sum s_r^2). InputError for rank outside 1 .. K or a bands count that does not divide the planes.
struct LowRankPsf {
  RealStack psfs;
  Eigen::MatrixXd coeff;
  std::vector<double> singular;
  double truncation_error = 0;
};
LowRankPsf low_rank_psf(const RealStack& psfs, std::size_t bands, std::size_t rank);
// u_r = sum_k coeff(k, r) w_k: weights K x H x W, coeff K x R -> R x H x W.
RealStack combine_weights(const RealStack& weights, const Eigen::MatrixXd& coeff);

}  // namespace qdo
