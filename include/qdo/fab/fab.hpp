// From design to fab: lithography mask sets (GDSII + manifest), fabrication-constraint checks,
// reconstruction of the height map from the masks, and Monte Carlo tolerance analysis.
//
// Heights. A design's height map H (N x N, metres) is the glass relief above the base plate
// (REFERENCE §1). The blank's unetched surface sits at the highest level, top = max_l H_l; every
// pixel is etched by e = top - H from that surface. (REFERENCE's "etch depth = h_max - H" differs
// by the constant h_max - top: a uniformly thinner relief layer, which changes only the constant
// phase.) The manifest lists both.
//
// Schemes (REFERENCE §6):
//   binary    k masks with etch depths D_j; a level's etch is the sum of the depths of the masks
//             open over it. Either "index-coded" (L = 2^k levels in the design's table order,
//             level l etched by the masks j whose bit j of l is 0, D_j = H_{L-1} - H_{L-1-2^j}:
//             uniform levels, QDO+M designs) or "multiples of d" (every etch a multiple m_l of
//             the smallest step d, D_j = 2^j d, level etched by the masks of m_l's set bits).
//             Levels that are neither are rejected, naming the first offending level.
//   nested    L - 1 masks for L used levels, sorted by height descending H_(0) > H_(1) > ...:
//             mask m (m = 1..L-1) opens every pixel at H_(m) or below and etches the free step
//             H_(m-1) - H_(m); the openings nest (each inside the previous).
//   greyscale one layer per used level (the pixels at that level) with its total etch depth and
//             a relative exposure dose from a calibration curve (depth_nm -> dose CSV; default a
//             linear placeholder dose = e / e_max, to be replaced by the fab's curve).
//
// GDSII (qdo/fab/gds.hpp): 1 nm database unit, 1 µm user unit; structure "DOE"; mask m on layer
// m + 1 (datatype 0) with polygons = the open (etched) regions, i.e. dark-field masks for a
// positive resist; alignment crosses on layer 254; the aperture outline (a filled polygon
// approximating the circle) on layer 255. Coordinates: the optical axis (sample (N/2, N/2)) at
// the origin; pixel (row i, col j) covers x in [(j - N/2 - 1/2) p, (j - N/2 + 1/2) p], y in
// [(i - N/2 - 1/2) p, (i - N/2 + 1/2) p], p the pitch in nm (must be an even integer so edges lie
// on the 1 nm grid). y grows with the row index: a GDS viewer (y up) shows the map flipped
// vertically with respect to the PNG previews (row 0 at the top).
#pragma once
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/fab/gds.hpp"
#include "qdo/data/io.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/decode/testset.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo::fab {

enum class Scheme { Binary, Nested, Greyscale };
Scheme scheme_from_string(const std::string& s);
std::string to_string(Scheme s);

constexpr int kMarkLayer = 254;      // alignment crosses
constexpr int kApertureLayer = 255;  // aperture outline
constexpr int kMaxMaskLayers = 253;  // mask layers 1..253

struct Constraints {
  double min_feature_um = 1.0;       // narrowest drawn feature and narrowest gap per mask (µm); 0: off
  int max_levels = 0;                // most used levels; 0: the scheme's (binary 16, nested 16, greyscale 253)
  double max_height_nm = 0;          // etchable range of H: [0, max_height_nm]; 0: h_max
  double level_tolerance_nm = 1e-3;  // a height equals a level, or a sum of depths, within this
};

struct Level {
  int index = 0;                     // position in the design's level table (/levels_m order)
  double height_m = 0;               // H, relief above the base plate
  double etch_depth_m = 0;           // top - H
  std::size_t pixels = 0;            // pixels at this level (0: listed, not fabricated)
  std::vector<int> masks;            // masks (indices into MaskPlan::masks) open over it
};

struct Mask {
  int layer = 0;                     // GDS layer
  std::string name;
  double etch_depth_m = 0;           // binary / nested: depth this etch adds; greyscale: the level's total etch
  double relative_dose = 0;          // greyscale only
  std::vector<std::uint8_t> drawn;   // N x N, 1 where open (drawn polygons, etched)
  std::size_t pixels = 0;
};

struct MaskPlan {
  Scheme scheme = Scheme::Binary;
  std::string method;                // binary: "index-coded" or "multiples of d"; else the scheme name
  std::size_t n = 0;
  double pitch_m = 0;
  std::int64_t pitch_nm = 0;
  double h_max_m = 0;
  double top_m = 0;                  // the unetched surface (highest level)
  std::vector<Level> levels;         // every entry of the level table, in table order
  std::vector<std::int32_t> level_of_pixel;  // N x N, index into levels
  std::vector<Mask> masks;
};

// Checks the design against the scheme and the constraints and plans the masks; writes nothing.
// Every violation is an InputError naming the offending level (index and height), mask, or pixel
// region (row, col): heights that are not level heights, levels outside the etchable range, more
// levels than the scheme allows, binary schemes for levels that are not subset sums, features or
// gaps below the minimum size. Designs without /levels_m use their distinct heights as levels.
// dose_curve: greyscale calibration (etch depth nm, relative dose) pairs, increasing in depth;
// empty: linear.
MaskPlan plan_masks(const Design& d, const SystemConfig& cfg, Scheme scheme, const Constraints& c,
                    const std::vector<std::pair<double, double>>& dose_curve = {});

// Height map (metres) and level index map from a plan's depths and a set of drawn masks (one N x N
// bitmap per plan mask, in plan order): H = top - sum of the depths of the open masks (binary,
// nested) or top - the depth of the covering layer (greyscale). A pixel whose mask combination
// is not a level's gets level -1.
struct Reconstruction {
  Map2D height_m;
  std::vector<std::int32_t> level_of_pixel;
};
Reconstruction reconstruct(const MaskPlan& plan, const std::vector<std::vector<std::uint8_t>>& drawn);

// Reads an export folder back (manifest.json + masks.gds with the project's GDSII reader) and
// rebuilds the height map and level map from the polygons and the manifest's depths only.
Reconstruction reconstruct_export(const std::string& dir);

struct ExportOptions {
  Scheme scheme = Scheme::Binary;
  Constraints constraints;
  std::string dose_curve_csv;        // greyscale: CSV with columns depth_nm, dose
  std::string out;                   // folder (created)
  std::map<std::string, std::string> provenance;  // source, run, mode, levels, ...
  double mark_arm_um = 100, mark_width_um = 10, mark_margin_um = 200;
  std::size_t aperture_vertices = 1024;
};
struct ExportResult {
  MaskPlan plan;
  std::size_t polygons = 0, vertices = 0;     // mask layers only
  double max_height_error_nm = 0;             // GDS read back vs the design
  std::vector<std::string> files;
};
// Plans (all checks first), then writes OUT/masks.gds, manifest.json, manifest.md,
// mask_L<layer>.png (white = open), heights_from_masks.png; reads the GDS back and verifies the
// reconstructed level map equals the design's (qdo::Error otherwise).
ExportResult export_design(const Design& d, const SystemConfig& cfg, const ExportOptions& o);

// --- Tolerance analysis ------------------------------------------------------------------------

// One fabrication realisation of a mask plan. Per mask: an etch depth error (added to its
// depth) and a lateral shift (metres, x = column direction, y = row direction); for all masks an
// edge blur (Gaussian sigma, metres, on the mask's open region: sloped / rounded edges); per
// DOE pixel a height noise draw (uniform in [-height_noise_m, height_noise_m], seeded).
struct Perturbation {
  std::vector<double> depth_error_m, shift_x_m, shift_y_m;  // one per mask (empty: zeros)
  double edge_blur_m = 0;
  double height_noise_m = 0;
  std::uint64_t noise_seed = 0;
};
// The fabricated height map (N x N): every mask is rendered on a grid `oversample` times finer
// (its shifted, blurred open region as area fractions in [0, 1]), the etch composed there, and
// the change against the nominal etch area-averaged back to the DOE pitch: H = H_design + ΔH
// (+ noise). With no errors, H equals the design bit for bit. Heights are finally offset by a
// constant, when needed, to stay >= 0 (a constant height only adds a constant phase).
Map2D perturbed_heights(const MaskPlan& plan, const Map2D& design_height_m, const Perturbation& p,
                        std::size_t oversample = 4);

// --- The camera as built, for a simulation of the built camera ----------------------------------

// One fabricated camera (`qdo fabricate`; EXPERIMENTS "The built camera, in simulation"): the
// design's masks made with one draw of the tolerance study's errors (trial `trial` of
// `qdo tolerance` with the same seed, scheme and sizes: per mask an etch depth error uniform in
// [-etch_depth_error_m, etch_depth_error_m], per mask after the first an overlay shift uniform in
// [-overlay_m, overlay_m] per axis; perturbed_heights with `oversample`), then the whole relief
// moved against the aperture by (offset_x_m, offset_y_m) (x = column direction; exactly, as qdo
// fit's model: optics.hpp move_relief, whole pixels in the map with zero relief brought in, the
// rest as the optical axis moved the other way; the as-built aperture is area-weighted,
// aperture_edge "area") and the DOE-sensor distance changed by sensor_distance_error_m (an
// assembly error).
struct AsBuiltOptions {
  std::string scheme = "auto";        // binary | nested | greyscale | auto (binary when possible, else nested)
  double etch_depth_error_m = 20e-9;  // REFERENCE §6
  double overlay_m = 0.5e-6;
  double edge_blur_m = 0;
  std::uint64_t seed = 0;
  std::size_t trial = 0;
  std::size_t oversample = 4;
  double offset_x_m = 0, offset_y_m = 0;
  double sensor_distance_error_m = 0;
  // The as-built configuration's padding_px, its model's window (unset: the design's; qdo
  // fabricate sets it by --model-padding, option_inputs.hpp apply_model_padding).
  std::optional<std::size_t> padding_px;
};
struct AsBuiltCamera {
  Design design;                        // the as-built relief (N x N, metres); levels_m empty (edges are not on levels)
  SystemConfig cfg;                     // the as-built geometry (sensor_distance_m, aperture_edge and aperture_offset_m changed)
  MaskPlan plan;
  std::string scheme_note;
  std::vector<double> depth_error_m, shift_x_m, shift_y_m;  // the draws, one per mask
  // Per design level: its design height less the depth errors of the masks open over it (the
  // constant perturbed_heights may add to keep the relief >= 0 left out: a piston; edges blurred
  // by overlay are not levels).
  std::vector<double> level_height_m;
};
// InputError (naming the option) for negative sizes, an offset beyond the grid, a distance error
// that makes z <= 0, a design that is not on cfg's grid or cannot be planned in the scheme.
AsBuiltCamera fabricate(const Design& d, const SystemConfig& cfg, const AsBuiltOptions& o);

struct ToleranceOptions {
  std::string run;                   // a run folder of qdo design
  std::string scheme = "auto";       // binary | nested | greyscale | auto (binary when possible, else nested)
  double etch_depth_error_m = 20e-9; // per mask, uniform in [-S, S]            (REFERENCE §6: ±20 nm)
  double overlay_m = 0.5e-6;         // per mask after the first, per axis, uniform in [-S, S] (§6: 0.5 µm)
  double edge_blur_m = 0;            // Gaussian sigma of mask edges
  double height_noise_m = 0;         // per pixel, uniform in [-S, S]
  std::size_t trials = 16;
  std::uint64_t seed = 0;
  std::size_t oversample = 4;
  bool per_source = true;            // also run each error source alone
  std::vector<std::string> data;     // test scenes; empty: the held-out synthetic scenes of qdo eval
  std::string data_format = "auto";
  std::size_t synthetic_scenes = 6;
  double noise_sigma = -1;           // measurement noise; < 0: the run's decoder sigma
  Precision precision = Precision::F32;
  std::string out;                   // empty: no files
  bool save_psfs = false;            // also OUT/psfs.h5: the sensor PSF stack of every trial
  bool quiet = true;
};

using Metrics = testset::Scores;  // the six metrics of the shared test-set evaluation
struct Trial {
  std::string scenario;              // all | etch depth | overlay | edge blur | height noise
  std::size_t index = 0;
  std::vector<double> depth_error_m, shift_x_m, shift_y_m;
  double height_rms_change_m = 0;    // RMS of H_trial - H_design over the map
  double psf_rel_change = 0;         // ||psf - psf_nominal|| / ||psf_nominal|| (sensor PSF stack)
  Metrics calibrated;                // Wiener decoder rebuilt for the fabricated DOE's PSF
  Metrics nominal_decoder;           // Wiener decoder of the nominal design (errors unknown)
};
struct Stat {
  double mean = 0, std = 0, min = 0, max = 0;
};
struct ScenarioSummary {
  std::string scenario;
  std::size_t trials = 0;
  std::map<std::string, Stat> calibrated, nominal_decoder;  // keyed by metric name (psnr_db, ...)
};
struct ToleranceResult {
  MaskPlan plan;
  Metrics nominal;                   // the undisturbed design: equals qdo eval's matched metrics
  std::vector<Trial> trials;
  std::vector<ScenarioSummary> summary;
};
// Monte Carlo over fabrication errors of a run's design (see Perturbation): for each trial the
// sensor PSF stack and the reconstruction metrics on the test scenes, with the same scenes,
// noise and decoder as qdo eval (so the zero-error trial reproduces its metrics exactly). The
// draws of trial t depend only on (seed, t), so a source-alone trial t uses the draws of the
// combined trial t. Writes OUT/tolerance.csv, tolerance.json, tolerance.md and plots (and, with
// save_psfs, OUT/psfs.h5: /psf_nominal and /psf_<scenario>_<trial>, bands x S x S each).
ToleranceResult tolerance_analysis(Runtime& rt, const ToleranceOptions& o);

}  // namespace qdo::fab
