#include "qdo/field_reference.hpp"

#include <cmath>

#include "qdo/error.hpp"

namespace qdo::ref {

ComplexStack doe_field(const SystemConfig& cfg, const Map2D& height_m, const PropagationGeometry& g) {
  if (height_m.rows != cfg.n || height_m.cols != cfg.n)
    reject("height_m", to_str(height_m.rows) + " x " + to_str(height_m.cols), "an N x N map with N = " + to_str(cfg.n));
  const auto k = wavenumber_per_band(cfg);
  const auto dn = delta_n_per_band(cfg);
  // Aperture: integer pixel radius² against cfg.aperture_inside_px2() (aperture_edge), as kernels/field.cl.
  const double r_ap2_px = cfg.aperture_inside_px2();
  const double d = cfg.scene_distance_m;
  ComplexStack f(cfg.bands, g.m, g.m, cdouble(0, 0));
  for (std::size_t b = 0; b < cfg.bands; ++b) {
    for (std::size_t i = 0; i < g.n; ++i) {
      for (std::size_t j = 0; j < g.n; ++j) {
        const double y = (double(i) - double(g.n / 2)) * g.pitch_m, x = (double(j) - double(g.n / 2)) * g.pitch_m;
        const double r2 = x * x + y * y;
        const double di = double(i) - double(g.n / 2), dj = double(j) - double(g.n / 2);
        if (di * di + dj * dj > r_ap2_px) continue;
        const double src = cfg.scene_at_infinity ? 0.0 : r2 / (std::sqrt(r2 + d * d) + d);
        const double phase = k[b] * (src + dn[b] * height_m(i, j));
        f(b, g.offset + i, g.offset + j) = std::polar(1.0, phase);
      }
    }
  }
  return f;
}

Map2D doe_phase_vjp(const SystemConfig& cfg, const PropagationGeometry& geo, const ComplexStack& u1,
                    const ComplexStack& g) {
  const auto k = wavenumber_per_band(cfg);
  const auto dn = delta_n_per_band(cfg);
  Map2D dh(cfg.n, cfg.n);
  for (std::size_t b = 0; b < cfg.bands; ++b)
    for (std::size_t i = 0; i < cfg.n; ++i)
      for (std::size_t j = 0; j < cfg.n; ++j) {
        const std::size_t y = geo.offset + i, x = geo.offset + j;
        const cdouble v = std::conj(g(b, y, x)) * cdouble(0, 1) * u1(b, y, x);
        dh(i, j) += k[b] * dn[b] * v.real();
      }
  return dh;
}

ComplexStack doe_phase_jvp(const SystemConfig& cfg, const PropagationGeometry& geo, const ComplexStack& u1,
                           const Map2D& d_height_m) {
  const auto k = wavenumber_per_band(cfg);
  const auto dn = delta_n_per_band(cfg);
  ComplexStack du(cfg.bands, geo.m, geo.m, cdouble(0, 0));
  for (std::size_t b = 0; b < cfg.bands; ++b)
    for (std::size_t i = 0; i < cfg.n; ++i)
      for (std::size_t j = 0; j < cfg.n; ++j) {
        const std::size_t y = geo.offset + i, x = geo.offset + j;
        du(b, y, x) = cdouble(0, 1) * (k[b] * dn[b] * d_height_m(i, j)) * u1(b, y, x);
      }
  return du;
}

}  // namespace qdo::ref
