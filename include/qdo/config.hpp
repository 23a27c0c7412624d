// The system description: every value of REFERENCE §1 in one validated structure.
// Units are in the names. Loaded from JSON (unknown keys rejected) or from a preset.
#pragma once
#include <cstddef>
#include <string>
#include <vector>

namespace qdo {

enum class Propagator { Fresnel, AngularSpectrum };
enum class ConvolutionMode { Linear, Circular };
// Which DOE samples the circular aperture keeps: r <= R (qdo's default) or r < R (the release's,
// REFERENCE §1: at N = 1024 the release drops the 12 samples at exactly r = (N/2 - 1) pitch).
enum class ApertureEdge { Inclusive, Strict };
// The colour filter mosaic of the built sensor (the raw stage, include/qdo/raw.hpp): None gives
// three full planes; a Bayer pattern names its 2 x 2 cell row by row from pixel (0, 0), e.g.
// RGGB: (0, 0) = R, (0, 1) = G, (1, 0) = G, (1, 1) = B. JSON "cfa": "none" | "rggb" | ...
enum class Cfa { None, RGGB, GRBG, GBRG, BGGR };
std::string to_string(Cfa c);  // "none", "rggb", "grbg", "gbrg", "bggr"

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
  double sensor_distance_m = 0.05;       // DOE to sensor, z
  double aperture_radius_m = 0;          // 0 means the release's (N/2 - 1) * pitch_m
  ApertureEdge aperture_edge = ApertureEdge::Inclusive;  // JSON "aperture_edge": "inclusive" | "strict"
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
  // The sensor as built (raw stage, include/qdo/raw.hpp; not in the design loop). A code value
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
  double h_max_m() const;                // one 2π phase at base_wavelength_nm
  std::size_t sensor_size_px() const;    // round(n * pitch_m / sensor_pitch_m)

  // Checks every field; throws InputError naming the key, the value and what is allowed.
  void validate() const;
};

// Presets: "paper" (REFERENCE §1 values) and "small" (N = 256, z scaled with N so the
// numerical aperture and the transfer-function sampling ratio equal the paper's).
SystemConfig preset_config(const std::string& name);
std::vector<std::string> preset_names();

// JSON I/O. `from_json_text` starts from the preset named by the optional "preset" key
// (default "paper") and overrides with the other keys; unknown keys are rejected.
SystemConfig config_from_json_text(const std::string& text, const std::string& origin = "<json>");
SystemConfig config_from_json_file(const std::string& path);
std::string config_to_json_text(const SystemConfig& c);

}  // namespace qdo
