// Geometry and bookkeeping shared by the OpenCL path and the CPU reference: FFT sizes,
// frequency grids, sampling checks, area-resampling weights and the sensor response.
#pragma once
#include <Eigen/Dense>
#include <cstddef>
#include <string>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

// Smallest 2^a 3^b 5^c 7^d >= min_len (radices both clFFT and FFTW handle fast).
std::size_t fast_fft_size(std::size_t min_len);

// Propagation window: the N x N DOE field sits at rows/cols [offset, offset + n) of an
// M x M zero-padded window, M = fast_fft_size(n + 2 * padding_px), offset = (M - n) / 2.
// The optical axis is at window index offset + n/2.
struct PropagationGeometry {
  std::size_t n = 0, m = 0, offset = 0;
  double pitch_m = 0;
  static PropagationGeometry from_config(const SystemConfig& c);
};

// Spatial frequency of FFT bin k of an M-point transform at pitch_m (numpy fftfreq), 1/m.
inline double fft_frequency(std::size_t k, std::size_t m, double pitch_m) {
  const double kk = k < (m + 1) / 2 ? double(k) : double(k) - double(m);
  return kk / (double(m) * pitch_m);
}

// Highest per-axis frequency |f| (1/m) at which the propagator's transfer function is
// sampled at or above Nyquist on the M-point grid: Fresnel: M·pitch / (2 λ |z|) (the chirp's
// phase step between bins reaches π there); angular spectrum: Matsushima's band limit
// 1 / (λ sqrt((2 z / (M pitch))² + 1)). Frequencies above it alias (Fresnel) or are cut (ASM).
double transfer_function_limit_per_m(Propagator p, double wavelength_nm, double z_m, std::size_t m, double pitch_m);

// The smallest padding_px (per side) whose window (PropagationGeometry: M = fast_fft_size(n + 2 p),
// M - n even) samples the propagator's transfer function up to the DOE grid's Nyquist 1 / (2 pitch)
// in every band of cfg at the DOE-sensor distance z_m: transfer_function_limit_per_m >= 0.5 /
// pitch_m (Fresnel: M pitch >= lambda_max z / pitch). cfg's own padding_px is not read. When no
// padding up to the configuration's limit 4 n does, padding_px = 4 n and sampled = false.
struct SampledPadding {
  std::size_t padding_px = 0;
  bool sampled = true;
};
SampledPadding sampled_padding_px(const SystemConfig& cfg, double z_m);

struct BandSampling {
  double wavelength_nm = 0;
  double f_limit_per_m = 0;          // see transfer_function_limit_per_m
  double f_nyquist_per_m = 0;        // 1 / (2 pitch)
  bool undersampled = false;         // f_limit < f_nyquist: part of the band is unreliable
  double aliased_energy_fraction = 0;  // field spectral energy beyond f_limit (either axis)
  double energy_outside_window = 0;  // energy of the propagated field outside the N x N crop
  // The point source's spherical wave on the DOE grid: its local frequency at the aperture rim,
  // r_ap / (λ sqrt(r_ap² + d²)) (0 for a plane wave), and whether it exceeds the grid's Nyquist.
  double source_frequency_per_m = 0;
  bool source_undersampled = false;
  // With object points (config.hpp; -1 / zeros without): the plane's point index in cfg.points(),
  // its distance (inf: plane wave), field angles, and where its chief ray meets the sensor
  // ((-z tan θx, -z tan θy), metres). Its source_frequency_per_m is then the largest per-axis local
  // frequency of the (tilted) wave over the aperture (object_point_frequency_per_m).
  int point = -1;
  double point_distance_m = 0, field_x_deg = 0, field_y_deg = 0, chief_ray_x_m = 0, chief_ray_y_m = 0;
};
// Fills the source fields of every plane from the configuration (planes: designs x points x bands,
// the band grid repeating per design and point).
void check_source_sampling(const SystemConfig& cfg, std::vector<BandSampling>& bands);

struct SamplingReport {
  std::vector<BandSampling> bands;
  // Aliased energy above which a band counts as inaccurately simulated.
  static constexpr double kAliasTolerance = 1e-4;
  bool any_inaccurate() const;
  double worst_aliased_fraction() const;
  double worst_energy_outside() const;
  std::string summary() const;       // one readable paragraph
  // Throws AccuracyError (naming the band, the limit and the fix) if any band is inaccurate.
  void enforce() const;
};

// Area-integration weights for resampling a length-n grid at pitch_in onto a length-s grid
// at pitch_out, both centred on the optical axis (index n/2, resp. s/2). Output pixel o
// receives sum_t w[o*taps + t] * in[start[o] + t]; w is the fraction of the input cell inside
// the output pixel, so a PSF's sum is preserved where the grids overlap. shift_out_px moves the
// content by that many output pixels (the output grid moved by -shift_out_px against the axis):
// output pixel o integrates what pixel o - shift_out_px of the centred grid would, the input's
// cells taken as uniform, as at zero shift.
// Rows and columns may have their own shifts (make_xy): the rows' table is entries [0, s), the
// columns' [col_offset, col_offset + s); col_offset is 0 when both axes share one table (every
// call with equal shifts, bit for bit the one-axis table) and s when the columns' table follows.
struct AreaWeights {
  std::size_t n = 0, s = 0, taps = 0;
  std::size_t col_offset = 0;
  std::vector<int> start;            // s (one table) or 2 s (rows, then columns)
  std::vector<double> w;             // (s or 2 s) x taps, row-major
  static AreaWeights make(std::size_t n, double pitch_in_m, std::size_t s, double pitch_out_m, double shift_out_px = 0);
  // Columns moved by shift_x_px, rows by shift_y_px (output pixels).
  static AreaWeights make_xy(std::size_t n, double pitch_in_m, std::size_t s, double pitch_out_m, double shift_x_px,
                             double shift_y_px);
  // The transpose (maps the length-s grid back onto the length-n grid): n and s swap roles, each
  // axis's table transposed (col_offset becomes n when there are two).
  AreaWeights transposed() const;
};

// The native grid (N at pitch_m) onto the sensor (S at sensor_pitch_m) for cfg: the sensor window
// centred on the optical axis (cfg.aperture_offset_*_m), so the content moves by -offset / sensor
// pitch, plus (extra_x_px, extra_y_px) sensor pixels (a registration).
AreaWeights sensor_weights(const SystemConfig& cfg, double extra_x_px = 0, double extra_y_px = 0);

// The aperture on the DOE grid: N x N transmissions (row-major), sample (i, j) the cell of side
// pitch centred at ((j - N/2) pitch, (i - N/2) pitch). Inclusive / Strict: 1 inside the integer
// radius test (aperture_inside_px2), else 0; Area: the exact area fraction of the cell inside the
// circle of radius aperture_radius() centred at (aperture_offset_x_m, aperture_offset_y_m).
std::vector<double> aperture_transmission(const SystemConfig& cfg);
// A relief moved by (dx, dy) metres against its aperture and sensor (x along columns), exactly:
// the whole-pixel part (round(D / pitch) per axis, D = the move plus the relief's present offset
// -cfg.aperture_offset) moves the height map itself (zero relief brought in from outside the grid,
// every pixel still on its level); the rest, within half a pixel, moves the optical axis the
// other way (aperture_offset_m, with aperture_edge "area"). height_m (N x N, row-major) is moved in
// place; the configuration to simulate it with is returned, validated (InputError, naming
// aperture_offset_m, when the aperture no longer fits the grid). A relief neither moved nor offset
// keeps cfg's edge unless area_edge asks for the area-weighted one anyway (a model continuous in the move).
SystemConfig move_relief(const SystemConfig& cfg, Map2D& height_m, double dx_m, double dy_m, bool area_edge = true);
// The configuration alone of move_relief (the same checks, no map moved).
SystemConfig moved_relief_config(const SystemConfig& cfg, double dx_m, double dy_m, bool area_edge = true);
// The transpose of move_relief's whole-pixel move of a height map: a gradient on the moved map
// (N x N) back onto the map before the move (the pixels moved off the grid get 0).
Map2D move_relief_adjoint(const SystemConfig& cfg, const Map2D& g_moved, double dx_m, double dy_m);

// The area of the rectangle [x0, x1] x [y0, y1] inside the circle of radius r at the origin (closed
// form, any units; empty when x1 <= x0 or y1 <= y0).
double circle_rectangle_area(double r, double x0, double x1, double y0, double y1);

// The sensor response as a 3 x B matrix (rows R, G, B) on the configuration's band grid,
// each row divided by its sum (Eq. 7's normalisation, so a flat spectrum maps to itself).
// cfg.camera is a built-in name ("FLIR_GS3-U3-41S4C") or a CSV path with columns
// wavelength_nm,R,G,B. A table on another band grid is an InputError unless
// cfg.srf_interpolate allows linear interpolation (never extrapolation).
Eigen::MatrixXd sensor_response(const SystemConfig& cfg);
std::vector<std::string> builtin_cameras();

// Refractive index minus one and wavenumber 2π/λ (1/m) per band.
std::vector<double> delta_n_per_band(const SystemConfig& cfg);
std::vector<double> wavenumber_per_band(const SystemConfig& cfg);

}  // namespace qdo
