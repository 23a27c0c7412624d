// The camera operator: scene batch -> per-band convolution with the sensor PSF stack (linear or
// circular, cfg.convolution) -> RGB sensor integration -> noise, on the device, with its adjoints
// (to the PSF stack and to the scenes) and an optional skipping of what a scene does not need,
// each rule behind its own tolerance and with a rigorous per-pixel error bound (units of full
// scale 1.0) reported with what was skipped.
//
// Forward: bands x H x W scenes, bands x S x S sensor PSF (axis at (S/2, S/2)); per-band linear
// convolution with the output aligned with the input, then I_c = sum_b srf(c, b) I'_b with srf
// rows normalised to unit sum, then noise. The host double-precision references are
// ref::convolve + ref::sensor_integrate (cpu_reference.hpp) and, for the adjoints,
// ref::convolve_vjp_psf / ref::convolve_vjp_scene + ref::sensor_integrate_vjp (adjoint.hpp).
// Computed as:
//
//   * exact reorganisation (always on, no error): two real bands share one complex FFT, the
//     sensor integration is done per frequency before the inverse transform (2 inverse FFTs per
//     image instead of one per band), and the FFT grid is the smallest alias-free 7-smooth one
//     (H + S/2 instead of H + S - 1 for the uncropped PSF);
//   rule 1 (bands): band b is skipped when sum over skipped b of srf(c, b) * max|scene_b| (max
//     over the batch) stays <= band_tolerance for every channel c; bound = that sum (max over c);
//   rule 2 (crop): every kept band's PSF is cut to the centred square of Chebyshev radius r
//     (offsets |ty|, |tx| <= r), r the smallest with max_c sum_b srf(c, b) * peak_b * dropped_b(r)
//     <= crop_tolerance (dropped_b = sum of |psf_b| outside the square, peak_b = max(1, max|scene_b|)
//     so the radius, and with it the OTFs, stay the same for every scene in [0, 1]); r then grows to
//     the largest radius the chosen FFT grid holds. Bound = max_c sum_b srf(c, b) max|scene_b|
//     dropped_b(r);
//   rule 3 (tiles): scenes are cut into tile_px x tile_px tiles convolved by overlap-add; tiles
//     are skipped, smallest first, while max_c sum_b srf(c, b) kept_b * max over skipped tiles of
//     max|scene_b on the tile| <= tile_tolerance (kept_b = sum of the cropped |psf_b| ~ 1); that
//     sum is the bound (skipped input is at most that value pointwise, the PSF spreads it with
//     weights summing to kept_b).
//
// The total bound is max_c of the per-channel sum of the three rule bounds, <= the sum of the
// rule tolerances. The bounds cover the skipping only; the arithmetic rounding of the working
// precision comes on top (float32: ~1e-7 relative per operation; see docs/fast-paths.md).
//
// Reuse: the pair-packed OTFs of the cropped kept bands are computed once per PSF generation (and
// per crop radius, FFT grid and kept-band set) and reused across calls and across the scenes of a
// batch; FFT plans come from Runtime::fft (cached); device buffers are kept between calls and
// regrown only when a larger batch needs it. Inside a call, scenes are uploaded once and the
// images are read back once at the end; the per-generation PSF ring energies (bands x (S/2 + 1)
// reals) are the only other read-back.
#pragma once
#include <CL/opencl.hpp>

#include <Eigen/Dense>

#include <cstdint>
#include <string>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/physics/psf_source.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

enum class TileMode { Off, On, Auto };
TileMode tile_mode_from_string(const std::string& s);  // "off", "on", "auto"; InputError otherwise
std::string to_string(TileMode m);

struct SkipOptions {
  // true disables every rule (the tolerances are ignored): every band of every tile is
  // computed, the images of the CPU reference camera up to the rounding of the precision.
  bool exact = false;
  // Per-rule budgets in units of full scale; 0 still skips what contributes exactly nothing
  // (bands the camera does not see or that are zero, zero tiles). Defaults: the total 3e-7 stays
  // below the float32 rounding noise of the unskipped path on the CAVE scenes (docs/fast-paths.md).
  double band_tolerance = 1e-7;
  double crop_tolerance = 1e-7;
  double tile_tolerance = 1e-7;
  // Tiling (rule 3): Off, On, or Auto (tiles when a cost model of the transforms predicts at
  // least 25 % less work than one window per scene; linear convolution only).
  TileMode tiles = TileMode::Off;
  std::size_t tile_px = 64;  // tile edge in sensor pixels, 8 .. 4096

  double total_tolerance() const { return exact ? 0.0 : band_tolerance + crop_tolerance + tile_tolerance; }
  // Each rule gets a third of `total` (>= 0, finite); tiles as given.
  static SkipOptions split(double total, TileMode tiles = TileMode::Off, std::size_t tile_px = 64);
  // Rejects (InputError, naming the option) negative, NaN or infinite tolerances and tile sizes
  // outside 8 .. 4096.
  void validate() const;
};

// What the last images() call skipped and the bounds it guarantees (units of full scale).
struct SkipReport {
  std::size_t scenes = 0, height = 0, width = 0, bands = 0;
  std::vector<std::size_t> bands_kept, bands_skipped;     // source band indices
  std::size_t sensor_psf_px = 0;                         // S
  std::size_t crop_radius_px = 0;                         // r used (S/2 = no crop)
  bool cropped = false;                                  // r < S/2 and energy was dropped
  double min_kept_energy = 1.0;                          // min over kept bands of the kept |psf| sum
  std::size_t grid_rows = 0, grid_cols = 0;              // FFT grid of one window
  bool tiled = false;
  std::size_t tile_px = 0, tiles_y = 1, tiles_x = 1;     // tile grid per scene (1 x 1 untiled)
  std::size_t tiles_total = 0, tiles_skipped = 0;        // over the batch
  std::vector<std::uint8_t> tile_skipped;                // scenes x tiles_y x tiles_x, 1 = skipped
  std::size_t forward_ffts = 0, inverse_ffts = 0;        // complex transforms of the grid size, this call
  double band_bound = 0, crop_bound = 0, tile_bound = 0; // each max over channels
  double total_bound = 0;                                // max over channels of the sum
  double tolerance = 0;                                  // SkipOptions::total_tolerance()
  std::uint64_t psf_generation = 0;
  bool otf_reused = false;                               // the OTFs of an earlier call were used
  std::string to_json() const;                           // one JSON object (the fields above)
};

class Camera {
 public:
  // Follows `source`'s current sensor PSF stack (PsfSource::psf_sensor_buffer(), the OTFs rebuilt
  // when psf_generation() changes): a Simulator, the radial engine, a PSF file
  // (StackPsfSource)... Configuration, precision and runtime are the source's; it must have one
  // design (psf_planes() == bands) and outlive the camera.
  explicit Camera(const PsfSource& source);
  // Standalone: the PSF comes from set_psf() (tests, tools with a PSF from elsewhere).
  Camera(Runtime& rt, const SystemConfig& cfg, Precision p);

  // A host PSF stack: bands x S x S (S = cfg.sensor_size_px()), axis at (S/2, S/2); finite.
  // Only for standalone imagers.
  void set_psf(const RealStack& psf_sensor);

  // RGB images (3 x H x W each) of same-shape scenes (bands x H x W, finite; values in [0, 1]
  // expected, larger ones are handled with correspondingly larger bounds), with cfg's noise.
  // Rejects bad options, shapes and values before any device work.
  std::vector<RealStack> images(const std::vector<RealStack>& cubes, const SkipOptions& opt = {});
  const SkipReport& last_report() const { return report_; }

  const SystemConfig& config() const { return cfg_; }
  Precision precision() const { return prec_; }
  const Eigen::MatrixXd& srf() const { return srf_; }

  // Adjoint of the last images() call's noiseless camera (noise is additive and independent of
  // the inputs: it passes no gradient): image gradients g_rgb (one 3 x H x W per scene of that
  // call, finite) -> the gradient on the sensor PSF stack (bands x S x S, summed over the batch)
  // and, when want_scenes, on each scene (bands x H x W). It is the exact adjoint of what that
  // call computed: skipped bands get zero gradients, PSF entries outside a crop too. Refused
  // (InputError) after a tiled call, without a preceding images() call, after blur(), and
  // when the PSF changed since (Error). The scenes stay on the device; nothing is recomputed
  // but their spectra.
  struct Gradient {
    RealStack psf;                  // bands x S x S
    std::vector<RealStack> scenes;  // bands x H x W each (empty unless want_scenes)
  };
  Gradient vjp(const std::vector<RealStack>& g_rgb, bool want_scenes = true);

  // The per-band convolution alone (bands x H x W each, cfg.convolution, no skipping, no sensor,
  // no noise): blur_b = psf_b * scene_b, as ref::convolve.
  std::vector<RealStack> blur(const std::vector<RealStack>& cubes);

  // Times the OTFs were rebuilt since construction (tests of the reuse rule).
  std::size_t otf_builds() const { return otf_builds_; }
  // vjp() reuses the scene spectra images() left on the device when that call ran in one chunk
  // (spectra_reused()); forget_spectra() makes the next vjp() transform the scenes again (tests
  // compare the two).
  bool spectra_reused() const { return spectra_ready_; }
  void forget_spectra() { spectra_ready_ = false; }

 private:
  void init();
  // What images() decides on the host before any device work: the kept bands, the crop radius r,
  // the FFT grid gy x gx of one window of th x tw pixels, the tile grid nty x ntx per scene and the
  // skipped tiles (scenes x nty x ntx, 1 = skipped); report_ is filled with it.
  struct Plan {
    std::vector<std::size_t> kept;
    std::size_t r = 0, gy = 0, gx = 0, th = 0, tw = 0, nty = 1, ntx = 1;
    bool tiled = false;
    std::vector<std::uint8_t> tile_skip;
  };
  Plan plan_images(const std::vector<RealStack>& cubes, const SkipOptions& opt);
  // Shape, band-count and finiteness checks of a batch (InputError naming the scene and pixel);
  // also refuses non-7-smooth sizes in circular mode and a missing PSF.
  // With values = false the finiteness scan is left to the caller (images() in exact mode does it
  // while uploading, then calls this again with values = true to name the value it found).
  void check_batch(const std::vector<RealStack>& cubes, bool values = true) const;
  // Uploads the kept bands (compacted) of every scene into cube_ and one untiled window per scene
  // into tiles_ / slot_of_.
  void upload_cubes(const std::vector<RealStack>& cubes, const std::vector<std::size_t>& kept);
  void ensure_rings();
  void ensure_otf(std::size_t r, std::size_t gy, std::size_t gx, const std::vector<std::size_t>& kept);
  cl::Buffer& grow(cl::Buffer& b, std::size_t& cap, std::size_t bytes, cl_mem_flags flags = CL_MEM_READ_WRITE);
  const cl::Buffer& psf_buffer() const;
  std::uint64_t current_generation() const;

  Runtime& rt_;
  const PsfSource* source_ = nullptr;
  SystemConfig cfg_;
  Precision prec_;
  std::size_t s_ = 0, rsz_ = 4;
  Eigen::MatrixXd srf_;
  SkipReport report_;

  cl::Buffer own_psf_;                   // standalone PSF (bands x S x S)
  std::uint64_t own_generation_ = 0;
  // Ring energies (bands x (S/2 + 1), host copy in double) of the PSF generation rings_gen_.
  std::vector<double> rings_;
  std::uint64_t rings_gen_ = 0;
  bool rings_valid_ = false;
  // OTF cache key and buffer (P x GY x GX complex).
  std::uint64_t otf_gen_ = 0;
  std::size_t otf_r_ = 0, otf_gy_ = 0, otf_gx_ = 0;
  std::vector<std::size_t> otf_kept_;
  bool otf_valid_ = false;
  std::size_t otf_builds_ = 0;

  cl::Buffer otf_, band_of_, cube_, tiles_, slot_of_, spec_, rgbspec_, rgb_, noisy_, wts_, eye_, rings_buf_;
  std::size_t otf_cap_ = 0, band_of_cap_ = 0, cube_cap_ = 0, tiles_cap_ = 0, slot_of_cap_ = 0, spec_cap_ = 0,
              rgbspec_cap_ = 0, rgb_cap_ = 0, noisy_cap_ = 0, wts_cap_ = 0, rings_cap_ = 0;
  bool vjp_ready_ = false;  // cube_, tiles_ and wts_ hold the last images() call's (untiled) batch
  // spec_ still holds the pair spectra of every scene of the last images() call (it ran in one
  // chunk, untiled): vjp() reads them instead of transforming the scenes again.
  bool spectra_ready_ = false;
  cl::Buffer grgb_, gscene_, gpsf_, gout_, gpsf_out_;
  std::size_t grgb_cap_ = 0, gscene_cap_ = 0, gpsf_cap_ = 0, gout_cap_ = 0, gpsf_out_cap_ = 0;
  cl::Kernel k_rings_, k_place_psf_, k_place_, k_combine_, k_gather_, k_noise_, k_multiply_, k_gather_pairs_,
      k_vjp_spectra_, k_gather_psf_;
};

// CPU reference (double, ref::convolve and ref::sensor_integrate) of the skipped computation a
// report describes: kept bands only (skipped bands contribute nothing), each PSF band (bands x
// S x S, axis at (S/2, S/2)) zeroed outside offsets |ty|, |tx| <= crop_radius_px, the skipped
// tiles of each scene zeroed, then the linear (or circular, as `mode`) per-band convolution and
// the sensor integration with srf (3 x bands, rows summing to 1). No noise. One 3 x H x W image
// per cube (bands x H x W).
std::vector<RealStack> skipped_images_reference(const std::vector<RealStack>& cubes, const RealStack& psf_sensor,
                                                const Eigen::MatrixXd& srf, const SkipReport& report,
                                                ConvolutionMode mode = ConvolutionMode::Linear);

// The sensor's full scale: a pixel value above 1 (after noise) reads as 1, as a real ADC
// saturates. rgb: 3 x H x W (any planes x H x W), modified in place. Returns the fraction of
// values that were clipped (> 1) and the largest value before clipping; values below 0 (read
// noise on a dark pixel, as after black-level subtraction) are kept. NumericalError naming
// `what` if any value is NaN or Inf.
struct SensorClip {
  std::size_t clipped = 0, total = 0;
  double max_before = 0;
  double fraction() const { return total ? double(clipped) / double(total) : 0.0; }
};
SensorClip clip_to_full_scale(RealStack& rgb, const std::string& what);
// One report line: "sensor: 0.12 % of values (12 of 9800) clipped at full scale 1 (max 1.3 before
// clipping)", or "sensor: no value clipped at full scale (max 0.97)".
std::string clip_summary(const SensorClip& c);

}  // namespace qdo
