// The host side of include/qdo/physics/doe.hpp: parameterizations and their expansion, the quantizer,
// alpha blending and schedule, lens and flat designs, in double (the CPU reference of kernels/doe.cl's
// expand_params and quantize_blend; the device launcher is src/physics/doe.cpp).
#include "qdo/physics/doe.hpp"

#include <algorithm>
#include <cmath>

#include "qdo/runtime/error.hpp"
#include "qdo/data/materials.hpp"

namespace qdo {

Parameterization parameterization_from_string(const std::string& s) {
  if (s == "2d" || s == "full") return Parameterization::Full2D;
  if (s == "radial") return Parameterization::Radial;
  if (s == "quad") return Parameterization::Quad;
  reject("parameterization", s, "one of 2d, radial, quad");
}

std::size_t parameter_count(Parameterization p, std::size_t n) {
  switch (p) {
    case Parameterization::Full2D: return n * n;
    case Parameterization::Radial: return n / 2;
    case Parameterization::Quad: return (n / 2) * (n / 2);
  }
  return 0;
}

Map2D expand_parameters(Parameterization p, const std::vector<double>& params, std::size_t n, double h_max_m) {
  if (n < 2 || n % 2) reject("n", n, "an even number >= 2");
  if (params.size() != parameter_count(p, n))
    reject("params.size()", params.size(), "exactly " + to_str(parameter_count(p, n)) + " for this parameterization");
  const long half = static_cast<long>(n / 2);
  Map2D h(n, n);
  for (std::size_t i = 0; i < n; ++i) {
    for (std::size_t j = 0; j < n; ++j) {
      const long di = static_cast<long>(i) - half, dj = static_cast<long>(j) - half;
      double v = 0;
      if (p == Parameterization::Full2D) {
        v = params[i * n + j];
      } else if (p == Parameterization::Radial) {
        const long r2 = di * di + dj * dj;
        long k = static_cast<long>(std::sqrt(double(r2)));
        while (k * k > r2) --k;  // exact integer floor(sqrt), as kernels/doe.cl
        while ((k + 1) * (k + 1) <= r2) ++k;
        k = std::min(k, half - 1);
        v = params[static_cast<std::size_t>(k)];
      } else {
        const long a = std::min(std::labs(di), half - 1), b = std::min(std::labs(dj), half - 1);
        v = params[static_cast<std::size_t>(a * half + b)];
      }
      if (!std::isfinite(v)) reject("params", v, "finite heights");
      h(i, j) = std::clamp(v, 0.0, h_max_m);
    }
  }
  return h;
}

Placement placement_from_string(const std::string& s) {
  if (s == "inclusive") return Placement::Inclusive;
  if (s == "wrapped") return Placement::Wrapped;
  reject("placement", s, "inclusive (levels k/(L-1), the release) or wrapped (levels k/L)");
}

std::string to_string(Placement p) { return p == Placement::Inclusive ? "inclusive" : "wrapped"; }

void Quantizer::validate() const {
  if (levels < 2 || levels > 65536) reject("levels", levels, "an integer in [2, 65536]");
  if (!level_table.empty()) {
    if (level_table.size() != static_cast<std::size_t>(levels))
      reject("level_table.size()", level_table.size(), "one value per level (" + to_str(levels) + ")");
    for (std::size_t l = 0; l < level_table.size(); ++l)
      if (!std::isfinite(level_table[l])) reject("level_table[" + to_str(l) + "]", level_table[l], "finite values");
  }
  if (!offsets.empty()) {
    if (offsets.size() != static_cast<std::size_t>(levels))
      reject("offsets.size()", offsets.size(), "one offset per level (" + to_str(levels) + ")");
    const double lim = levels == 2 ? 0.2 : 1.0;
    const std::size_t pin = static_cast<std::size_t>(pinned_level());
    if (offsets[pin] != 0.0)
      reject("offsets[" + to_str(pin) + "]", offsets[pin], "0 (level " + to_str(pin) + " is the pinned one)");
    for (std::size_t l = 0; l < offsets.size(); ++l)
      if (!(std::fabs(offsets[l]) <= lim))
        reject("offsets[" + to_str(l) + "]", offsets[l], "within [-" + to_str(lim) + ", " + to_str(lim) + "]");
  }
}

int Quantizer::level_index(double u) const {
  const double uc = std::clamp(u, 0.0, 1.0);
  if (placement == Placement::Inclusive) {
    return std::min(static_cast<int>(std::floor(uc * (levels - 1) + 0.5)), levels - 1);
  }
  const int k = static_cast<int>(std::floor(uc * levels + 0.5));
  return k % levels;
}

double Quantizer::level_value(int l) const {
  if (!level_table.empty()) return level_table[static_cast<std::size_t>(l)];
  const double a = offsets.empty() ? 0.0 : offsets[static_cast<std::size_t>(l)];
  const double denom = placement == Placement::Inclusive ? double(levels - 1) : double(levels);
  return (l + 0.5 * a) / denom;
}

std::vector<double> Quantizer::level_heights_m(double h_max_m) const {
  std::vector<double> out(static_cast<std::size_t>(levels));
  for (int l = 0; l < levels; ++l) out[static_cast<std::size_t>(l)] = h_max_m * level_value(l);
  return out;
}

Map2D quantize_heights(const Map2D& h_full_m, double h_max_m, const Quantizer& q, double alpha) {
  q.validate();
  if (!(h_max_m > 0)) reject("h_max_m", h_max_m, "> 0");
  if (!(alpha >= 0 && alpha <= 1)) reject("alpha", alpha, "within [0, 1]");
  Map2D out(h_full_m.rows, h_full_m.cols);
  for (std::size_t i = 0; i < out.data.size(); ++i) {
    const double hf = h_full_m.data[i];
    if (!std::isfinite(hf)) reject("height_m[" + to_str(i) + "]", hf, "finite values");
    out.data[i] = alpha * h_max_m * q.quantize(hf / h_max_m) + (1.0 - alpha) * hf;
  }
  return out;
}

double alpha_schedule(double step, double t0, double t1) {
  if (!(t1 > t0)) reject("t1", t1, "> t0 = " + to_str(t0));
  if (step <= t0) return 0.0;
  if (step > t1) return 1.0;
  const double r = (t1 - step) / (t1 - t0);
  return 1.0 - r * r * r;
}

double quantization_deviation_m(const Map2D& h_q, const Map2D& h_f) {
  if (h_q.data.size() != h_f.data.size() || h_q.data.empty())
    reject("h_q.size()", h_q.data.size(), "the size of h_f (" + to_str(h_f.data.size()) + "), non-zero");
  double s = 0;
  for (std::size_t i = 0; i < h_q.data.size(); ++i) s += std::fabs(h_q.data[i] - h_f.data[i]);
  return s / double(h_q.data.size());
}

Map2D lens_design(const SystemConfig& cfg, double design_wavelength_nm) {
  cfg.validate();
  const Material& mat = material_by_name(cfg.material);
  const double dn = mat.index(design_wavelength_nm, "design_wavelength_nm") - 1.0;
  const double k = 2.0 * M_PI / (design_wavelength_nm * 1e-9);
  const double z = cfg.sensor_distance_m, d = cfg.scene_distance_m;
  const std::size_t n = cfg.n;
  const double h_max_m = cfg.h_max_m();  // evaluates the material's dispersion: once, not per pixel
  Map2D h(n, n);
  for (std::size_t i = 0; i < n; ++i) {
    for (std::size_t j = 0; j < n; ++j) {
      const double y = (double(i) - double(n / 2)) * cfg.pitch_m, x = (double(j) - double(n / 2)) * cfg.pitch_m;
      const double r2 = x * x + y * y;
      // sqrt(r²+z²) - z = r² / (sqrt(r²+z²) + z): no cancellation.
      double path = r2 / (std::sqrt(r2 + z * z) + z);
      if (!cfg.scene_at_infinity) path += r2 / (std::sqrt(r2 + d * d) + d);
      double phi = std::fmod(-k * path, 2.0 * M_PI);
      if (phi < 0) phi += 2.0 * M_PI;
      h(i, j) = std::min(phi / (k * dn), h_max_m);
    }
  }
  return h;
}

Map2D flat_design(const SystemConfig& cfg) { return Map2D(cfg.n, cfg.n, 0.0); }

}  // namespace qdo
