// A spatially varying capture as a library call (what `qdo simulate --depth` and `--field-grid`
// run): the RGB sensor image of a scene whose PSF varies from pixel to pixel, through VaryingCamera
// (include/qdo/physics/varying.hpp).
//
//   depth  an H x W depth map (metres) beside the scene; each pixel goes to the nearest depth layer
//          in diopters (depth_layer_weights); the design's PSF is computed at the layers some pixel
//          uses only (one batched Simulator pass with on-axis object points), the others are
//          reported as skipped.
//   field  a regular grid of field angles up to the field edge; each point's PSF recentred on the
//          axis (set_shifts) and the image interpolated between neighbouring points (bilinear hats,
//          field_grid_weights); points whose hats miss the scene are not computed. With a rank R:
//          the low-rank form (low_rank_psf, combine_weights).
//
// Three steps. plan_depth_capture / plan_field_capture check every input on the host (depth values
// and size, layers, the field edge against the sampling limit, the points' sampling) and choose the
// components, before any device work. run_varying_capture computes the PSFs of the used components
// and the image, and adds the configuration's noise as the camera adds it (ref::add_noise, the
// camera's counters for scene 0). write_varying_outputs writes the files.
//
// Refusals are InputErrors naming the argument, the value and what is allowed. Each spec carries
// the names its refusals use (InputLabel): the library's argument names by default; a caller such as
// the command line passes its own option names and the values as the user gave them.
#pragma once
#include <cstddef>
#include <functional>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/physics/camera.hpp"
#include "qdo/physics/varying.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

// How a refusal names an input: `name` (the argument), and `text`, the value as the caller received
// it (empty: the library formats the value itself).
struct InputLabel {
  std::string name;
  std::string text;
};

// ---- Depth maps ----

// The built-in chart scene's layered depth (scenes.hpp, the same geometry): row r = 0 .. 3 of
// patches at 2^(r + 2) z (z the DOE-sensor distance: 4 z, 8 z, 16 z, 32 z), the background and the
// white dots at infinity. Metres, s x s, s = cfg.scene_size_px.
Map2D builtin_chart_depth(const SystemConfig& cfg);

// Where a depth map comes from. spec: "builtin" (builtin_chart_depth), a 16-bit PNG (FILE.png:
// code x scale_m_per_code metres, code 0 = infinity) or an HDF5 dataset (FILE[:/KEY], KEY following
// the last ":/"; default /depth_m in metres; /inverse_depth_per_m in diopters, 0 = infinity, as
// depth.h5 holds it, H x W or 1 x H x W).
struct DepthMapSource {
  std::string spec;
  std::optional<double> scale_m_per_code;  // PNG only, in (0, 1e6]; default 0.001 (NaN: refused as not a number)
  InputLabel spec_label{"spec", ""};       // refusals quote `spec` itself
  InputLabel scale_label{"scale_m_per_code", ""};
};
// The depth map, rows x cols metres (> 0 or +inf), read and checked: the scene's size, every value
// (the first bad pixel named); InputError naming spec_label / scale_label otherwise.
Map2D read_depth_map(const DepthMapSource& src, const SystemConfig& cfg, std::size_t rows, std::size_t cols);

// The default layer rule (metres, +inf allowed): the map's distinct values when there are at most
// 8, else 8 layers evenly spaced in diopters between its nearest and farthest values, near to far.
// depth_m: H x W metres, > 0 or +inf. `rule` says which, for the report.
std::vector<double> default_depth_layers(const Map2D& depth_m, std::string& rule);

// ---- Plans (host) ----

struct DepthCaptureSpec {
  Map2D depth_m;                   // rows x cols (the scene's size) metres, each > 0 or +inf
  std::vector<double> layers_m;    // > 0 or +inf, distinct, at most 256; empty: default_depth_layers
  std::string source;              // the depth map's source, for the report (varying.json, depth.h5)
  PsfPlacement placement = PsfPlacement::Source;
  InputLabel depth_label{"depth_m", ""};   // text empty: refusals quote `source`
  InputLabel layers_label{"layers_m", ""};  // text: the layers as given (empty: listed in metres)
};

struct FieldCaptureSpec {
  std::size_t nx = 1, ny = 1;      // grid points along x and y, each in [1, 31]
  // The outermost field angle in degrees, in (0, 89] and within the sampling limit. Empty: the
  // smallest of the scene's half extent on the sensor, a quarter of the N x N window and the
  // sampling limit (max_field_angle_deg, of the "asm" propagator where it reaches further).
  std::optional<double> edge_deg;
  std::size_t rank = 0;            // 0: every computed point; else the low-rank form, in [1, points computed]
  PsfPlacement placement = PsfPlacement::Source;
  InputLabel grid_label{"nx x ny", ""};
  InputLabel edge_label{"edge_deg", ""};
  InputLabel rank_label{"rank", ""};
};

enum class VaryingMode { Depth, Field };

// What a capture computes, decided on the host.
struct VaryingPlan {
  VaryingMode mode = VaryingMode::Depth;
  SystemConfig cfg;                       // the configuration (linear convolution)
  // The used components as object points (one: the pre-object-point form, computed exactly as a
  // configuration with that scene_distance_m); field grids on "asm" where Fresnel refuses a point.
  SystemConfig psf_cfg;
  PsfPlacement placement = PsfPlacement::Source;
  std::size_t rows = 0, cols = 0;         // the scene's size
  std::size_t total = 0;                  // components: depth layers or grid points
  std::vector<std::size_t> used;          // the components some pixel uses, increasing
  RealStack weights;                      // used.size() x rows x cols, row-major
  std::vector<std::pair<long, long>> shifts;  // field: (dy, dx) per used point, recentring its PSF; depth: empty
  // Field: the low-rank form's R, in [1, used.size()] (0: every point). May be set after planning
  // (run_varying_capture checks it again).
  std::size_t rank = 0;
  Map2D layer_map;                        // depth: each pixel's layer in diopters (0 = infinity), rows x cols
  Map2D depth_diopters;                   // depth: the map as read in 1/m (0 = infinity), rows x cols
  std::string depth_source;               // depth: DepthCaptureSpec::source
  std::string summary;                    // one line: the components, used and skipped
  std::string note;                       // empty, or the propagator switch of a field grid
  std::string info_json;                  // varying.json's host part (one JSON object)
};

// The plans, every input checked and every component chosen before any device work. rows x cols:
// the scene's size (depth_m's). The configuration's convolution must be linear.
VaryingPlan plan_depth_capture(const SystemConfig& cfg, const DepthCaptureSpec& spec, std::size_t rows, std::size_t cols);
VaryingPlan plan_field_capture(const SystemConfig& cfg, const FieldCaptureSpec& spec, std::size_t rows, std::size_t cols);

// ---- Device work and outputs ----

struct VaryingCaptureResult {
  RealStack rgb;                  // 3 x rows x cols, noise added, clipped to full scale 1
  RealStack psfs;                 // (used * bands) x S x S, point-major (plane k * bands + b), as computed (not recentred)
  VaryingReport report;           // the varying operator's
  SensorClip clip;                // what the clip to full scale changed
  std::string summary;            // plan.summary, with the low-rank truncation when rank > 0
  std::string sampling_summary;   // the PSF simulation's sampling report
  double psf_seconds = 0, seconds = 0;  // the PSFs; everything (PSFs, image, noise)
  std::string info_json;          // varying.json (one JSON object)
};

// The PSFs of the plan's used components (one batched Simulator pass), the image of `scene`
// (bands x rows x cols, row-major) through them with heights_m (N x N metres, the design), and the
// configuration's noise. say (when set) gets one progress line once the PSFs are computed.
// InputError before any device work for a scene or weights of another shape than planned, a rank
// in a depth plan, or a rank beyond the points computed.
VaryingCaptureResult run_varying_capture(Runtime& rt, const VaryingPlan& plan, const Map2D& heights_m, const RealStack& scene,
                                         Precision precision, const std::function<void(const std::string&)>& say = {});

// DIR/sensor.h5 and sensor.png (the image), scene.png (the scene through the camera's response),
// psf_points.h5 (the computed PSFs, point-major, with each point's inverse distance and angles) and
// psf.png, design.png (heights_m, N x N metres), for a depth plan depth.png and depth.h5 (the map
// and each pixel's layer, in diopters), varying.json. `provenance` is the files' "source" attribute
// (depth.h5's followed by the depth source). The folder exists; the caller claims it.
void write_varying_outputs(const std::string& dir, const VaryingPlan& plan, const VaryingCaptureResult& result,
                           const Map2D& heights_m, const RealStack& scene, const std::string& provenance);

}  // namespace qdo
