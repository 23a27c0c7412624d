// DOE height maps: parameterizations, designs and the quantizer of REFERENCE §2, on the host
// (src/physics/doe_reference.cpp) and on the device (DoeStage, kernels/doe.cl, src/physics/doe.cpp).
// Heights are the glass relief H above the base plate, in metres, bounded to [0, h_max];
// normalised height u = H / h_max. Grid: N x N, sample (i, j) (row, col) sits at
// ((j - N/2) * pitch, (i - N/2) * pitch), row-major.
#pragma once
#include <CL/opencl.hpp>

#include <cstddef>
#include <string>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

enum class Parameterization { Full2D, Radial, Quad };
Parameterization parameterization_from_string(const std::string& s);

// Number of free parameters: Full2D N*N (row-major), Radial N/2 (ring k holds pixels with
// k <= r/pitch < k+1, r measured from sample (N/2, N/2); pixels with r >= N/2 take the last
// ring), Quad (N/2)*(N/2) (quarter (a, b) with a = min(|i - N/2|, N/2 - 1), likewise b).
std::size_t parameter_count(Parameterization p, std::size_t n);
// Expands `params` (layout above) into the N x N map; each value is clamped to [0, h_max_m].
Map2D expand_parameters(Parameterization p, const std::vector<double>& params, std::size_t n, double h_max_m);

// Level placement of the uniform quantizer with L levels:
//  Inclusive (the release): u_k = k / (L - 1), k = 0..L-1 (0 and h_max both levels);
//  Wrapped (textbook multi-level DOE): u_k = k / L, k = 0..L-1 (u near 1 wraps to level 0).
enum class Placement { Inclusive, Wrapped };
Placement placement_from_string(const std::string& s);
std::string to_string(Placement p);

struct Quantizer {
  int levels = 4;                      // L >= 2
  Placement placement = Placement::Inclusive;
  // Adaptive per-level offsets a_l (QDO+A, release convention): level l sits at
  // (l + 0.5 a_l) / (L - 1) [Inclusive] or (l + 0.5 a_l) / L [Wrapped]; a_0 is fixed at 0.
  // Empty means all zero. Size L when given; a_l must lie in [-1, 1] ([-0.2, 0.2] when L = 2).
  // The pinned level's offset is 0 (pinned_level()).
  std::vector<double> offsets;
  // Which end of the ladder is fixed: level 0 (H = 0, qdo's convention) or, with pin_top, level
  // L - 1 (H = h_max). The release's u is an etch depth (u_release = 1 - u) and it fixes its level
  // 0, the unetched surface: on qdo's relief axis that is the top level.
  bool pin_top = false;
  int pinned_level() const { return pin_top ? levels - 1 : 0; }
  // Explicit normalised level heights u_l (size L), overriding placement values and offsets
  // for the level *values* (the index still comes from the uniform grid of `placement`): for
  // level sets that are not uniform plus offsets, e.g. subset sums of binary-mask etch depths.
  // Empty means unused. Values must be finite.
  std::vector<double> level_table;

  void validate() const;
  // Index of the level nearest in the uniform grid (round half up: floor(x + 0.5)).
  int level_index(double u) const;
  // Normalised height of level l, offsets included.
  double level_value(int l) const;
  // Quantized normalised height Q(u).
  double quantize(double u) const { return level_value(level_index(u)); }
  // All L level heights in metres.
  std::vector<double> level_heights_m(double h_max_m) const;
};

// Alpha-blended heights (Eq. 8): H = alpha * h_max * Q(H_f / h_max) + (1 - alpha) * H_f,
// element-wise over an N x N map.
Map2D quantize_heights(const Map2D& h_full_m, double h_max_m, const Quantizer& q, double alpha = 1.0);

// Cubic alpha schedule (Eq. 10): 0 for s <= t0, 1 - ((t1 - s)/(t1 - t0))^3 for t0 < s <= t1, 1 after.
double alpha_schedule(double step, double t0, double t1);

// Quantization deviation (Table 2): mean |H_q - H_f| in metres over the map.
double quantization_deviation_m(const Map2D& h_q, const Map2D& h_f);

// A diffractive lens for `design_wavelength_nm` that images the on-axis source at the scene
// distance onto the sensor at sensor_distance_m: phase -k[(sqrt(r²+d²) - d) + (sqrt(r²+z²) - z)]
// (exact; the first term is dropped for a source at infinity), wrapped to [0, 2π) and
// converted to relief with the material's index at the design wavelength.
Map2D lens_design(const SystemConfig& cfg, double design_wavelength_nm);
// A flat (zero-height) design.
Map2D flat_design(const SystemConfig& cfg);

// The DOE stage on the device (kernels/doe.cl): height maps into a device buffer of
// designs x N x N reals of the precision (row-major, map d at element d * N * N), the input of
// FieldStage (field.hpp). One per (configuration, precision); the configuration is taken as valid.
class DoeStage {
 public:
  DoeStage(Runtime& rt, const SystemConfig& cfg, Precision p);
  DoeStage(const DoeStage&) = delete;
  DoeStage& operator=(const DoeStage&) = delete;

  // Writes the maps (each N x N metres, row-major) into heights[0, maps.size() x N x N), blocking.
  // Rejects wrong shapes, NaN/Inf and heights outside [0, 2 h_max] (InputError) before any device work.
  void write(const cl::Buffer& heights, const std::vector<Map2D>& maps);
  // Expands `params` (layout of parameter_count(kind, N), metres) onto heights[0, N x N) clamped to
  // [0, h_max] (expand_params) and, when q is given, applies the alpha-blended quantizer in place
  // (quantize_blend); as expand_parameters and quantize_heights in double. Rejects NaN/Inf, wrong
  // sizes, an invalid quantizer and alpha outside [0, 1] before any device work. Returns with the
  // queue finished (the parameter and level tables it uploads are released on return).
  void expand(const cl::Buffer& heights, Parameterization kind, const std::vector<double>& params,
              const Quantizer* q = nullptr, double alpha = 1.0);

 private:
  Runtime& rt_;
  SystemConfig cfg_;
  Precision prec_;
  cl::Kernel k_expand_, k_quantize_;
};

}  // namespace qdo
