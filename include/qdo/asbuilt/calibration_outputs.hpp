// The files of a PSF calibration (calibrate.hpp), as library calls (what `qdo calibrate` writes):
// the measured stack in the layout of `qdo psf` with the calibration's own datasets and provenance,
// its figure, and the comparison with a design's simulated stack.
#pragma once
#include <string>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/physics/calibrate.hpp"
#include "qdo/runtime/parse.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

// Where the captures came from, for psf.h5's attributes (the folders as the caller named them).
struct CalibrationProvenance {
  std::string source = "calibrate_psf";  // the "source" attribute
  std::string frames_dir, darks_dir, white_dir;
  std::string signal_mask;  // the "signal_mask" attribute: windows and threshold (empty: not written)
};

// DIR/psf.h5: /psf_sensor (r.psf, bands x S x S) and /wavelengths_nm as `qdo psf` writes them (one
// measured point), with /frame_wavelengths_nm, /peak_snr, /noise_dn, /background_dn (bands each),
// /white_channel_gains (3, with whites) and the provenance (files, darks, hot pixels, centre, frame
// size, notes); DIR/psf.png (the stack, a crop of at most 96 px). The folder exists.
void write_calibration_outputs(const std::string& dir, const SystemConfig& cfg, const CalibrationResult& r,
                               const CalibrationProvenance& prov);

// The measured stack (bands x S x S) against the stack of a design (heights_m: N x N metres, N =
// cfg.n) simulated in precision p: DIR/compare.csv (per band: correlation, EE80 of each, centroid
// offset) and compare.png (measured and simulated side by side for up to 8 bands, evenly spaced;
// `design` names the design in the title). Returns the mean correlation over the bands.
double compare_calibration_with_design(Runtime& rt, const SystemConfig& cfg, Precision p, const RealStack& measured,
                                       const Map2D& heights_m, const std::string& design, const std::string& dir);

// ---- qdo calibrate as a library call ----
struct CalibrateRequest {
  SystemConfig cfg;
  std::string frames, darks;   // the folders of PSF frames and dark frames
  CalibrationOptions options;  // white, hot-sigma, min-snr, min-response, floor-sigma, background, centre
  std::string design;          // the design compared with (a run folder's design.h5); empty: none
  Map2D heights;               // its heights, N x N metres (empty without a design)
  Precision precision = Precision::F32;
};
// How the raw point-source frames are reduced, read from the options as a user typed them, shared by
// qdo calibrate and qdo fit --frames: --white, --hot-sigma (> 1, default 8), --min-snr (>= 0,
// default 20), --min-response (in (0, 1]; absent: CalibrationOptions' default, every colour that
// responds at all) and --centre ROW,COL; InputErrors name the option as typed. The other fields of
// opt are left as they are.
void frame_reduction_from_options(const TextOptions& a, CalibrationOptions& opt);
// The options as a user typed them (TextOptions: preset, config, frames, darks, white, design,
// hot-sigma, min-snr, min-response, floor-sigma, background, centre, precision), each checked and
// the design read (InputError naming the option as typed), before any work.
CalibrateRequest calibrate_request_from_options(const TextOptions& a);
// The calibration (calibrate_psf, on the host) and its files in `dir` (write_calibration_outputs);
// the report holds its notes, a summary, the seconds per step and, without a design, the files written.
struct CalibrationRun {
  CalibrationResult result;
  std::string report;
};
CalibrationRun run_calibration(const CalibrateRequest& q, const std::string& dir);
// With a design: compare_calibration_with_design into `dir`, and its report (the mean correlation,
// the files written).
std::string compare_calibration_report(Runtime& rt, const CalibrateRequest& q, const CalibrationResult& r, const std::string& dir);

}  // namespace qdo
