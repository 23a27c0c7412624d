#include <cmath>

#include "qdo/adjoint.hpp"
#include "qdo/cpu_reference.hpp"
#include "qdo/error.hpp"

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

// Forward state of the chain kept for the backward pass.
struct Forward {
  PropagationGeometry g;
  ComplexStack u1, u2;        // bands x M x M
  RealStack p;                // bands x N x N, normalised
  std::vector<double> p_sums; // raw crop sums
  AreaWeights w;
  RealStack s;                // bands x S x S, normalised
  std::vector<double> s_sums;
};

Forward forward(const SystemConfig& cfg, const Map2D& h) {
  cfg.validate();
  Forward f;
  f.g = PropagationGeometry::from_config(cfg);
  f.u1 = doe_field(cfg, h, f.g);
  f.u2 = f.u1;
  propagate(f.u2, cfg.wavelengths_nm(), cfg.pitch_m, cfg.sensor_distance_m, cfg.propagator);
  f.p = RealStack(cfg.bands, cfg.n, cfg.n);
  for (std::size_t b = 0; b < cfg.bands; ++b)
    for (std::size_t i = 0; i < cfg.n; ++i)
      for (std::size_t j = 0; j < cfg.n; ++j) f.p(b, i, j) = std::norm(f.u2(b, f.g.offset + i, f.g.offset + j));
  for (std::size_t b = 0; b < cfg.bands; ++b) f.p_sums.push_back(plane_sum(f.p, b));
  normalize_planes(f.p);
  f.w = AreaWeights::make(cfg.n, cfg.pitch_m, cfg.sensor_size_px(), cfg.sensor_pitch_m);
  f.s = resample_area(f.p, f.w);
  for (std::size_t b = 0; b < cfg.bands; ++b) f.s_sums.push_back(plane_sum(f.s, b));
  normalize_planes(f.s);
  return f;
}

// From a gradient on the raw crop intensities to dL/dH.
Map2D backward_from_intensity(const SystemConfig& cfg, const Forward& f, const RealStack& g_raw) {
  ComplexStack g(cfg.bands, f.g.m, f.g.m, cdouble(0, 0));
  for (std::size_t b = 0; b < cfg.bands; ++b)
    for (std::size_t i = 0; i < cfg.n; ++i)
      for (std::size_t j = 0; j < cfg.n; ++j) {
        const std::size_t y = f.g.offset + i, x = f.g.offset + j;
        g(b, y, x) = 2.0 * g_raw(b, i, j) * f.u2(b, y, x);
      }
  propagate(g, cfg.wavelengths_nm(), cfg.pitch_m, -cfg.sensor_distance_m, cfg.propagator);
  const auto k = wavenumber_per_band(cfg);
  const auto dn = delta_n_per_band(cfg);
  Map2D dh(cfg.n, cfg.n);
  for (std::size_t b = 0; b < cfg.bands; ++b)
    for (std::size_t i = 0; i < cfg.n; ++i)
      for (std::size_t j = 0; j < cfg.n; ++j) {
        const std::size_t y = f.g.offset + i, x = f.g.offset + j;
        const cdouble v = std::conj(g(b, y, x)) * cdouble(0, 1) * f.u1(b, y, x);
        dh(i, j) += k[b] * dn[b] * v.real();
      }
  return dh;
}

}  // namespace

RealStack convolve_vjp_psf(const RealStack& cube, const RealStack& g_out, std::size_t psf_size, ConvolutionMode mode) {
  if (g_out.planes != cube.planes || g_out.rows != cube.rows || g_out.cols != cube.cols)
    reject("g_out", to_str(g_out.planes) + " x " + to_str(g_out.rows) + " x " + to_str(g_out.cols), "the cube's shape");
  // <convolve(cube, psf), g> is linear in psf: probe it one PSF pixel at a time would be slow;
  // instead correlate: g_psf[b][y][x] = sum_{p} g[b][p] * cube[b][p - (y - c, x - c)] over the
  // same (zero-padded or periodic) grid the forward convolution uses.
  const std::size_t h = cube.rows, w = cube.cols, s = psf_size, c = s / 2;
  const bool lin = mode == ConvolutionMode::Linear;
  const std::size_t py = lin ? fast_fft_size(h + s - 1) : h, px = lin ? fast_fft_size(w + s - 1) : w;
  RealStack out(cube.planes, s, s);
  for (std::size_t b = 0; b < cube.planes; ++b) {
    // r[u][v] = sum_{y',x'} g[y'][x'] X[(y' - u) mod P][(x' - v) mod P] on the padded grid.
    std::vector<double> r(py * px, 0.0);
    for (std::size_t u = 0; u < py; ++u)
      for (std::size_t v = 0; v < px; ++v) {
        double acc = 0;
        for (std::size_t y = 0; y < h; ++y) {
          const std::size_t sy = (y + py - u) % py;
          if (sy >= h) continue;
          for (std::size_t x = 0; x < w; ++x) {
            const std::size_t sx = (x + px - v) % px;
            if (sx < w) acc += g_out(b, y, x) * cube(b, sy, sx);
          }
        }
        r[u * px + v] = acc;
      }
    for (std::size_t y = 0; y < s; ++y)
      for (std::size_t x = 0; x < s; ++x) out(b, y, x) = r[((y + py * s - c) % py) * px + (x + px * s - c) % px];
  }
  return out;
}

RealStack convolve_vjp_scene(const RealStack& psf, const RealStack& g_out, ConvolutionMode mode) {
  if (psf.planes != g_out.planes || psf.rows != psf.cols)
    reject("psf", shape(psf), "square planes, one per band of g_out (" + to_str(g_out.planes) + ")");
  const long h = long(g_out.rows), w = long(g_out.cols), s = long(psf.rows), c = s / 2;
  const bool lin = mode == ConvolutionMode::Linear;
  RealStack out(g_out.planes, g_out.rows, g_out.cols);
  for (std::size_t b = 0; b < g_out.planes; ++b)
    for (long qy = 0; qy < h; ++qy)
      for (long qx = 0; qx < w; ++qx) {
        double acc = 0;
        for (long ty = -c; ty < s - c; ++ty)
          for (long tx = -c; tx < s - c; ++tx) {
            long py = qy + ty, px = qx + tx;
            if (lin && (py < 0 || py >= h || px < 0 || px >= w)) continue;
            py = ((py % h) + h) % h;
            px = ((px % w) + w) % w;
            acc += g_out(b, std::size_t(py), std::size_t(px)) * psf(b, std::size_t(ty + c), std::size_t(tx + c));
          }
        out(b, std::size_t(qy), std::size_t(qx)) = acc;
      }
  return out;
}

RealStack sensor_integrate_vjp(const RealStack& g_rgb, const Eigen::MatrixXd& srf) {
  if (g_rgb.planes != 3 || srf.rows() != 3) reject("g_rgb", g_rgb.planes, "3 channels");
  RealStack out(static_cast<std::size_t>(srf.cols()), g_rgb.rows, g_rgb.cols);
  for (std::size_t b = 0; b < out.planes; ++b)
    for (std::size_t p = 0; p < out.plane_size(); ++p) {
      double acc = 0;
      for (std::size_t ch = 0; ch < 3; ++ch) acc += srf(Eigen::Index(ch), Eigen::Index(b)) * g_rgb.plane(ch)[p];
      out.plane(b)[p] = acc;
    }
  return out;
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
            const double wx = w.w[ox * w.taps + tx];
            if (wx == 0) continue;
            out(b, static_cast<std::size_t>(w.start[oy]) + ty, static_cast<std::size_t>(w.start[ox]) + tx) += wy * wx * v;
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
  check_shape(g_psf, cfg.bands, cfg.n, "g_psf");
  const Forward f = forward(cfg, height_m);
  return backward_from_intensity(cfg, f, normalize_vjp(g_psf, f.p, f.p_sums));
}

Map2D psf_sensor_vjp(const SystemConfig& cfg, const Map2D& height_m, const RealStack& g_psf_sensor) {
  check_shape(g_psf_sensor, cfg.bands, cfg.sensor_size_px(), "g_psf_sensor");
  const Forward f = forward(cfg, height_m);
  const RealStack g_p = resample_area_adjoint(normalize_vjp(g_psf_sensor, f.s, f.s_sums), f.w);
  return backward_from_intensity(cfg, f, normalize_vjp(g_p, f.p, f.p_sums));
}

RealStack psf_sensor_stack(const SystemConfig& cfg, const Map2D& height_m) { return forward(cfg, height_m).s; }

RealStack psf_sensor_jvp(const SystemConfig& cfg, const Map2D& height_m, const Map2D& d_height_m) {
  const Forward f = forward(cfg, height_m);
  const auto k = wavenumber_per_band(cfg);
  const auto dn = delta_n_per_band(cfg);
  // dU1 = i dtheta U1, dU2 = propagate(dU1), dP = 2 Re(conj(U2) dU2).
  ComplexStack du(cfg.bands, f.g.m, f.g.m, cdouble(0, 0));
  for (std::size_t b = 0; b < cfg.bands; ++b)
    for (std::size_t i = 0; i < cfg.n; ++i)
      for (std::size_t j = 0; j < cfg.n; ++j) {
        const std::size_t y = f.g.offset + i, x = f.g.offset + j;
        du(b, y, x) = cdouble(0, 1) * (k[b] * dn[b] * d_height_m(i, j)) * f.u1(b, y, x);
      }
  propagate(du, cfg.wavelengths_nm(), cfg.pitch_m, cfg.sensor_distance_m, cfg.propagator);
  RealStack dp(cfg.bands, cfg.n, cfg.n);
  for (std::size_t b = 0; b < cfg.bands; ++b)
    for (std::size_t i = 0; i < cfg.n; ++i)
      for (std::size_t j = 0; j < cfg.n; ++j) {
        const std::size_t y = f.g.offset + i, x = f.g.offset + j;
        dp(b, i, j) = 2.0 * (std::conj(f.u2(b, y, x)) * du(b, y, x)).real();
      }
  const RealStack dpn = normalize_jvp(dp, f.p, f.p_sums);
  return normalize_jvp(resample_area(dpn, f.w), f.s, f.s_sums);
}

std::vector<double> expand_parameters_vjp(Parameterization p, const std::vector<double>& params, std::size_t n,
                                          double h_max_m, const Map2D& g_heights) {
  if (params.size() != parameter_count(p, n))
    reject("params.size()", params.size(), "exactly " + to_str(parameter_count(p, n)));
  const long half = static_cast<long>(n / 2);
  std::vector<double> g(params.size(), 0.0);
  for (std::size_t i = 0; i < n; ++i)
    for (std::size_t j = 0; j < n; ++j) {
      const long di = static_cast<long>(i) - half, dj = static_cast<long>(j) - half;
      std::size_t idx = 0;
      if (p == Parameterization::Full2D) {
        idx = i * n + j;
      } else if (p == Parameterization::Radial) {
        const long r2 = di * di + dj * dj;
        long k = static_cast<long>(std::sqrt(double(r2)));
        while (k * k > r2) --k;
        while ((k + 1) * (k + 1) <= r2) ++k;
        idx = static_cast<std::size_t>(std::min(k, half - 1));
      } else {
        idx = static_cast<std::size_t>(std::min(std::labs(di), half - 1) * half + std::min(std::labs(dj), half - 1));
      }
      g[idx] += g_heights(i, j);
    }
  // The clamp to [0, h_max] has zero derivative outside the interval.
  for (std::size_t k = 0; k < g.size(); ++k)
    if (params[k] < 0 || params[k] > h_max_m) g[k] = 0;
  return g;
}

QuantizeVjp quantize_vjp(const Map2D& h_full_m, double h_max_m, const Quantizer& q, double alpha, const Map2D& g_out,
                         bool ste) {
  q.validate();
  QuantizeVjp r;
  r.g_full = Map2D(h_full_m.rows, h_full_m.cols);
  r.g_offsets.assign(static_cast<std::size_t>(q.levels), 0.0);
  r.g_levels.assign(static_cast<std::size_t>(q.levels), 0.0);
  const double denom = q.placement == Placement::Inclusive ? double(q.levels - 1) : double(q.levels);
  const double through = ste ? 1.0 : 1.0 - alpha;
  for (std::size_t i = 0; i < h_full_m.data.size(); ++i) {
    r.g_full.data[i] = through * g_out.data[i];
    const int l = q.level_index(h_full_m.data[i] / h_max_m);
    r.g_levels[static_cast<std::size_t>(l)] += alpha * h_max_m * g_out.data[i];
    if (l > 0) r.g_offsets[static_cast<std::size_t>(l)] += alpha * h_max_m * 0.5 / denom * g_out.data[i];
  }
  return r;
}

}  // namespace qdo::ref
