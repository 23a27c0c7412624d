// The inputs many of qdo's commands share, read from options as a user typed them (TextOptions,
// qdo/runtime/parse.hpp): the configuration (--config or --preset), the scene (--scene, --key,
// --resample-bands), dataset lists (--data), the design's heights (--design, --levels,
// --placement), the PSF source (--psf or --design) and the object points (--object-distances,
// --field-angles). Every refusal is an InputError naming the option as typed ("--levels"), the
// value and what is allowed, before any device work. The qdo tool and Python both read them here.
//
//   scene:   bands x H x W reals, row-major
//   heights: N x N metres, row-major, N = cfg.n
#pragma once
#include <string>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/design/psf_spec.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/runtime/parse.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

// The configuration from --config or --preset (default small), the camera response checked too.
// A configuration of several object points is refused unless allow_points (qdo design: a design
// over a range of points; qdo psf: one batched pass).
SystemConfig config_from_options(const TextOptions& a, bool allow_points = false);
// How far beyond the configuration's DOE-sensor distance a model's window samples the transfer
// function with --model-padding auto: a fitted or as-built z up to 5 % longer stays sampled.
constexpr double kModelPaddingZMargin = 1.05;
// --model-padding of the commands that model a built camera (qdo fit, qdo fabricate): "auto" (the
// default) raises cfg.padding_px, never lowers it, to sampled_padding_px(cfg, kModelPaddingZMargin
// * z_m) (optics.hpp): the window then samples the transfer function in every band, where the
// presets (the paper's ratio) under-sample the long wavelengths; "config" keeps cfg's; an integer
// in [0, 4 n] sets it. Refused naming --model-padding otherwise. Returns a line saying what changed
// ("" when nothing did).
std::string apply_model_padding(SystemConfig& cfg, const TextOptions& a, double z_m);
// --scene builtin (the configuration's chart scene, the default), a cube file (.mat / .h5,
// read_cube with --key) or a folder of PNG bands, checked to have cfg.bands bands: bands x H x W.
// A band axis stored in the file must match cfg's (refused naming both grids; interpolated with
// --resample-bands); the radiance rule (conform_radiance) applies.
RealStack scene_from_options(const SystemConfig& cfg, const TextOptions& a);
// The scene sources of option `name` (comma-separated): dataset names resolved under the data root
// (data_root.hpp), paths checked to exist; an InputError naming --name otherwise. Empty when the
// option is not given and has no default.
std::vector<std::string> scene_paths_from_options(const TextOptions& a, const std::string& name);
// --levels L and --placement: a post-hoc quantizer, active only when --levels is given (--placement
// alone is refused).
struct QuantizerOption {
  bool active = false;
  Quantizer q;
};
QuantizerOption quantizer_from_options(const TextOptions& a);
// --design (lens:NM, flat, or an HDF5 design file matching cfg's grid), quantized by --levels when
// given: N x N metres. `q_out` (when set) gets the quantizer.
Map2D design_heights_from_options(const SystemConfig& cfg, const TextOptions& a, QuantizerOption* q_out = nullptr);
// The PSF of simulate and image, decided and checked before any device work (psf_spec.hpp):
// --psf FILE (the file's stack, checked against the configuration's bands and sensor grid) or
// --design (heights, quantized by --levels when given, simulated once the device is up). Exactly
// one of the two.
PsfInput psf_input_from_options(const SystemConfig& cfg, const TextOptions& a);
// --object-distances (metres > 0, at least 1e-6, or inf) and --field-angles (degrees: A or X:Y,
// comma-separated) into c.object_points: every distance under every angle (distances default to
// the configuration's one distance, angles to 0), each value once, each angle within
// max_field_angle_deg at every distance (the refusal names the limit), at most 4096 points.
// Refused when c already lists points. Nothing changes when neither option is given.
void object_points_from_options(const TextOptions& a, SystemConfig& c);

}  // namespace qdo
