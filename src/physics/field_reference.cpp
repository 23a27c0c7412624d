#include "qdo/physics/field_reference.hpp"

#include <cmath>

#include "qdo/runtime/error.hpp"
#include "qdo/physics/field.hpp"

namespace qdo::ref {

double point_source_m(const std::vector<double>& pt, std::size_t p, double x, double y) {
  const double x0 = pt[4 * p], y0 = pt[4 * p + 1], d = pt[4 * p + 2], r0 = pt[4 * p + 3], r2 = x * x + y * y;
  if (x0 == 0 && y0 == 0) return d > 0 ? r2 / (std::sqrt(r2 + d * d) + d) : 0.0;
  if (d > 0) return (r2 - 2.0 * (x * x0 + y * y0)) / (std::sqrt((x - x0) * (x - x0) + (y - y0) * (y - y0) + d * d) + r0);
  return -(x * x0 + y * y0);
}

ComplexStack doe_field(const SystemConfig& cfg, const Map2D& height_m, const PropagationGeometry& g) {
  if (height_m.rows != cfg.n || height_m.cols != cfg.n)
    reject("height_m", to_str(height_m.rows) + " x " + to_str(height_m.cols), "an N x N map with N = " + to_str(cfg.n));
  const auto k = wavenumber_per_band(cfg);
  const auto dn = delta_n_per_band(cfg);
  // Aperture: aperture_transmission (optics.hpp): the integer pixel radius² test of
  // cfg.aperture_inside_px2(), or each cell's area fraction with aperture_edge "area", as kernels/field.cl.
  const std::vector<double> amp = aperture_transmission(cfg);
  const std::vector<double> pt = FieldStage::point_table(cfg);
  const std::size_t points = cfg.point_count(), bands = cfg.bands;
  ComplexStack f(points * bands, g.m, g.m, cdouble(0, 0));
  for (std::size_t pl = 0; pl < points * bands; ++pl) {
    const std::size_t b = pl % bands, p = pl / bands;
    for (std::size_t i = 0; i < g.n; ++i) {
      for (std::size_t j = 0; j < g.n; ++j) {
        const double y = (double(i) - double(g.n / 2)) * g.pitch_m, x = (double(j) - double(g.n / 2)) * g.pitch_m;
        const double a = amp[i * g.n + j];
        if (!(a > 0)) continue;
        const double src = point_source_m(pt, p, x, y);
        const double phase = k[b] * (src + dn[b] * height_m(i, j));
        f(pl, g.offset + i, g.offset + j) = std::polar(a, phase);
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
  for (std::size_t pl = 0; pl < cfg.point_count() * cfg.bands; ++pl)
    for (std::size_t i = 0; i < cfg.n; ++i)
      for (std::size_t j = 0; j < cfg.n; ++j) {
        const std::size_t y = geo.offset + i, x = geo.offset + j, b = pl % cfg.bands;
        const cdouble v = std::conj(g(pl, y, x)) * cdouble(0, 1) * u1(pl, y, x);
        dh(i, j) += k[b] * dn[b] * v.real();
      }
  return dh;
}

ComplexStack doe_phase_jvp(const SystemConfig& cfg, const PropagationGeometry& geo, const ComplexStack& u1,
                           const Map2D& d_height_m) {
  const auto k = wavenumber_per_band(cfg);
  const auto dn = delta_n_per_band(cfg);
  ComplexStack du(cfg.point_count() * cfg.bands, geo.m, geo.m, cdouble(0, 0));
  for (std::size_t pl = 0; pl < cfg.point_count() * cfg.bands; ++pl)
    for (std::size_t i = 0; i < cfg.n; ++i)
      for (std::size_t j = 0; j < cfg.n; ++j) {
        const std::size_t y = geo.offset + i, x = geo.offset + j, b = pl % cfg.bands;
        du(pl, y, x) = cdouble(0, 1) * (k[b] * dn[b] * d_height_m(i, j)) * u1(pl, y, x);
      }
  return du;
}

}  // namespace qdo::ref
