// The system description: every value of REFERENCE §1 in one validated structure.
// Units are in the names. Loaded from JSON (unknown keys rejected) or from a preset.
#pragma once
#include <cstddef>
#include <string>
#include <utility>
#include <vector>

namespace qdo {

enum class Propagator { Fresnel, AngularSpectrum };
enum class ConvolutionMode { Linear, Circular };
// Which DOE samples the circular aperture keeps: r <= R (qdo's default) or r < R (the release's,
// REFERENCE §1: at N = 1024 the release drops the 12 samples at exactly r = (N/2 - 1) pitch), each
// sample whole; or Area: every sample weighted by the exact fraction of its pitch x pitch cell
// inside the circle (a transmission in [0, 1], continuous in the aperture's radius and centre).
enum class ApertureEdge { Inclusive, Strict, Area };
// The colour filter mosaic of the built sensor (the raw stage, include/qdo/physics/raw.hpp): None gives
// three full planes; a Bayer pattern names its 2 x 2 cell row by row from pixel (0, 0), e.g.
// RGGB: (0, 0) = R, (0, 1) = G, (1, 0) = G, (1, 1) = B. JSON "cfa": "none" | "rggb" | ...
enum class Cfa { None, RGGB, GRBG, GBRG, BGGR };
std::string to_string(Cfa c);  // "none", "rggb", "grbg", "gbrg", "bggr"

// One object point (REFERENCE §7): a point source at distance_m in front of the DOE (infinity: a
// plane wave) seen under the field angles (field_x_deg, field_y_deg): it sits at
// (x0, y0) = (d tan θx, d tan θy) and its exact field at the DOE is exp(ik sqrt((x-x0)² + (y-y0)² + d²))
// (for d = inf the plane wave exp(-ik (x α + y β)), (α, β, γ) the unit vector along (tan θx, tan θy, 1)).
// A thin lens images it, inverted, at (-z tan θx, -z tan θy) on the sensor (the chief ray through the
// DOE centre), whatever d is.
struct ObjectPoint {
  double distance_m = 1.0;  // > 0, or +infinity (JSON "inf")
  double field_x_deg = 0;   // field angle about the y axis: the point at x0 = d tan θx
  double field_y_deg = 0;
  bool on_axis() const { return field_x_deg == 0 && field_y_deg == 0; }
  bool at_infinity() const;
};
// The product of a distance list and a field-angle list, distance-major: point
// i * angles.size() + j is at distances_m[i] under angles_deg[j] = {θx, θy}.
std::vector<ObjectPoint> object_point_grid(const std::vector<double>& distances_m,
                                           const std::vector<std::pair<double, double>>& angles_deg);

struct SystemConfig {
  std::string preset = "custom";        // name of the preset it came from, informational
  // DOE grid: N x N samples at pitch_m, sample (i, j) at ((j - N/2) * pitch, (i - N/2) * pitch).
  std::size_t n = 1024;
  double pitch_m = 4e-6;
  // Spectral samples: wavelength_start_nm + k * wavelength_step_nm, k = 0 .. bands-1.
  double wavelength_start_nm = 400;
  double wavelength_step_nm = 10;
  std::size_t bands = 31;
  // On-axis point source distance; scene_at_infinity = true means a plane wave
  // (JSON: "scene_distance_m": "inf").
  double scene_distance_m = 1.0;
  bool scene_at_infinity = false;
  // Object points of the PSF stack: empty (the default) means one on-axis point
  // at scene_distance_m, computed exactly as before object points existed. Non-empty: the PSF
  // chain computes points x bands planes, point-major (plane p * bands + b), and
  // scene_distance_m no longer enters the PSF. JSON: "object_points": [[d_m, θx_deg, θy_deg], ...]
  // with d a number of metres or "inf" (an explicit list; object_point_grid makes the product of a
  // distance list and an angle list). Off-axis points must be within the sampling
  // (object_point_limit below): validate() refuses the others, naming the point and the limit.
  std::vector<ObjectPoint> object_points;
  double sensor_distance_m = 0.05;       // DOE to sensor, z
  double aperture_radius_m = 0;          // 0 means the release's (N/2 - 1) * pitch_m
  ApertureEdge aperture_edge = ApertureEdge::Inclusive;  // JSON "aperture_edge": "inclusive" | "strict" | "area"
  // The optical axis against the DOE grid: the aperture's centre, the on-axis object point (every
  // object point moves with it) and the sensor window's centre sit at (x, y) metres from the grid's
  // centre sample (N/2, N/2), x along columns. The relief therefore sits at (-x, -y) against the
  // aperture and the sensor: a relief a fab moved by (dx, dy) against the aperture is
  // aperture_offset = (-dx, -dy), with every relief pixel still on its level. Non-zero needs
  // aperture_edge "area" (a sub-pixel centre has no whole-sample edge) and a circle inside the DOE
  // grid; the radial path refuses it. JSON "aperture_offset_m": [x, y], written only when non-zero.
  double aperture_offset_x_m = 0, aperture_offset_y_m = 0;
  std::string material = "OHARA_SK1300";
  double base_wavelength_nm = 700;       // h_max = base_wavelength / (n(base) - 1)
  double base_plate_m = 2e-3;            // glass under the relief (fabrication files only)
  Propagator propagator = Propagator::Fresnel;
  std::size_t padding_px = 256;          // zero padding per side before propagation (N/4 default)
  bool strict_sampling = false;          // refuse under-sampled transfer functions
  // Sensor: square pixels of sensor_pitch_m; PSF resampled onto it by area integration.
  double sensor_pitch_m = 8e-6;
  std::size_t scene_size_px = 512;       // size of built-in scenes (rows = cols)
  std::string camera = "FLIR_GS3-U3-41S4C";  // built-in name, or a CSV path (wavelength_nm,R,G,B)
  bool srf_interpolate = false;          // allow linear interpolation of a CSV SRF onto the band grid
  ConvolutionMode convolution = ConvolutionMode::Linear;
  double read_noise_sigma = 0.0;         // Gaussian read noise, in units of full scale
  double full_well_photons = 0.0;        // photons at value 1.0 for shot noise; 0 disables shot noise
  unsigned long long noise_seed = 0;
  // The sensor as built (raw stage, include/qdo/physics/raw.hpp; not in the design loop). A code value
  // in DN lies in [0, white_level_dn()]; the linear signal v (1.0 = full well) becomes
  // black_level_dn + gain * v * (white_level_dn() - black_level_dn) before clipping and rounding.
  Cfa cfa = Cfa::None;
  double black_level_dn = 0.0;           // code of a dark pixel, DN; below white_level_dn()
  double gain = 1.0;                     // dimensionless analog gain: gain 1 puts the full well at the white level
  std::size_t bit_depth = 0;             // 0: no quantization (DN = full-scale units, white 1); else 8 .. 16 bits

  // The largest code value: 2^bit_depth - 1 DN, or 1 when bit_depth = 0 (continuous codes).
  double white_level_dn() const;

  // Derived quantities.
  std::vector<double> wavelengths_nm() const;
  double aperture_radius() const;        // metres, resolved default
  // The aperture test on the DOE grid: sample (i, j), at integer offsets (di, dj) = (i - N/2,
  // j - N/2) pixels, is inside when di² + dj² <= aperture_inside_px2(). Half an integer, so the
  // comparison is exact in float32 as well; it encodes aperture_edge (ties at r = R in or out).
  double aperture_inside_px2() const;
  bool aperture_offset() const { return aperture_offset_x_m != 0 || aperture_offset_y_m != 0; }
  double h_max_m() const;                // one 2π phase at base_wavelength_nm
  std::size_t sensor_size_px() const;    // round(n * pitch_m / sensor_pitch_m)
  // The object points of the PSF stack: object_points, or the one on-axis point at
  // scene_distance_m (infinity when scene_at_infinity) when that list is empty.
  std::vector<ObjectPoint> points() const;
  std::size_t point_count() const { return object_points.empty() ? 1 : object_points.size(); }

  // Checks every field; throws InputError naming the key, the value and what is allowed.
  void validate() const;
};

// Sampling of an object point on this configuration's grids (REFERENCE §7), shared by validate(),
// the sampling report (optics.hpp) and the tests.
// The largest per-axis local spatial frequency (1/m) of the point's field over the DOE aperture at
// wavelength_nm: max over the aperture rim of |x - x0| / (λ R) and |y - y0| / (λ R),
// R = sqrt((x - x0)² + (y - y0)² + d²) (the plane wave: |α| / λ, |β| / λ).
double object_point_frequency_per_m(const SystemConfig& c, const ObjectPoint& p, double wavelength_nm);
// Where the chief ray of the point meets the sensor: (-z tan θx, -z tan θy), metres.
std::pair<double, double> chief_ray_image_m(const SystemConfig& c, const ObjectPoint& p);
// Why an off-axis point is beyond what the grids support, or "" when it is supported (on-axis
// points always are: their sampling is reported, and enforced by strict_sampling, as before):
//  - its field at the DOE aliases: object_point_frequency_per_m at the shortest band > 1 / (2 pitch);
//  - its chief-ray image lies outside the N x N window (|z tan θ| > N pitch / 2 on either axis):
//    the PSF is reported on the fixed window centred on the optical axis;
//  - with the Fresnel propagator, the paraxial transfer function moves the chief ray by
//    z |tan θ - sin θ| (it lands at z sin θ instead of z tan θ): more than a tenth of a sensor pixel
//    is refused (use "propagator": "asm", the band-limited angular spectrum).
std::string object_point_limit(const SystemConfig& c, const ObjectPoint& p);
// The largest field angle (degrees, on one axis, the other 0) object_point_limit accepts at
// distance_m: what the refusals name as the limit. 0 when no off-axis angle is supported.
double max_field_angle_deg(const SystemConfig& c, double distance_m);

// The configuration of object point p of c.points() alone: an on-axis point becomes
// scene_distance_m / scene_at_infinity with an empty object_points (the pre-object-point form: it
// computes bit-identically to a configuration written that way, and the radial path takes it); an
// off-axis point stays a one-entry object_points list. InputError when p >= c.point_count().
SystemConfig point_config(const SystemConfig& c, std::size_t p);

// Presets: "paper" (REFERENCE §1 values) and "small" (N = 256, z scaled with N so the
// numerical aperture and the transfer-function sampling ratio equal the paper's).
SystemConfig preset_config(const std::string& name);
std::vector<std::string> preset_names();

// JSON I/O. `from_json_text` starts from the preset named by the optional "preset" key
// (default "paper"; the result's preset field is then "custom") and overrides with the other
// keys; unknown keys are rejected.
SystemConfig config_from_json_text(const std::string& text, const std::string& origin = "<json>");
SystemConfig config_from_json_file(const std::string& path);
std::string config_to_json_text(const SystemConfig& c);

}  // namespace qdo
