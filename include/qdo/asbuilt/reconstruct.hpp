// `qdo reconstruct` as a library call: captured photos of one scene through the
// built camera -> the run's decoder, with the PSF of the camera as built (measured or fitted) ->
// the spectral cube, an sRGB render and spectra at named points and boxes.
//
// The capture chain, in order (every file is read and checked before any is processed; each
// refusal is an InputError naming the file or the argument):
//   1. read: 16-bit PNG or TIFF captures (read_capture16, io.hpp), one scene, all the same size; RGB (3
//      planes) when the configuration's cfa is none, a raw mosaic (1 plane) otherwise. Several
//      captures are averaged. A code value above the white level (cfg.white_level_dn(); 65535
//      when bit_depth is 0: the container's) is refused (wrong bit depth or a shifted container).
//   2. dark: the mean of the dark frames (a folder of 16-bit PNG or TIFF files of the captures' size and
//      planes) is subtracted; without darks the configured black level (black_level_dn).
//   3. signal: v = (DN - dark) / (gain * (white - black_level_dn)): the linear signal, 1.0 = full
//      well, the inverse of the sensor-as-built stage (raw.hpp).
//   4. mosaic: the 2 x 2 phase and colours are checked by read_captures (check_mosaic_phase,
//      check_mosaic_colours, on step 3's signal), then the capture pipeline's development of a
//      raw frame (CapturePipeline::develop, capture_pipeline.hpp: the demosaic, bilinear or
//      Malvar-He-Cutler, on the device; the stages `qdo simulate --raw` runs after the sensor).
//   5. crop: ROW, COL, H, W of the frame (after the demosaic, so the mosaic phase is kept).
//   6. exposure (ExposureRule): none, a fixed factor, or the factor that puts a percentile of
//      the cropped image at a level.
// Then the decoder on tiles of its grid (S x S, the prior's and the training crops'), with
// overlap, blended (blend_tiles); the cube is clipped to [0, 1] as `qdo eval` clips it.
#pragma once
#include <Eigen/Dense>

#include <cstddef>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/data/cube_views.hpp"
#include "qdo/decode/decoder.hpp"
#include "qdo/decode/testset.hpp"
#include "qdo/decode/tiled.hpp"
#include "qdo/runtime/parse.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/runtime/types.hpp"
#include "qdo/decode/wiener.hpp"
#include "qdo/physics/demosaic_reference.hpp"

namespace qdo {

// How the signal is scaled before decoding (step 6):
//   none            as the sensor settings give it (v above)
//   scale:K         v * K (e.g. the ratio of the training exposure to the capture's), K in (0, 1e6]
//   percentile:P:L  v * L / (the P-th percentile of the cropped image's values), P in (0, 100],
//                   L in (0, 1]; a percentile <= 0 is refused
struct ExposureRule {
  enum class Kind { None, Scale, Percentile } kind = Kind::None;
  double scale = 1, percentile = 99, level = 0.9;
  std::string to_string() const;
};
ExposureRule exposure_rule_from_string(const std::string& s, const std::string& argument = "--exposure");

struct CaptureOptions {
  std::vector<std::string> captures;  // 16-bit PNG or TIFF files of one scene (averaged)
  std::string darks_dir;              // folder of dark frames (*.png); empty: the black level
  // Folder of white (flat-field) frames: a uniformly lit, spectrally flat white target filling the
  // view, the captures' size and kind, averaged, dark subtracted as the captures. Every capture
  // pixel is divided by its white signal over the white's mean: the colour channels' gains and
  // the pixels' response non-uniformity measured instead of taken from the response table.
  // Empty: none.
  std::string white_dir;
  ExposureRule exposure;
  bool crop = false;                  // crop_* below: rows and columns of the frame, 0-based
  std::size_t crop_row = 0, crop_col = 0, crop_rows = 0, crop_cols = 0;
  std::string demosaic = "bilinear";  // raw captures: bilinear or mhc (Malvar-He-Cutler)
};

// The captures, read and checked (step 1 and the darks' reading), nothing processed yet.
struct CaptureFiles {
  RealStack mean_dn;                 // planes x H x W (planes 1: a mosaic; 3: RGB), mean of the captures, DN
  RealStack dark_dn;                 // planes x H x W, mean of the darks; empty: none
  std::vector<std::string> darks;    // the dark frames read
  std::size_t saturated = 0;         // capture values at the white level (kept; counted)
  double white_dn = 0;               // the white level used
  std::vector<std::string> whites;   // the white (flat-field) frames read
  RealStack flat;                    // planes x H x W: white signal / its mean (1 = nominal); empty: none
  std::vector<double> channel_gains; // with whites: each colour channel's white mean / the white's mean (R, G, B)
  std::vector<std::string> notes;    // what the user should know (clipped values), printed and in reconstruct.json
};
// Every capture and dark read and checked: sizes, the white level, overexposed or empty captures
// (check_capture_levels), and with a mosaic its phase and colours (step 4's checks).
CaptureFiles read_captures(const SystemConfig& cfg, const CaptureOptions& o);

// The mosaic's 2 x 2 phase against cfg.cfa, cheaply: the two green sites of a Bayer cell see the
// same filter, so diagonal neighbours on the green diagonal differ by the scene's gradient only,
// while the red-blue pair differs by the colour as well. When the configured layout's green pair
// differs on average by more than 2 % of the mean level and more than 3 times the other pair, the
// capture is refused naming `origin` and the layout family that fits (RGGB/BGGR against
// GRBG/GBRG; an R/B swap within a family cannot be seen without knowing the scene, nor anything
// on a grey scene). (qdo calibrate's check predicts a monochromatic frame's cell shares from the
// camera response; a broadband scene has no such prediction, hence this one.)
// raw: 1 x H x W signal (dark subtracted).
void check_mosaic_phase(const RealStack& raw, Cfa cfa, const std::string& origin);
// Red and blue within a family (RGGB read as BGGR: a raw frame cropped by one row and one
// column), seen through physics instead of the scene: every light the camera records is a
// non-negative mix of its bands, so a cell's (R, B) / (R + G + B) lies in the convex hull of the
// band columns of srf (3 x bands), whatever the scene and the PSF. With the configured layout, the
// fraction of bright cells (sum above the median) outside the hull by more than 0.02 is compared
// with the same fraction with red and blue swapped; above 20 % and more than 4 times the swapped
// one, the capture is refused naming `origin` and the swapped layout. A grey or weakly coloured
// scene passes either way (nothing to see). raw: 1 x H x W signal (dark subtracted).
void check_mosaic_colours(const RealStack& raw, Cfa cfa, const Eigen::MatrixXd& srf, const std::string& origin);

// Steps 2 and 3: the linear signal (planes x H x W) of read_captures' result.
RealStack capture_signal(const SystemConfig& cfg, const CaptureFiles& f);

struct PreparedCapture {
  RealStack rgb;             // 3 x H x W linear signal, cropped, exposure applied
  double exposure_factor = 1;
  // A raw mosaic's demosaic error, estimated from the capture itself (full-scale units, before the
  // exposure): the RMS over channels and pixels (2 px from the edge left out) of the demosaiced
  // image sampled through the mosaic one column over and developed again (estimate_demosaic_sigma);
  // 0 for RGB captures.
  double demosaic_sigma = 0;
  double seconds_dark = 0, seconds_demosaic = 0;
};
// Steps 2 to 6 on read_captures' result; the development (CapturePipeline::develop) on rt's device
// in precision p.
PreparedCapture prepare_capture(Runtime& rt, Precision p, const SystemConfig& cfg, const CaptureOptions& o, const CaptureFiles& f);
// The demosaic error of a developed mosaic capture, from the capture alone: rgb (3 x H x W, the
// demosaic by `method` of a raw frame of cfg.cfa, linear units) is sampled through the mosaic one
// column over (each site then holds another colour) and developed by the same demosaic on rt's
// device; at the sites where the capture measured colour c, that development interpolates a value
// rgb holds as measured. sigma^2 = the mean over the colours of the share of pixels the first
// demosaic interpolates (3/4 red and blue, 1/2 green) times the colour's mean squared error at
// its sites (2 px from the edge left out): the RMS error of the first demosaic over all pixels if
// the second errs as it did. Its neighbours are partly interpolated already (a smoother image), so
// it errs less: tests/test_reconstruct_sensor.cpp measures it against the true error.
double estimate_demosaic_sigma(Runtime& rt, Precision p, const SystemConfig& cfg, DemosaicMethod method, const RealStack& rgb);

// The sensor as built, over the run's configuration: a JSON object of sensor keys only (cfa,
// black_level_dn, bit_depth, gain, read_noise_sigma, full_well_photons, noise_seed, camera,
// srf_interpolate) replacing the run's values, checked as a configuration. Any other key (the
// optics are the run's) is refused naming it; with a trained decoder (a network) the camera
// response cannot change (its network saw the run's), so camera and srf_interpolate are refused.
// `overridden` (optional) gets the keys given, in the file's order.
SystemConfig with_sensor(const SystemConfig& run_cfg, const std::string& sensor_file, bool trained_decoder,
                         std::vector<std::string>* overridden = nullptr);

struct ReconstructOptions {
  std::string run;          // the run folder: its configuration, prior and decoder
  std::string sensor_file;  // the sensor as built (with_sensor); empty: the run's sensor
  std::string psf_file;     // a measured PSF stack (qdo calibrate's psf.h5); or
  std::string design_file;  // a fitted as-built design .h5 (simulated); neither: the run's design
  CaptureOptions capture;
  std::size_t overlap_px = 0;  // tile overlap; 0: S / 4
  // The tiles' boundary; default (unset): linear for the Wiener decoder, mirror for cg, circular
  // for a network (which refuses mirror and linear: it was trained on circular S x S patches);
  // linear needs the Wiener or cg decoder (it solves their objective by conjugate gradients,
  // tiled.hpp).
  bool boundary_set = false;
  TileBoundary boundary = TileBoundary::Linear;
  double noise_sigma = -1;     // the Wiener decoder's sigma; < 0: the run's (or the model's, below)
  // The sigma from the sensor's noise model at the capture's mean signal v (full-scale units,
  // before the exposure): sqrt(read^2 + v / full well + (1 / (2^bits - 1))^2 / 12), times the
  // exposure factor; each term only where the configuration has it (read_noise_sigma,
  // full_well_photons > 0, bit_depth > 0), and for a raw mosaic the demosaic error estimated from
  // the capture (PreparedCapture::demosaic_sigma) added in quadrature.
  bool noise_sigma_model = false;
  // The Wiener decoder's sigma chosen from the capture: the largest marginal likelihood of its
  // S x S tiles under the decoder's own model (wiener::ml_noise_sigma, with the PSF and prior the
  // decoder is built with), so power the model does not predict (demosaic error, light from
  // outside a tile, a scene the prior fits badly) counts as noise. Refused for other decoders.
  bool noise_sigma_ml = false;
  // The same search by generalised cross-validation instead (wiener::gcv_noise_sigma), for
  // comparison: with 3 channels for 31 bands it runs to the bottom of its range (docs/built-camera.md).
  bool noise_sigma_gcv = false;
  std::vector<SpectrumRegion> regions;  // empty: the image centre
  std::string out;
  Precision precision = Precision::F32;
  bool quiet = false;       // no progress lines
};
struct ReconstructResult {
  RealStack cube;                                       // bands x H x W, clipped to [0, 1]
  std::vector<std::pair<std::string, double>> seconds;  // per stage, in order
  std::size_t tiles = 0, tile_px = 0;
  std::string boundary;                                 // "circular", "mirror" or "linear"
  std::string psf, decoder;                             // what was used, one line each
  double exposure_factor = 1;
  std::vector<std::string> notes;                       // from the captures (CaptureFiles::notes)
  // The linear boundary's Wiener solves (MaskedWienerDecoder::Stats): tiles solved, the most
  // iterations, the worst relative residual, whether every one converged; solves 0 otherwise.
  std::size_t solver_solves = 0, solver_max_iterations = 0;
  double solver_worst_residual = 0;
  bool solver_converged = true;
};
// Writes OUT/cube.h5 (/cube bands x H x W float64, /wavelengths_nm, provenance attributes),
// srgb.png, spectra.csv (wavelength_nm, one column per region), spectra.png and reconstruct.json
// (inputs, the PSF and decoder used, tiles, seconds per stage). Every input checked first.
ReconstructResult reconstruct(Runtime& rt, const ReconstructOptions& o);


// ---- Scoring against the scene a capture shows (a simulation's cube) ----
// Arguments named in refusals: the library's names by default; a caller passes its own.
struct TruthArguments {
  std::string run = "run", truth = "truth", key = "truth_key", border = "truth_border";
};
// The truth cube (read_scene with `key`, the run's configuration with o.sensor_file's sensor), checked
// against the captures' size and cropped as o.capture crops them: bands x H x W, row-major. Reads
// the captures' headers and pixels (read_captures) but does no device work.
RealStack read_reconstruct_truth(const ReconstructOptions& o, const std::string& path, const std::string& key,
                                 const TruthArguments& names = {});
// The scored interior, border_px from each edge of truth (bands x H x W), must hold the metrics'
// 11 x 11 SSIM window; an InputError naming names.border otherwise.
void check_truth_border(const RealStack& truth, std::size_t border_px, const TruthArguments& names = {});
// qdo eval's metrics of cube against truth (both bands x H x W, the same shape) over the interior
// border_px from each edge; OUT/metrics.json (truth: `path`, border, the PSF and decoder of r, the
// means). An InputError naming names.truth (value `path`) when the bands differ.
testset::Scores score_reconstruction(const ReconstructResult& r, const RealStack& truth, std::size_t border_px,
                                     const std::string& path, const std::string& out, const TruthArguments& names = {});

// ---- qdo reconstruct as a library call ----
struct ReconstructRequest {
  ReconstructOptions options;  // out left empty: the caller claims the folder and sets it
  std::string truth_path;      // the scene the captures show (empty: not scored)
  RealStack truth;             // read_reconstruct_truth's: bands x H x W, row-major
  std::size_t border_px = 0;   // the score's border
  TruthArguments names{"--run", "--truth", "--truth-key", "--truth-border"};
};
// The options as a user typed them (TextOptions: run, sensor, capture (repeatable), darks, white, psf, design, exposure, crop, demosaic, overlap, boundary, noise-sigma,
// points, boxes, truth, truth-key, truth-border, precision), each checked, and the truth read and
// checked against the captures: every refusal an InputError naming the option as typed, before any
// device work.
ReconstructRequest reconstruct_request_from_options(const TextOptions& a);
// reconstruct() into q.options.out, then with a truth the score (metrics.json); returns the report:
// the score, the notes, the decoder, PSF, sizes, tiles, seconds per stage and the files written.
std::string run_reconstruct_request(Runtime& rt, const ReconstructRequest& q);

}  // namespace qdo
