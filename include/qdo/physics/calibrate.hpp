// Measured PSFs from captures (REFERENCE §8): a monochromator sweep of a point source, one or
// more raw frames per wavelength (16-bit grayscale PNG or TIFF, or camera raw, the wavelength in
// the file name: `psf_550nm.png`, `*_<number>nm.png`), and a folder of dark frames at the same
// exposure, become a sensor-grid PSF stack in the layout of `qdo psf` (bands x S x S, each band
// summing to 1, the centre at (S/2, S/2)). The steps, in order (all frames are checked before any
// is processed):
//   1. match: every configured band needs a frame within kBandAxisToleranceNm (a missing band is
//      refused naming the wavelength); frames at other wavelengths are refused too (naming the
//      file), so a sweep on another grid is never half used; several frames of one band (within
//      the tolerance) are exposures of it, averaged in step 3;
//   2. check: every frame (and every dark) the same size, code values within [0, white level]
//      (a value above it: wrong bit depth or a shifted container); a frame holding a pixel at
//      the white level is saturated and refused, naming the file and the pixel;
//   3. dark: the mean of the dark frames is subtracted from every exposure; a band's signal is the
//      mean of its k exposures (after step 4's test), its noise sigma (DN) = 1.4826 x the median
//      absolute deviation of that mean (the point occupies a small part of a frame), at least
//      0.5 DN / sqrt(k) (each exposure's own sigma likewise, at least 0.5 DN). The noise of a pixel
//      is Poisson-Gaussian: sigma² x k / (its exposures used) + its signal x shot_dn / k, with
//      shot_dn = gain x (white - black) / full_well_photons DN² per DN (one electron's DN) from
//      the configuration; full_well_photons 0 (no shot noise configured) leaves read noise alone;
//   4. hot pixels: a pixel of the mean dark above its median by hot_sigma x the dark's own MAD
//      sigma is hot in every frame. A transient (a pixel of one exposure only) is found against
//      the band's other exposures and against the adjacent bands, never by spatial isolation (a
//      speckle peak of a mosaic colour is isolated too):
//        exposures (k >= 2): each exposure's value above alpha_e x the median of the others' at
//          that pixel (alpha_e: the exposure's brightness against the others', the median ratio
//          over pixels above hot_sigma x sigma) by more than hot_sigma x the sd of that
//          difference (read and shot noise of the exposure and of the median);
//        adjacent bands (the PSF changes slowly with wavelength): a value above the ceiling that
//          both adjacent bands (at the sweep's ends the next two) set at that pixel, each band's
//          largest value in the pixel's 3 x 3 neighbourhood (a speckle moves by up to a pixel
//          between bands) scaled by its colour's response and its band's total signal, times
//          (1 + kAdjacentBandRise = 3), plus hot_sigma x the sd of the difference; with k >= 2 the
//          value must also stand 3 sd above the band's other exposures there;
//      a transient is left out of its band's mean (the pixel's mean over the band's other
//      exposures); a hot pixel, or a pixel whose exposures were all transient (with one
//      exposure: every transient), is no measurement and gets step 5's neighbourhood estimate;
//   5. colours: a frame is one wavelength, so every pixel sees the same PSF theta times its
//      gain: its colour's response at that band relative to the band's largest colour
//      (sensor_response; 1 without a mosaic), times the flat field with --white. Each pixel's
//      own estimate x = raw / gain has variance v = (its noise, step 3) / gain² (the shot term's
//      signal from its 8 neighbours, never from its own noisy value); colours below
//      min_response (default 0.005: a colour that responds at all is used) are no measurement.
//      The estimate is empirical Bayes (joint_pixel_estimate): m = the inverse-variance mean of
//      the 8 neighbours' x (of the 5 x 5 window's 24 where none of the 8 measures), vm its
//      variance from their noise, tau² the local spread of the truth about such a mean,
//      proportional to the local level (kappa (m² + vm), kappa the noise-debiased mean of
//      (x_q - m_q)² / (m_q² + vm_q) over the 7 x 7 window, each term weighted by its variance,
//      the spread's own included: a speckle's spread, and a peak's departure from its
//      neighbours, scale with their level), and
//      x^ = (x / v + m / (vm + tau²)) / (1 / v + 1 / (vm + tau²)): a weak colour's noisy pixel
//      leans on its neighbours where the PSF is smooth, and keeps its own value where the PSF
//      has structure its neighbours do not predict; noise-free frames give x^ = raw / gain (to
//      the rounding: within 1.5 DN / gain on a DOE's speckle, tests/test_calibrate.cpp). No pixel
//      is replaced blindly, so nothing of a speckle one pixel wide is interpolated away. A
//      pixel's noise scale (its error sd over the band's sigma) is 1 / sqrt(1 / v + 1 / (vm + tau²))
//      over sigma. Before that, with a mosaic, the layout is checked: the signal of the four
//      2 x 2 cell positions summed over all bands is compared with each layout's prediction;
//      when another layout fits at least 4 times better than the configured one, the capture
//      is refused naming the layout that fits;
//   6. too dark: peak SNR (largest dark-subtracted mean value / sigma, hot pixels and transients
//      left out) below min_snr is refused;
//   7. centre: one common centre for all bands (a point on the axis: chromatic differences of
//      the design stay in the stack), by CalibrationOptions::centre: the given pixel; the frame's
//      centre pixel (rows / 2, cols / 2); or the light's centroid: the intensity-weighted centroid
//      of the sum over bands of each band's unit-sum image with values below 3 x its noise set to
//      0, within the S x S window around its brightest pixel (then around that centroid once
//      more), rounded to a pixel. The default (automatic) takes the frame's centre when the
//      centroid lies within kFrameCentreReachPx of it, else the centroid (with a note): a camera
//      is built with the DOE's axis over the sensor's centre and a simulator puts it there, while
//      a DOE's PSF is not symmetric and its centroid lies a pixel or two off the axis, which would
//      move the stack, and every cube reconstructed with it, against the design's PSF and a
//      simulation's truth. The S x S crop puts the centre at (S/2, S/2), refused when it leaves
//      the frame;
//   8. background: the median of the crop's outer ring (2 px wide) is subtracted (unless
//      ring_background is off: a PSF with energy out to the crop's edge, as a DOE's has, loses
//      that level times S² with it; the dark has removed the sensor's own offset); then the
//      signal mask, over mask_windows (default 5, 11, 23 px): a window is lit when the mean of
//      its pixels not yet in the mask exceeds floor_sigma x that mean's noise (1 / sqrt of the
//      sum of their own-estimate precisions 1 / v: sigma / 5 for 25 equal pixels; windows more
//      than half inside the mask are not tested), and every pixel of a lit window joins the mask,
//      the smallest window first (so the 5 x 5 scale keeps a compact PSF and its faint wings,
//      and the larger ones a DOE's wide halo, below the noise of every 5 x 5 window, without
//      being lit by a core they contain); pixels in the mask keep their value, all others are 0;
//      a negative value inside is taken from its positive neighbours (8-neighbours, then squares
//      up to 6 px for what is left; the rest set to 0), so the band's sum stays unbiased
//      (clamping would add 0.4 sigma per masked pixel); each band is divided by its sum.
#pragma once
#include <array>
#include <string>
#include <utility>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

// The wavelength in a file name's stem, "<anything>_<number>nm" (e.g. psf_552.5nm.png -> 552.5);
// a negative value when the name has none.
double wavelength_from_file_name(const std::string& path);

// Where step 7 centres the S x S window.
enum class CentreRule {
  automatic,  // the frame's centre pixel when the centroid lies within kFrameCentreReachPx of it, else the centroid
  centroid,   // the light's centroid, rounded to a pixel
  frame,      // the frame's centre pixel (rows / 2, cols / 2)
  given       // CalibrationOptions::centre_row, centre_col
};
// The automatic rule's reach (px): a DOE's PSF centroid lies 1-2 px from its axis (EXPERIMENTS.md,
// the Section 7 design), a point source aligned elsewhere further.
inline constexpr double kFrameCentreReachPx = 4;

struct CalibrationOptions {
  double hot_sigma = 8;        // hot-pixel threshold, in noise sigmas
  double min_snr = 20;         // least peak SNR of a band
  // Least relative response (of the band's largest colour) for a mosaic colour's pixels to be a
  // measurement at a band; below it (or at 0) they get step 5's neighbourhood estimate. Weak
  // colours above it are used, weighted by their noise: a floor against a response table's own
  // error at near-zero values, not a noise threshold.
  double min_response = 0.005;
  double floor_sigma = 4;      // signal-mask threshold, in sigmas of a window mean's noise
  // The signal mask's window widths (px, odd, 3 .. 255, ascending): the first tests every pixel's
  // window, each further one the light the earlier ones have not kept (step 8). {5} alone keeps
  // a compact PSF and cuts a faint wide halo.
  std::vector<std::size_t> mask_windows{5, 11, 23};
  bool ring_background = true; // subtract the median of the crop's outer ring (false: the dark only)
  // Folder of white (flat-field) frames, the frames' size: a uniformly lit, spectrally flat white
  // target filling the view (flat_field.hpp). Their mean over the mean dark divides every frame's
  // signal before the colours are combined, so the colour channels' gains and the pixels' response
  // are measured, not taken from the response table. Empty: none.
  std::string white_dir;
  CentreRule centre = CentreRule::automatic;
  long centre_row = 0, centre_col = 0;  // CentreRule::given: the frame pixel of the optical axis
};

struct CalibrationResult {
  RealStack psf;                      // bands x S x S, each band summing to 1
  std::vector<std::string> files;     // every frame used, band by band (a band's exposures in name order)
  std::vector<std::size_t> exposures;  // per band, the frames averaged
  std::vector<double> wavelengths_nm;  // per band, from the file names (the mean over its exposures)
  std::vector<double> peak_snr;       // per band
  std::vector<double> noise_dn;       // per band, sigma of the band's mean of exposures
  std::vector<std::string> darks;     // the dark frames averaged
  std::size_t hot_pixels = 0;         // replaced: the darks' hot pixels once per band, plus every transient
  std::vector<char> hot_map;          // frame_rows x frame_cols, row-major: 1 at the darks' hot pixels
  // The transients of step 4 (each exposure's pixel counts once): (band, exposure, row, column).
  std::vector<std::array<std::size_t, 4>> transients;
  long centre_row = 0, centre_col = 0;  // frame pixel put at (S/2, S/2)
  // The rule that chose the centre: "given", "frame centre", "centroid", or "frame centre
  // (automatic: ...)" / "centroid (automatic: ...)" with the light's centroid and its distance.
  std::string centre_rule;
  std::size_t frame_rows = 0, frame_cols = 0;
  // Per band, the frame's own background after the mean dark is subtracted (DN): ~0 when the
  // darks match the frames (same exposure, gain, temperature). Estimated from the frame's 10th
  // percentile (which light only raises) plus 1.2816 noise sigmas.
  std::vector<double> background_dn;
  std::vector<std::string> notes;  // what the user should know (printed and stored with psf.h5)
  std::vector<std::string> whites;        // the white frames averaged (CalibrationOptions::white_dir)
  std::array<double, 3> channel_gains{};  // with whites: each colour's mean white signal over the white's mean
  // Seconds per step, in order: match, read, dark, hot pixels and SNR, mosaic, centre, crop,
  // background and normalise.
  std::vector<std::pair<std::string, double>> seconds;
};

// The whole calibration (steps above) of frames_dir against darks_dir for cfg. Every refusal is
// an InputError naming the file (or folder) and what is wrong, raised before the frames are
// processed where the input alone shows it.
CalibrationResult calibrate_psf(const SystemConfig& cfg, const std::string& frames_dir, const std::string& darks_dir,
                                const CalibrationOptions& opt = {});

// One frame's code values as calibrate_psf reads them: rows x cols DN (with bit_depth 0, a 16-bit
// file's codes over 65535) from a 16-bit grayscale PNG, TIFF or camera raw file (its layout,
// black and white levels checked against cfg). An InputError naming the file otherwise.
Map2D read_raw_frame(const SystemConfig& cfg, const std::string& path);

// The sweep reduced for a fit in the measurement domain (fit_raw.hpp): calibrate_psf's reading,
// checks and refusals (with ring_background off: the darks alone remove the offset, and darks
// that do not match the frames are refused), its hot pixels, transients, noise and centre, and
// then, per band, the S x S window of the frames themselves around that centre (the window of
// the stack calibrate_psf makes), not a calibrated stack.
struct RawPsfWindows {
  CalibrationResult calibration;  // calibrate_psf of the same frames (its psf is the stack path's measured stack)
  std::size_t s = 0;              // the window's side, cfg.sensor_size_px()
  long top = 0, left = 0;         // frame pixel of the window's (0, 0): the centre less (S/2, S/2)
  double dn_full_scale = 1;       // DN of the linear signal 1.0: gain x (white level - black level)
  // bands x S x S each, row-major; signal and variance in full-scale units (DN / dn_full_scale):
  //   signal    the mean of the band's exposures at the pixel (transients and codes clipped at 0
  //             left out) less the mean dark;
  //   variance  its Poisson-Gaussian variance: the read variance of the mean of the n exposures
  //             used less the mean of d darks, (1/n + 1/d) times one frame's (with d >= 2 the mean
  //             over the pixels of each pixel's sample variance across the darks, at least the
  //             rounding's 1/12 DN^2; with one dark, calibrate's noise of the band's mean, the MAD
  //             of its unlit pixels) plus the shot noise of the expected signal over n, one electron
  //             gain (white - black) / full_well_photons DN; the expected signal is the pixel's
  //             gain times the PSF its 8 neighbours measure, never its own value, so a weight
  //             does not follow the noise it weighs;
  //   gain      the pixel's signal per unit PSF and source power: its colour's response at the
  //             band over the band's largest colour, times the white frames' flat field when
  //             given (PixelGain); 0 where the pixel is no measurement (hot in the darks, a colour
  //             under min_response, no exposure left): signal and variance are 0 there.
  RealStack signal, variance, gain;
  // variance's two parts (bands x S x S, full-scale units; 0 where not usable): variance =
  // read_variance + shot_per_signal x the expected signal (full-scale units), so that a fit can
  // weigh again with the signal its model expects (fit_raw.hpp: reweight_raw_windows).
  RealStack read_variance, shot_per_signal;
  std::vector<int> colour;  // S x S: each pixel's mosaic colour (0 R, 1 G, 2 B; -1 without a mosaic)
  std::size_t usable = 0;   // the entries (pixels of all bands) with gain > 0
};
RawPsfWindows reduce_psf_frames(const SystemConfig& cfg, const std::string& frames_dir, const std::string& darks_dir,
                                const CalibrationOptions& opt = {});

// Steps 4 and 5 on their own (calibrate_psf uses them; tests call them on synthetic frames).

// How far a PSF value may rise over the adjacent bands' prediction before it counts as a
// transient (step 4): a value above (1 + this) x the prediction, plus hot_sigma noise sd. A DOE's
// PSF is not the same at 10 nm steps: a speckle's intensity changes. Over the pixels above 1e-4 of
// the peak of the small preset's stacks, a band's value rose over the larger of both adjacent
// bands' 3 x 3 maxima (each band at unit sum) by up to 2.2 x (the random-phase speckle DOE of
// tests/test_calibrate.cpp), 1.9 x (lens:550, defocused at the sweep's ends) and 2.6 x (the
// trained 4-level QDO+A design of scripts/experiments_section7.sh, tests/test_fit.cpp), so a
// transient must triple the prediction.
constexpr double kAdjacentBandRise = 2.0;

// The gain of pixel (y, x) at band b: its colour's relative response (colour 0 without a mosaic)
// times the flat field; 0 where the pixel is dead (the darks' hot pixels) or the response is below
// min_response (no measurement).
struct PixelGain {
  Cfa cfa = Cfa::None;
  std::vector<std::array<double, 3>> response;  // per band, R G B relative to the band's largest
  double min_response = 0;
  const Map2D* flat = nullptr;  // rows x cols, mean 1; nullptr: 1
  std::vector<char> dead;       // rows x cols, or empty
  std::size_t cols = 0;
  double operator()(std::size_t b, std::size_t y, std::size_t x) const;
};

// Step 4 across one band's k exposures (each rows x cols, dark subtracted, DN; sigma_dn per
// exposure; shot_dn the DN² of shot-noise variance per DN of signal in one exposure, 0 for read
// noise alone): per exposure, rows x cols, how many sd its value stands above alpha_e x the median
// of the others' (each over its brightness alpha); 0 at pixels marked in skip (rows x cols, or
// empty) and everywhere when k < 2.
std::vector<Map2D> exposure_excess(const std::vector<Map2D>& exposures_dn, const std::vector<double>& sigma_dn,
                                   double shot_dn, double hot_sigma, const std::vector<char>& skip);

// Step 4 against the adjacent bands: rows x cols, the largest value (DN) one exposure of band b
// (noise sigma own_sigma_dn) may hold at a pixel before it is a transient, from the other bands'
// means (mean_dn: bands x rows x cols, DN, their sigma and exposure counts). Infinite where
// untestable (no measurement, one band only).
Map2D adjacent_band_ceiling(std::size_t b, const std::vector<Map2D>& mean_dn, const std::vector<double>& mean_sigma_dn,
                            const std::vector<std::size_t>& exposures, const PixelGain& gain, double own_sigma_dn,
                            double shot_dn, double hot_sigma);

// Step 5 on one band (all maps rows x cols): raw_dn the signal (dark subtracted, DN), gain each
// pixel's expected signal per unit PSF (0: no measurement), read_var_dn2 its read-noise variance,
// shot_dn the shot-noise variance per DN of signal. The PSF theta (DN per unit gain) by the
// empirical-Bayes combination of each pixel's own estimate raw / gain with its neighbourhood's.
struct JointEstimate {
  Map2D value;  // theta^, DN per unit gain
  Map2D sd;     // its error sd, same units; infinite where neither the pixel nor a neighbour measures
  Map2D info;   // 1 / the variance of the pixel's own estimate raw / gain (0: no measurement)
};
JointEstimate joint_pixel_estimate(const Map2D& raw_dn, const Map2D& gain, const Map2D& read_var_dn2, double shot_dn);

// Step 7: the common centre by opt.centre (CentreRule) from every band's signal (bands maps of
// rows x cols, DN per unit gain), each pixel's noise scale (its error sd over the band's noise,
// same layout) and each band's noise noise_dn (DN); s the window's side (the centroid's reach).
struct CentreChoice {
  long row = 0, col = 0;  // the frame pixel put at (S/2, S/2)
  std::string rule;  // as CalibrationResult::centre_rule
  std::string note;  // automatic, far from the frame's centre: what the user should know; else empty
};
CentreChoice choose_centre(const std::vector<Map2D>& signal_dn, const std::vector<Map2D>& noise_scale,
                           const std::vector<double>& noise_dn, std::size_t s, const CalibrationOptions& opt);

// Step 8 on one band: the S x S crop of estimate (rows x cols, DN per unit gain) whose top-left
// corner is frame pixel (y0, x0), the ring background subtracted when ring_background, the signal
// mask (info: rows x cols, each pixel's own-estimate precision times sigma_dn², the band's sigma;
// mask_windows as CalibrationOptions'),
// negatives spread onto positive neighbours, unit sum. S x S; all 0 when nothing positive is left.
Map2D crop_band(const Map2D& estimate, const Map2D& info, double sigma_dn, std::size_t y0, std::size_t x0,
                std::size_t s, double floor_sigma, bool ring_background, const std::vector<std::size_t>& mask_windows);

// Measured against simulated, per band (stacks bands x S x S of one shape).
struct PsfBandComparison {
  double correlation = 0;        // Pearson correlation of the two planes
  double ee80_measured_px = 0;   // radius holding 80 % of the energy around the plane's centroid
  double ee80_simulated_px = 0;
  double centroid_offset_px = 0; // distance between the two centroids
};
std::vector<PsfBandComparison> compare_psf_stacks(const RealStack& measured, const RealStack& simulated);

}  // namespace qdo
