#include "qdo/physics/psf_reference.hpp"

#include <cmath>

#include "qdo/runtime/error.hpp"
#include "qdo/physics/field_reference.hpp"
#include "qdo/physics/propagate_reference.hpp"

namespace qdo::ref {
namespace {

double plane_sum(const RealStack& s, std::size_t b) {
  double acc = 0;
  for (std::size_t i = 0; i < s.plane_size(); ++i) acc += s.plane(b)[i];
  return acc;
}

void check_shape(const RealStack& g, std::size_t planes, std::size_t rows, const char* name) {
  if (g.planes != planes || g.rows != rows || g.cols != rows)
    reject(name, to_str(g.planes) + " x " + to_str(g.rows) + " x " + to_str(g.cols),
           "shape " + to_str(planes) + " x " + to_str(rows) + " x " + to_str(rows));
}

// The wavelength of every plane of the stack (points x bands, point-major).
std::vector<double> plane_wavelengths(const SystemConfig& cfg) {
  const auto wl = cfg.wavelengths_nm();
  std::vector<double> out;
  for (std::size_t p = 0; p < cfg.point_count(); ++p) out.insert(out.end(), wl.begin(), wl.end());
  return out;
}
std::size_t plane_count(const SystemConfig& cfg) { return cfg.point_count() * cfg.bands; }

// Forward state of the chain kept for the backward pass (planes = points x bands).
struct Forward {
  PropagationGeometry g;
  ComplexStack u1, u2;        // planes x M x M
  RealStack p;                // planes x N x N, normalised
  std::vector<double> p_sums; // raw crop sums
  AreaWeights w;
  RealStack s;                // planes x S x S, normalised
  std::vector<double> s_sums;
};

Forward forward(const SystemConfig& cfg, const Map2D& h) {
  cfg.validate();
  Forward f;
  f.g = PropagationGeometry::from_config(cfg);
  f.u1 = doe_field(cfg, h, f.g);
  f.u2 = f.u1;
  propagate(f.u2, plane_wavelengths(cfg), cfg.pitch_m, cfg.sensor_distance_m, cfg.propagator);
  const std::size_t planes = plane_count(cfg);
  f.p = RealStack(planes, cfg.n, cfg.n);
  for (std::size_t b = 0; b < planes; ++b)
    for (std::size_t i = 0; i < cfg.n; ++i)
      for (std::size_t j = 0; j < cfg.n; ++j) f.p(b, i, j) = std::norm(f.u2(b, f.g.offset + i, f.g.offset + j));
  for (std::size_t b = 0; b < planes; ++b) f.p_sums.push_back(plane_sum(f.p, b));
  normalize_planes(f.p);
  f.w = sensor_weights(cfg);  // the sensor window centred on the optical axis
  f.s = resample_area(f.p, f.w);
  for (std::size_t b = 0; b < planes; ++b) f.s_sums.push_back(plane_sum(f.s, b));
  normalize_planes(f.s);
  return f;
}

// From a gradient on the raw crop intensities to dL/dH.
Map2D backward_from_intensity(const SystemConfig& cfg, const Forward& f, const RealStack& g_raw) {
  ComplexStack g(plane_count(cfg), f.g.m, f.g.m, cdouble(0, 0));
  for (std::size_t b = 0; b < plane_count(cfg); ++b)
    for (std::size_t i = 0; i < cfg.n; ++i)
      for (std::size_t j = 0; j < cfg.n; ++j) {
        const std::size_t y = f.g.offset + i, x = f.g.offset + j;
        g(b, y, x) = 2.0 * g_raw(b, i, j) * f.u2(b, y, x);
      }
  propagate(g, plane_wavelengths(cfg), cfg.pitch_m, -cfg.sensor_distance_m, cfg.propagator);
  return doe_phase_vjp(cfg, f.g, f.u1, g);
}

}  // namespace

PsfResult psf_stack(const SystemConfig& cfg, const Map2D& height_m) {
  cfg.validate();
  const auto g = PropagationGeometry::from_config(cfg);
  for (double h : height_m.data)
    if (!std::isfinite(h)) reject("height_m", h, "finite heights");
  ComplexStack f = doe_field(cfg, height_m, g);
  PsfResult out;
  propagate(f, plane_wavelengths(cfg), cfg.pitch_m, cfg.sensor_distance_m, cfg.propagator, &out.sampling.bands);
  out.psf = RealStack(plane_count(cfg), g.n, g.n);
  for (std::size_t b = 0; b < plane_count(cfg); ++b) {
    double total = 0, inside = 0;
    for (std::size_t i = 0; i < g.m * g.m; ++i) total += std::norm(f.plane(b)[i]);
    for (std::size_t i = 0; i < g.n; ++i)
      for (std::size_t j = 0; j < g.n; ++j) {
        const double e = std::norm(f(b, g.offset + i, g.offset + j));
        out.psf(b, i, j) = e;
        inside += e;
      }
    out.sampling.bands[b].energy_outside_window = total > 0 ? 1.0 - inside / total : 0.0;
  }
  normalize_planes(out.psf);
  check_source_sampling(cfg, out.sampling.bands);
  if (cfg.strict_sampling) out.sampling.enforce();
  return out;
}

RealStack resample_area(const RealStack& psf, const AreaWeights& w) {
  if (psf.rows != w.n || psf.cols != w.n) reject("psf", to_str(psf.rows) + " x " + to_str(psf.cols), "N x N with N = " + to_str(w.n));
  RealStack out(psf.planes, w.s, w.s);
  for (std::size_t b = 0; b < psf.planes; ++b)
    for (std::size_t oy = 0; oy < w.s; ++oy)
      for (std::size_t ox = 0; ox < w.s; ++ox) {
        double acc = 0;
        for (std::size_t ty = 0; ty < w.taps; ++ty) {
          const double wy = w.w[oy * w.taps + ty];
          if (wy == 0) continue;
          const std::size_t iy = static_cast<std::size_t>(w.start[oy]) + ty;
          for (std::size_t tx = 0; tx < w.taps; ++tx) {
            const double wx = w.w[(w.col_offset + ox) * w.taps + tx];
            if (wx == 0) continue;
            acc += wy * wx * psf(b, iy, static_cast<std::size_t>(w.start[w.col_offset + ox]) + tx);
          }
        }
        out(b, oy, ox) = acc;
      }
  return out;
}

void normalize_planes(RealStack& s) {
  for (std::size_t b = 0; b < s.planes; ++b) {
    double sum = 0;
    for (std::size_t i = 0; i < s.plane_size(); ++i) sum += s.plane(b)[i];
    if (sum > 0)
      for (std::size_t i = 0; i < s.plane_size(); ++i) s.plane(b)[i] /= sum;
  }
}

RealStack resample_area_adjoint(const RealStack& g, const AreaWeights& w) {
  check_shape(g, g.planes, w.s, "g_psf_sensor");
  RealStack out(g.planes, w.n, w.n);
  for (std::size_t b = 0; b < g.planes; ++b)
    for (std::size_t oy = 0; oy < w.s; ++oy)
      for (std::size_t ox = 0; ox < w.s; ++ox) {
        const double v = g(b, oy, ox);
        for (std::size_t ty = 0; ty < w.taps; ++ty) {
          const double wy = w.w[oy * w.taps + ty];
          if (wy == 0) continue;
          for (std::size_t tx = 0; tx < w.taps; ++tx) {
            const double wx = w.w[(w.col_offset + ox) * w.taps + tx];
            if (wx == 0) continue;
            out(b, static_cast<std::size_t>(w.start[oy]) + ty, static_cast<std::size_t>(w.start[w.col_offset + ox]) + tx) += wy * wx * v;
          }
        }
      }
  return out;
}

RealStack normalize_vjp(const RealStack& g_out, const RealStack& y, const std::vector<double>& raw_sums) {
  RealStack g(y.planes, y.rows, y.cols);
  for (std::size_t b = 0; b < y.planes; ++b) {
    double dot = 0;
    for (std::size_t i = 0; i < y.plane_size(); ++i) dot += g_out.plane(b)[i] * y.plane(b)[i];
    const double inv = raw_sums[b] > 0 ? 1.0 / raw_sums[b] : 0.0;
    for (std::size_t i = 0; i < y.plane_size(); ++i) g.plane(b)[i] = (g_out.plane(b)[i] - dot) * inv;
  }
  return g;
}

RealStack normalize_jvp(const RealStack& dx, const RealStack& y, const std::vector<double>& raw_sums) {
  RealStack d(y.planes, y.rows, y.cols);
  for (std::size_t b = 0; b < y.planes; ++b) {
    const double s = plane_sum(dx, b);
    const double inv = raw_sums[b] > 0 ? 1.0 / raw_sums[b] : 0.0;
    for (std::size_t i = 0; i < y.plane_size(); ++i) d.plane(b)[i] = (dx.plane(b)[i] - y.plane(b)[i] * s) * inv;
  }
  return d;
}

Map2D psf_native_vjp(const SystemConfig& cfg, const Map2D& height_m, const RealStack& g_psf) {
  check_shape(g_psf, plane_count(cfg), cfg.n, "g_psf");
  const Forward f = forward(cfg, height_m);
  return backward_from_intensity(cfg, f, normalize_vjp(g_psf, f.p, f.p_sums));
}

Map2D psf_sensor_vjp(const SystemConfig& cfg, const Map2D& height_m, const RealStack& g_psf_sensor) {
  check_shape(g_psf_sensor, plane_count(cfg), cfg.sensor_size_px(), "g_psf_sensor");
  const Forward f = forward(cfg, height_m);
  const RealStack g_p = resample_area_adjoint(normalize_vjp(g_psf_sensor, f.s, f.s_sums), f.w);
  return backward_from_intensity(cfg, f, normalize_vjp(g_p, f.p, f.p_sums));
}

RealStack psf_sensor_stack(const SystemConfig& cfg, const Map2D& height_m) { return forward(cfg, height_m).s; }

RealStack psf_sensor_jvp(const SystemConfig& cfg, const Map2D& height_m, const Map2D& d_height_m) {
  const Forward f = forward(cfg, height_m);
  // dU1 = i dtheta U1, dU2 = propagate(dU1), dP = 2 Re(conj(U2) dU2).
  ComplexStack du = doe_phase_jvp(cfg, f.g, f.u1, d_height_m);
  propagate(du, plane_wavelengths(cfg), cfg.pitch_m, cfg.sensor_distance_m, cfg.propagator);
  RealStack dp(plane_count(cfg), cfg.n, cfg.n);
  for (std::size_t b = 0; b < plane_count(cfg); ++b)
    for (std::size_t i = 0; i < cfg.n; ++i)
      for (std::size_t j = 0; j < cfg.n; ++j) {
        const std::size_t y = f.g.offset + i, x = f.g.offset + j;
        dp(b, i, j) = 2.0 * (std::conj(f.u2(b, y, x)) * du(b, y, x)).real();
      }
  const RealStack dpn = normalize_jvp(dp, f.p, f.p_sums);
  return normalize_jvp(resample_area(dpn, f.w), f.s, f.s_sums);
}

}  // namespace qdo::ref
