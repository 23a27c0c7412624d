// The system configuration (include/qdo/data/config.hpp): derived quantities, object points and
// their sampling limits, validation and the presets. Reading and writing JSON is config_json.cpp.
#include "qdo/data/config.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

#include "qdo/runtime/error.hpp"
#include "qdo/data/materials.hpp"

namespace qdo {

// ---------------------------------------------------------------------------------------
// Derived quantities
// ---------------------------------------------------------------------------------------

std::vector<double> SystemConfig::wavelengths_nm() const {
  std::vector<double> out(bands);
  for (std::size_t k = 0; k < bands; ++k) out[k] = wavelength_start_nm + static_cast<double>(k) * wavelength_step_nm;
  return out;
}

double SystemConfig::aperture_radius() const {
  return aperture_radius_m > 0 ? aperture_radius_m : (static_cast<double>(n) / 2.0 - 1.0) * pitch_m;
}

double SystemConfig::aperture_inside_px2() const {
  const double r_px = aperture_radius() / pitch_m, r2 = r_px * r_px;
  // Integer radii² below R² (strict) or up to R² (inclusive); 1e-12 absorbs the rounding of R²
  // computed from metres, so a radius of exactly 511 pixels is a tie, as in the release.
  const double last_inside = aperture_edge == ApertureEdge::Strict ? std::ceil(r2 * (1 - 1e-12)) - 1 : std::floor(r2 * (1 + 1e-12));
  return last_inside + 0.5;
}

double SystemConfig::h_max_m() const {
  const double n_base = material_by_name(material).index(base_wavelength_nm, "base_wavelength_nm");
  return base_wavelength_nm * 1e-9 / (n_base - 1.0);
}

std::size_t SystemConfig::sensor_size_px() const {
  return static_cast<std::size_t>(std::llround(static_cast<double>(n) * pitch_m / sensor_pitch_m));
}

bool ObjectPoint::at_infinity() const { return std::isinf(distance_m) && distance_m > 0; }

std::vector<ObjectPoint> object_point_grid(const std::vector<double>& distances_m,
                                           const std::vector<std::pair<double, double>>& angles_deg) {
  std::vector<ObjectPoint> out;
  out.reserve(distances_m.size() * angles_deg.size());
  for (double d : distances_m)
    for (const auto& a : angles_deg) out.push_back(ObjectPoint{d, a.first, a.second});
  return out;
}

std::vector<ObjectPoint> SystemConfig::points() const {
  if (!object_points.empty()) return object_points;
  ObjectPoint p;
  p.distance_m = scene_at_infinity ? std::numeric_limits<double>::infinity() : scene_distance_m;
  return {p};
}

namespace {
constexpr double kPi = 3.14159265358979323846;
double tan_deg(double a) { return std::tan(a * kPi / 180.0); }
}  // namespace

double object_point_frequency_per_m(const SystemConfig& c, const ObjectPoint& p, double wavelength_nm) {
  const double lambda = wavelength_nm * 1e-9, tx = tan_deg(p.field_x_deg), ty = tan_deg(p.field_y_deg);
  if (p.at_infinity()) {
    const double g = std::sqrt(1.0 + tx * tx + ty * ty);
    return std::max(std::fabs(tx), std::fabs(ty)) / g / lambda;
  }
  // |x - x0| / R grows with |x - x0| and falls with |y - y0|: its maximum over the disc is on the rim.
  const double d = p.distance_m, x0 = d * tx, y0 = d * ty, r = c.aperture_radius();
  double best = 0;
  constexpr int kRim = 2048;
  for (int k = 0; k < kRim; ++k) {
    const double phi = 2.0 * kPi * k / kRim, dx = r * std::cos(phi) - x0, dy = r * std::sin(phi) - y0;
    const double rr = std::sqrt(dx * dx + dy * dy + d * d);
    best = std::max(best, std::max(std::fabs(dx), std::fabs(dy)) / rr);
  }
  return best / lambda;
}

std::pair<double, double> chief_ray_image_m(const SystemConfig& c, const ObjectPoint& p) {
  return {-c.sensor_distance_m * tan_deg(p.field_x_deg), -c.sensor_distance_m * tan_deg(p.field_y_deg)};
}

std::string object_point_limit(const SystemConfig& c, const ObjectPoint& p) {
  if (p.on_axis()) return "";
  const auto wl = c.wavelengths_nm();
  const double shortest = *std::min_element(wl.begin(), wl.end());
  const double f = object_point_frequency_per_m(c, p, shortest), nyq = 0.5 / c.pitch_m;
  if (f > nyq)
    return "its field at the DOE reaches a local frequency of " + to_str(f) + " 1/m at " + to_str(shortest) +
           " nm, above the DOE grid's Nyquist 1/(2 pitch_m) = " + to_str(nyq) + " 1/m (it would alias)";
  const auto img = chief_ray_image_m(c, p);
  const double half = static_cast<double>(c.n) / 2.0 * c.pitch_m;
  if (std::fabs(img.first) > half || std::fabs(img.second) > half)
    return "its chief ray meets the sensor at (" + to_str(img.first) + ", " + to_str(img.second) +
           ") m, outside the N x N window of half-width " + to_str(half) + " m";
  if (c.propagator == Propagator::Fresnel) {
    const double t = std::hypot(tan_deg(p.field_x_deg), tan_deg(p.field_y_deg)), sn = t / std::sqrt(1.0 + t * t);
    const double err = c.sensor_distance_m * (t - sn);
    if (err > 0.1 * c.sensor_pitch_m)
      return "the Fresnel transfer function would move its image by z (tan - sin) = " + to_str(err) +
             " m, more than a tenth of a sensor pixel (" + to_str(0.1 * c.sensor_pitch_m) +
             " m); use \"propagator\": \"asm\" (the band-limited angular spectrum)";
  }
  return "";
}

double max_field_angle_deg(const SystemConfig& c, double distance_m) {
  const auto ok = [&](double a) { return object_point_limit(c, ObjectPoint{distance_m, a, 0}).empty(); };
  double lo = 0, hi = 89.0;
  if (!ok(1e-9)) return 0;
  if (ok(hi)) return hi;
  for (int it = 0; it < 50; ++it) {
    const double mid = 0.5 * (lo + hi);
    (ok(mid) ? lo : hi) = mid;
  }
  return lo;
}

SystemConfig point_config(const SystemConfig& c, std::size_t p) {
  if (p >= c.point_count()) reject("object point", p, "an index below the configuration's " + to_str(c.point_count()) + " points");
  const ObjectPoint pt = c.points()[p];
  SystemConfig out = c;
  out.object_points.clear();
  if (!pt.on_axis()) {
    out.object_points.push_back(pt);
    return out;
  }
  out.scene_at_infinity = pt.at_infinity();
  out.scene_distance_m = pt.distance_m;
  return out;
}

double SystemConfig::white_level_dn() const {
  return bit_depth == 0 ? 1.0 : std::ldexp(1.0, static_cast<int>(bit_depth)) - 1.0;
}

std::string to_string(Cfa c) {
  switch (c) {
    case Cfa::None: return "none";
    case Cfa::RGGB: return "rggb";
    case Cfa::GRBG: return "grbg";
    case Cfa::GBRG: return "gbrg";
    case Cfa::BGGR: return "bggr";
  }
  return "cfa " + std::to_string(static_cast<int>(c));
}

// ---------------------------------------------------------------------------------------
// Validation
// ---------------------------------------------------------------------------------------

namespace {

// Rejects NaN and infinities as well as values outside [lo, hi].
void check_finite_range(const char* key, double v, double lo, double hi, const std::string& allowed) {
  if (!std::isfinite(v) || v < lo || v > hi) reject(key, v, allowed);
}

// Kernels may run in float32 (--precision f32, or a device without fp64), and sensor images
// are float32 either way: a value that is a finite double but overflows float32 (1e300 read
// noise wrote an all-Inf sensor.h5) or underflows to 0 / a denormal is refused here, naming the
// key, the value and the representable range.
void check_float32(const char* key, double v) {
  constexpr double lo = std::numeric_limits<float>::min(), hi = std::numeric_limits<float>::max();
  const double a = std::fabs(v);
  if (!std::isfinite(v) || a > hi || (a != 0 && a < lo))
    reject(key, v,
           "0 or a magnitude from " + to_str(lo) + " to " + to_str(hi) +
               " (the float32 range: kernels run in float32 with --precision f32)");
}

}  // namespace

void SystemConfig::validate() const {
  constexpr double inf = std::numeric_limits<double>::infinity();
  if (n < 16 || n > 16384 || n % 2 != 0) reject("n", n, "an even integer from 16 to 16384");
  check_finite_range("pitch_m", pitch_m, 1e-7, 1e-4, "a pitch from 1e-7 (0.1 um) to 1e-4 (100 um) metres");
  if (bands < 1 || bands > 1001) reject("bands", bands, "an integer from 1 to 1001");
  check_finite_range("wavelength_start_nm", wavelength_start_nm, 0, inf, "a finite positive wavelength in nm");
  if (bands > 1) check_finite_range("wavelength_step_nm", wavelength_step_nm, std::numeric_limits<double>::min(), inf,
                                    "a finite step > 0 nm when bands > 1");
  else check_finite_range("wavelength_step_nm", wavelength_step_nm, -inf, inf, "a finite number");
  const Material& mat = material_by_name(material);  // rejects unknown names under the key "material"
  const std::vector<double> wl = wavelengths_nm();
  for (std::size_t k = 0; k < wl.size(); ++k) {
    const std::string arg = k == 0 ? std::string("wavelength_start_nm")
                                   : "wavelength_start_nm + " + std::to_string(k) + " * wavelength_step_nm (bands = " +
                                         std::to_string(bands) + ")";
    mat.index(wl[k], arg);
  }
  mat.index(base_wavelength_nm, "base_wavelength_nm");
  if (std::isnan(scene_distance_m)) reject("scene_distance_m", scene_distance_m, "a finite distance > 0 m or \"inf\"");
  if (!scene_at_infinity)
    check_finite_range("scene_distance_m", scene_distance_m, std::numeric_limits<double>::min(), inf,
                       "a finite distance > 0 m, or \"inf\" for a source at infinity");
  // Below 1 um the DOE would touch the sensor: no optics qdo models (nor any Fresnel sampling).
  check_finite_range("sensor_distance_m", sensor_distance_m, 1e-6, 10.0, "a distance from 1 um to 10 m");
  const double half_width_m = static_cast<double>(n) / 2.0 * pitch_m;
  check_finite_range("aperture_radius_m", aperture_radius_m, 0.0, half_width_m,
                     "0 (default (n/2 - 1) * pitch_m) or a radius up to n/2 * pitch_m = " + to_str(half_width_m) + " m");
  check_finite_range("base_plate_m", base_plate_m, 0.0, inf, "a finite thickness >= 0 m");
  if (propagator != Propagator::Fresnel && propagator != Propagator::AngularSpectrum)
    reject("propagator", static_cast<int>(propagator), "\"fresnel\" or \"asm\"");
  if (padding_px > 4 * n) reject("padding_px", padding_px, "at most 4 * n = " + std::to_string(4 * n) + " pixels per side");
  const double field_m = static_cast<double>(n) * pitch_m;
  check_finite_range("sensor_pitch_m", sensor_pitch_m, pitch_m * 0.999, field_m,
                     "from pitch_m = " + to_str(pitch_m) + " to n * pitch_m = " + to_str(field_m) +
                         " m (the PSF is area-integrated onto sensor pixels, never interpolated finer)");
  if (scene_size_px < 1 || scene_size_px > 16384) reject("scene_size_px", scene_size_px, "an integer from 1 to 16384");
  if (camera.empty()) reject("camera", "\"\"", "a built-in camera name or a CSV path, not empty");
  if (aperture_edge != ApertureEdge::Inclusive && aperture_edge != ApertureEdge::Strict && aperture_edge != ApertureEdge::Area)
    reject("aperture_edge", static_cast<int>(aperture_edge), "\"inclusive\", \"strict\" or \"area\"");
  for (const auto& [key, v] : {std::pair<const char*, double>{"aperture_offset_m[0]", aperture_offset_x_m},
                                {"aperture_offset_m[1]", aperture_offset_y_m}})
    check_finite_range(key, v, -half_width_m, half_width_m, "a finite offset of the optical axis within the DOE grid (metres)");
  if (aperture_offset()) {
    if (aperture_edge != ApertureEdge::Area)
      reject("aperture_offset_m", "[" + to_str(aperture_offset_x_m) + ", " + to_str(aperture_offset_y_m) + "]",
             "[0, 0] unless \"aperture_edge\" is \"area\" (a sub-pixel centre has no whole-sample edge)");
    // Sample centres run from -N/2 to N/2 - 1 pitches: the cells span [-(N/2 + 1/2), N/2 - 1/2].
    const double r = aperture_radius(), lo = -(double(n) / 2.0 + 0.5) * pitch_m, hi = (double(n) / 2.0 - 0.5) * pitch_m;
    for (const auto& [key, v] : {std::pair<const char*, double>{"aperture_offset_m[0]", aperture_offset_x_m},
                                  {"aperture_offset_m[1]", aperture_offset_y_m}})
      if (v - r < lo || v + r > hi)
        reject(key, v,
               "an offset that keeps the aperture (radius " + to_str(r) + " m) inside the DOE grid's cells [" + to_str(lo) + ", " +
                   to_str(hi) + "] m");
  }
  if (convolution != ConvolutionMode::Linear && convolution != ConvolutionMode::Circular)
    reject("convolution", static_cast<int>(convolution), "\"linear\" or \"circular\"");
  check_finite_range("read_noise_sigma", read_noise_sigma, 0.0, inf, "a finite sigma >= 0 (units of full scale)");
  check_finite_range("full_well_photons", full_well_photons, 0.0, inf, "a finite count >= 0 (0 disables shot noise)");
  if (cfa != Cfa::None && cfa != Cfa::RGGB && cfa != Cfa::GRBG && cfa != Cfa::GBRG && cfa != Cfa::BGGR)
    reject("cfa", static_cast<int>(cfa), "\"none\", \"rggb\", \"grbg\", \"gbrg\" or \"bggr\"");
  if (bit_depth != 0 && (bit_depth < 8 || bit_depth > 16)) reject("bit_depth", bit_depth, "0 (no quantization) or 8 to 16 bits");
  check_finite_range("gain", gain, std::numeric_limits<double>::min(), 1e6, "a finite gain > 0 and <= 1e6 (dimensionless)");
  if (!std::isfinite(black_level_dn) || black_level_dn < 0 || black_level_dn >= white_level_dn())
    reject("black_level_dn", black_level_dn,
           "a finite code >= 0 and below the white level " + to_str(white_level_dn()) + " DN (bit_depth = " +
               std::to_string(bit_depth) + ")");
  for (std::size_t i = 0; i < object_points.size(); ++i) {
    const ObjectPoint& p = object_points[i];
    const std::string key = "object_points[" + std::to_string(i) + "]";
    if (std::isnan(p.distance_m) || !(p.distance_m > 0) || (std::isfinite(p.distance_m) && p.distance_m < 1e-6))
      reject(key + " distance", p.distance_m, "a distance > 0 m (at least 1e-6 m), or \"inf\" for a point at infinity");
    if (std::isfinite(p.distance_m)) check_float32((key + " distance").c_str(), p.distance_m);
    for (const auto& [axis, a] : {std::pair<const char*, double>{" field_x_deg", p.field_x_deg}, {" field_y_deg", p.field_y_deg}})
      check_finite_range((key + axis).c_str(), a, -89.0, 89.0, "a field angle from -89 to 89 degrees");
    const std::string why = object_point_limit(*this, p);
    if (!why.empty())
      reject(key, "(" + to_str(p.distance_m) + " m, " + to_str(p.field_x_deg) + " deg, " + to_str(p.field_y_deg) + " deg)",
             "a field angle within the sampling: " + why + ". At " + to_str(p.distance_m) +
                 " m this configuration supports field angles up to " + to_str(max_field_angle_deg(*this, p.distance_m)) +
                 " deg on one axis");
  }
  if (object_points.size() > 4096) reject("object_points", object_points.size(), "at most 4096 points");
  // Last, so that the range checks above name their own limits first.
  for (const auto& [key, value] : {std::pair<const char*, double>{"pitch_m", pitch_m},
                                   {"wavelength_start_nm", wavelength_start_nm},
                                   {"wavelength_step_nm", wavelength_step_nm},
                                   {"sensor_distance_m", sensor_distance_m},
                                   {"aperture_radius_m", aperture_radius_m},
                                   {"base_wavelength_nm", base_wavelength_nm},
                                   {"base_plate_m", base_plate_m},
                                   {"sensor_pitch_m", sensor_pitch_m},
                                   {"read_noise_sigma", read_noise_sigma},
                                   {"full_well_photons", full_well_photons},
                                   {"black_level_dn", black_level_dn},
                                   {"gain", gain}})
    check_float32(key, value);
  if (!scene_at_infinity && std::isfinite(scene_distance_m)) check_float32("scene_distance_m", scene_distance_m);
}

// ---------------------------------------------------------------------------------------
// Presets
// ---------------------------------------------------------------------------------------

std::vector<std::string> preset_names() { return {"paper", "small"}; }

SystemConfig preset_config(const std::string& name) {
  SystemConfig c;  // header defaults are the paper's values (REFERENCE §1)
  c.preset = "paper";
  c.n = 1024;
  c.pitch_m = 4e-6;
  c.wavelength_start_nm = 400;
  c.wavelength_step_nm = 10;
  c.bands = 31;
  c.scene_distance_m = 1.0;
  c.scene_at_infinity = false;
  c.sensor_distance_m = 0.05;
  c.aperture_radius_m = 0;
  c.aperture_edge = ApertureEdge::Inclusive;
  c.material = "OHARA_SK1300";
  c.base_wavelength_nm = 700;
  c.base_plate_m = 2e-3;
  c.propagator = Propagator::Fresnel;
  c.padding_px = 256;  // N/4 per side
  c.strict_sampling = false;
  c.sensor_pitch_m = 8e-6;
  c.scene_size_px = 512;
  c.camera = "FLIR_GS3-U3-41S4C";
  c.srf_interpolate = false;
  c.convolution = ConvolutionMode::Linear;
  c.read_noise_sigma = 0.001;  // training noise sigma
  c.full_well_photons = 0;     // no shot noise
  c.noise_seed = 0;
  c.cfa = Cfa::None;  // the sensor as built: no mosaic, no offset, unit gain, no quantization
  c.black_level_dn = 0;
  c.gain = 1;
  c.bit_depth = 0;
  if (name == "paper") return c;
  if (name == "small") {
    // Paper physics at N = 256: z scales with N (0.05 m * 256/1024), so the numerical
    // aperture (N/2 * pitch) / z and the transfer-function sampling ratio
    // lambda * z / (M * pitch^2), M = N + 2 * padding, both equal the paper's.
    c.preset = "small";
    c.n = 256;
    c.sensor_distance_m = 0.0125;
    c.padding_px = 64;
    c.scene_size_px = 128;  // sensor 256 * 4 um / 8 um = 128 px
    return c;
  }
  reject("preset", name, "one of paper, small");
}

}  // namespace qdo
