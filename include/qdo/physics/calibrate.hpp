// Measured PSFs from captures (REFERENCE §8): a monochromator sweep of a point
// source, one raw frame per wavelength (16-bit grayscale PNG or TIFF, the wavelength in the file name:
// `psf_550nm.png`, `*_<number>nm.png`), and a folder of dark frames at the same exposure, become
// a sensor-grid PSF stack in the layout of `qdo psf` (bands x S x S, each band summing to 1, the
// centre at (S/2, S/2)). The steps, in order (all frames are checked before any is processed):
//   1. match: every configured band needs a frame within kBandAxisToleranceNm (a missing band is
//      refused naming the wavelength); frames at other wavelengths are refused too (naming the
//      file), so a sweep on another grid is never half used; two frames of one band are refused;
//   2. check: every frame (and every dark) the same size, code values within [0, white level]
//      (a value above it: wrong bit depth or a shifted container); a frame holding a pixel at
//      the white level is saturated and refused, naming the file and the pixel;
//   3. dark: the mean of the dark frames is subtracted; noise sigma (DN) of a frame = 1.4826 x
//      the median absolute deviation of the dark-subtracted frame (the point occupies a small
//      part of a frame), at least 0.5 DN;
//   4. hot pixels: a pixel of the mean dark above its median by hot_sigma x the dark's own MAD
//      sigma is hot in every frame; a pixel of a dark-subtracted frame above hot_sigma x sigma
//      whose 8 neighbours and (in a mosaic) 8 same-colour neighbours 2 px away all lie below
//      3 sigma is a transient hot pixel (a point imaged through optics lights its neighbours); both are replaced by the median of their 8
//      neighbours of the same filter colour (distance 2 in a mosaic) or of the 3 x 3 ring;
//   5. mosaic (cfg.cfa not none): a frame is one wavelength, so every filter colour sees the same
//      PSF scaled by its response at that band, taken from the configuration's camera response
//      (sensor_response, relative to the band's largest colour): each pixel is divided by its
//      colour's relative response; colours below min_response are not used, and their pixels
//      get the mean of their 4 (else 8) neighbours of used colours. Before that, the layout is
//      checked: the signal of the four 2 x 2 cell positions summed over all frames is compared
//      with each layout's prediction; when another layout fits at least 4 times better than the
//      configured one, the capture is refused naming the layout that fits;
//   6. too dark: peak SNR (largest dark-subtracted value / sigma) below min_snr is refused;
//   7. centre: one common centre for all bands (a point on the axis: chromatic differences of
//      the design stay in the stack): the intensity-weighted centroid of the sum over bands of
//      each band's unit-sum image with values below 3 sigma set to 0, within the S x S window
//      around its brightest pixel (then around that centroid once more), rounded to a pixel, or the
//      given centre; the S x S crop puts it at (S/2, S/2), refused when it leaves the frame;
//   8. background: the median of the crop's outer ring (2 px wide) is subtracted (unless
//      ring_background is off: a PSF with energy out to the crop's edge, as a DOE's has, loses
//      that level times S² with it; the dark has removed the sensor's own offset); then the
//      signal mask: pixels whose 5 x 5 mean exceeds floor_sigma x its noise (sigma x the pixel's
//      noise scale / 5), grown by 2 px, keep their value, all others are 0 (faint wings next
//      to the signal stay); a negative value inside is taken from its positive 8-neighbours
//      (4 passes; the rest set to 0), so the band's sum stays unbiased (clamping would add
//      0.4 sigma per masked pixel); each band is divided by its sum.
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

struct CalibrationOptions {
  double hot_sigma = 8;        // hot-pixel threshold, in noise sigmas
  double min_snr = 20;         // least peak SNR of a band
  double min_response = 0.2;   // least relative colour response a mosaic colour must have to be used
  double floor_sigma = 4;      // signal-mask threshold, in sigmas of a 5 x 5 mean's noise
  bool ring_background = true; // subtract the median of the crop's outer ring (false: the dark only)
  // Folder of white (flat-field) frames, the frames' size: a uniformly lit, spectrally flat white
  // target filling the view (flat_field.hpp). Their mean over the mean dark divides every frame's
  // signal before the colours are combined, so the colour channels' gains and the pixels' response
  // are measured, not taken from the response table. Empty: none.
  std::string white_dir;
  bool has_centre = false;     // use centre_row/col instead of the centroid
  long centre_row = 0, centre_col = 0;
};

struct CalibrationResult {
  RealStack psf;                      // bands x S x S, each band summing to 1
  std::vector<std::string> files;     // per band, the frame it came from
  std::vector<double> wavelengths_nm; // per band, from the file names
  std::vector<double> peak_snr;       // per band
  std::vector<double> noise_dn;       // per band, sigma
  std::vector<std::string> darks;     // the dark frames averaged
  std::size_t hot_pixels = 0;         // replaced, over all frames
  long centre_row = 0, centre_col = 0;  // frame pixel put at (S/2, S/2)
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

// Measured against simulated, per band (stacks bands x S x S of one shape).
struct PsfBandComparison {
  double correlation = 0;        // Pearson correlation of the two planes
  double ee80_measured_px = 0;   // radius holding 80 % of the energy around the plane's centroid
  double ee80_simulated_px = 0;
  double centroid_offset_px = 0; // distance between the two centroids
};
std::vector<PsfBandComparison> compare_psf_stacks(const RealStack& measured, const RealStack& simulated);

}  // namespace qdo
