// `qdo eval-points` as a library call: what a design does against object distance
// and field angle, and its valid field of view.
//
// Per distance d (on axis, the run's propagator): the design's PSF at d, the test patches imaged
// through it (testset::PatchCamera, the run's decoder noise as `qdo eval` draws it) and
// reconstructed by a closed-form decoder (Wiener by default) built (a) for the nominal PSF, at the
// configuration's scene distance ("mismatch": a camera focused there looking at an object at d) and
// (b) for the PSF at d ("matched": the best the optics allow at d). The depth of field is the
// distance range around the nominal where the mismatch PSNR stays within dof_margin_db of the
// nominal's.
//
// Per field angle θ (along x, at the nominal distance, the angular-spectrum propagator: a Fresnel
// run is switched to "asm" and the result says so; the on-axis reference is computed the same way):
// the off-axis PSF recentred on its chief ray (point_psf.hpp; the part the shift brings in from
// outside the simulated window, where nothing is known, is taken from the on-axis PSF, so the error
// measures the change of shape, and energy_lost how much of the PSF the window missed), the patches
// imaged through it, the
// model error e(θ) = ||I_θ - I_0|| / ||I_0|| against the shift-invariant model's image I_0 (the
// on-axis PSF; norms over every noiseless image pixel of every patch), and the reconstruction with
// the on-axis decoder. The valid field of view is the largest angle up to which e stays within
// fov_tolerance (linear interpolation between samples).
//
// Stacks: every PSF here is bands x S x S (S = cfg.sensor_size_px(), axis at (S/2, S/2)), row-major.
#pragma once
#include <cstddef>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/decode/decoder_spec.hpp"
#include "qdo/runtime/parse.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

struct EvalPointsOptions {
  std::string run;                    // the run folder (config.json, prior.h5, design.h5)
  // The design evaluated in place of RUN/design.h5, a PSF spec's design (psf_spec.hpp: lens:NM,
  // flat or a design .h5, N x N at the run's pitch); empty: the run's.
  std::string design_file;
  // The nominal distance (metres, > 0 or +infinity): the decoder of the mismatch rows is built for
  // the PSF there, and the field angles are evaluated there. NaN (the default): the run's one object
  // point's distance when its configuration lists exactly one, else its scene_distance_m (or
  // infinity with scene_at_infinity); a run over several points has its scene distance.
  double nominal_m = std::numeric_limits<double>::quiet_NaN();
  std::vector<double> distances_m;    // > 0 or +infinity; empty: default_distances_m()
  std::vector<double> angles_deg;     // in [0, the sampling limit]; empty: 0 .. the field edge in angle_steps steps
  std::size_t angle_steps = 8;        // default angle grid: angle_steps + 1 angles, 1 .. 1000
  std::vector<std::string> data;      // test scenes; empty: synthetic held-out scenes (qdo eval's)
  std::string data_format = "auto";
  std::size_t synthetic_scenes = 6;
  double fov_tolerance = 0.05;        // largest model error e(θ) inside the valid field of view, in (0, 10]
  double dof_margin_db = 1.0;         // PSNR drop from the nominal that bounds the depth of field, in (0, 100]
  double noise_sigma = -1;            // < 0: the run's decoder sigma
  std::optional<DecoderSpec> decoder_kind;  // empty: wiener; a decoder trained with the optics is refused
  Precision precision = Precision::F32;     // of the PSF simulation (qdo eval's default)
  std::string out;                    // output folder (the caller claims it); empty: nothing written
  bool progress = true;               // one line per point on stdout
};
// 0.3, 0.5, 0.7, 1, 1.5, 2, 3, 5, 10, inf (metres).
std::vector<double> default_distances_m();

// Mean and spread (min .. max over the per-scene means) of one metric.
struct Spread {
  double mean = 0, min = 0, max = 0;
};
struct PointQuality {
  Spread psnr_db, ssim, sam_rad;
};
struct DistanceRow {
  double distance_m = 1;  // +infinity: a plane wave
  PointQuality mismatch;  // decoder for the nominal PSF
  PointQuality matched;   // decoder refit to this distance's PSF
};
struct AngleRow {
  double angle_deg = 0;
  double model_error = 0;   // ||I_θ - I_0|| / ||I_0|| over the noiseless images
  double energy_lost = 0;   // largest fraction of a band's PSF moved out of the window by the recentring
  PointQuality on_axis_decoder;
};
struct EvalPointsResult {
  double nominal_distance_m = 1;  // EvalPointsOptions::nominal_m as resolved (+infinity: at infinity)
  std::vector<DistanceRow> distances;  // ascending, +infinity last; includes the nominal
  std::size_t nominal_index = 0;
  double nominal_psnr_db = 0;          // mismatch (= matched) PSNR at the nominal distance
  // Depth of field: near and far ends (metres, the far one may be +infinity), interpolated in 1/d
  // between the last sample within the margin and the first beyond; *_open when the sweep's
  // end was still within it (the true end lies beyond the sampled range).
  double dof_near_m = 0, dof_far_m = 0;
  bool dof_near_open = false, dof_far_open = false;

  std::vector<AngleRow> angles;        // ascending, starting at 0
  bool switched_to_asm = false;        // the run's propagator was Fresnel
  double window_edge_deg = 0;          // atan(S sensor_pitch / 2 / z)
  double sampling_edge_deg = 0;        // max_field_angle_deg at the nominal distance (asm)
  double field_edge_deg = 0;           // min of the two
  std::string field_edge_binds;        // "sensor window" or "sampling"
  double fov_half_deg = 0, fov_full_deg = 0;
  std::string fov_limited_by;          // "tolerance", "sensor window", "sampling" or "angles sampled"
  std::string decoder;                 // the decoder's spec
  double noise_sigma = 0;
  std::size_t patches = 0, scenes = 0;
};

// The valid field of view (half-angle, degrees) of a sampled model error: angles ascending from
// 0, errors[0] = 0. The first sample with errors[k] > tolerance ends it at the linear
// interpolation between samples k - 1 and k (*exceeded = true); if none does, it is the last
// angle (*exceeded = false). InputError for mismatched or unsorted inputs.
double valid_fov_deg(const std::vector<double>& angles_deg, const std::vector<double>& errors, double tolerance,
                     bool* exceeded = nullptr);
// The depth of field around sample `nominal` of psnr_db (distances ascending, +infinity allowed
// last): the ends where psnr drops below psnr_db[nominal] - margin_db, interpolated linearly in
// 1/d; an end whose side stays within the margin to the sweep's end is that end, with *_open.
struct DepthOfField {
  double near_m = 0, far_m = 0;
  bool near_open = false, far_open = false;
};
DepthOfField depth_of_field(const std::vector<double>& distances_m, const std::vector<double>& psnr_db, std::size_t nominal,
                            double margin_db);

// The checks of everything before any device work (InputError naming the option, the value and
// the limit): the run folder, the design file, distances (> 0 or inf, no repeats, at most 200),
// angles (>= 0, within the sampling limit at the nominal distance, which is named), tolerances.
void check_eval_points(const EvalPointsOptions& o);

// The whole evaluation; with o.out set, writes OUT/points.json, points.csv, quality_vs_distance.png,
// quality_vs_angle.png, psf_vs_distance.png and psf_vs_angle.png (each written, then renamed).
EvalPointsResult evaluate_points(Runtime& rt, const EvalPointsOptions& o);

// qdo eval-points' options as a user typed them (TextOptions: the run is `run`; design, distances,
// nominal, angles, angle-steps, data, synthetic-scenes, fov-tolerance, dof-margin-db, noise-sigma,
// decoder-kind, precision, out), each parsed (InputError naming the option as typed) and then
// checked with check_eval_points, before any output folder or device.
EvalPointsOptions eval_points_options_from_options(const std::string& run, const TextOptions& a);
// The report: the distance table (mismatch and matched PSNR), the depth of field, the angle table
// (model error, PSNR, energy lost), the field edge and what binds it, the valid field of view and
// the files written. Lines end with "\n".
std::string eval_points_report(const EvalPointsOptions& o, const EvalPointsResult& r);

}  // namespace qdo
