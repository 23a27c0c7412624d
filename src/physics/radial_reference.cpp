// The radial engine's double-precision CPU reference (ref::radial_*): the same ring-by-ring
// Hankel chain as kernels/radial.cl and RadialEngine, on the host, with its adjoint.
#include "qdo/physics/radial.hpp"
#include <algorithm>
#include <chrono>
#include <cmath>
#include <map>
#include <mutex>
#include <thread>
#include <utility>
#include "qdo/physics/adjoint.hpp"
#include "qdo/physics/cpu_reference.hpp"
#include "qdo/runtime/error.hpp"

namespace qdo {

namespace ref {
namespace {

// y (bands x rows) = M (rows x cols, row-major) x (bands x cols), complex x, real M.
std::vector<cdouble> matvec(const std::vector<double>& m, std::size_t rows, std::size_t cols, const std::vector<cdouble>& x,
                            bool transpose) {
  const std::size_t out_len = transpose ? cols : rows, in_len = transpose ? rows : cols;
  if (x.size() % in_len) reject("x.size()", x.size(), "a multiple of " + to_str(in_len));
  const std::size_t bands = x.size() / in_len;
  std::vector<cdouble> y(bands * out_len, cdouble(0, 0));
  for (std::size_t b = 0; b < bands; ++b)
    for (std::size_t r = 0; r < rows; ++r)
      for (std::size_t c = 0; c < cols; ++c) {
        if (transpose) y[b * cols + c] += m[r * cols + c] * x[b * rows + r];
        else y[b * rows + r] += m[r * cols + c] * x[b * cols + c];
      }
  return y;
}

}  // namespace

std::vector<cdouble> radial_spectrum(const RadialTables& t, const std::vector<cdouble>& c) {
  return matvec(t.q, t.k, t.rings, c, false);
}
std::vector<cdouble> radial_spectrum_adjoint(const RadialTables& t, const std::vector<cdouble>& g) {
  return matvec(t.q, t.k, t.rings, g, true);
}
std::vector<cdouble> radial_output(const RadialTables& t, const std::vector<cdouble>& x) { return matvec(t.b, t.j, t.k, x, false); }
std::vector<cdouble> radial_output_adjoint(const RadialTables& t, const std::vector<cdouble>& y) {
  return matvec(t.b, t.j, t.k, y, true);
}

RadialState radial_forward(const RadialTables& t, const std::vector<double>& h) {
  if (h.size() != t.rings) reject("ring_heights_m.size()", h.size(), "exactly N/2 = " + to_str(t.rings));
  for (std::size_t k = 0; k < h.size(); ++k)
    if (!std::isfinite(h[k])) reject("ring_heights_m[" + to_str(k) + "]", h[k], "finite heights");
  RadialState s;
  s.c.assign(t.bands * t.rings, cdouble(0, 0));
  for (std::size_t b = 0; b < t.bands; ++b)
    for (std::size_t r = 0; r < t.rings; ++r)
      s.c[b * t.rings + r] = t.source[b * t.rings + r] * std::polar(1.0, t.kdn_per_m[b] * h[r]);
  s.g = radial_spectrum(t, s.c);
  std::vector<cdouble> gp(s.g.size());
  for (std::size_t e = 0; e < gp.size(); ++e) gp[e] = s.g[e] * t.tf[e];
  s.u2 = radial_output(t, gp);
  s.i.resize(s.u2.size());
  for (std::size_t e = 0; e < s.u2.size(); ++e) s.i[e] = std::norm(s.u2[e]);
  return s;
}

RealStack radial_render_native(const RadialTables& t, const std::vector<double>& i) {
  if (i.size() != t.bands * t.j) reject("i.size()", i.size(), "bands x J = " + to_str(t.bands * t.j));
  RealStack out(t.bands, t.n, t.n);
  const long half = long(t.n / 2);
  for (std::size_t y = 0; y < t.n; ++y)
    for (std::size_t x = 0; x < t.n; ++x) {
      const long dy = long(y) - half, dx = long(x) - half;
      int idx[4];
      double w[4];
      radial_lagrange4(std::sqrt(double(dy * dy + dx * dx)) * t.pitch_m, t.dr_m, idx, w);
      for (std::size_t b = 0; b < t.bands; ++b) {
        double v = 0;
        for (int q = 0; q < 4; ++q) v += w[q] * i[b * t.j + static_cast<std::size_t>(idx[q])];
        out(b, y, x) = v;
      }
    }
  return out;
}

RealStack radial_render_native_adjoint(const RadialTables& t, const RealStack& g) {
  if (g.planes != t.bands || g.rows != t.n || g.cols != t.n)
    reject("g", to_str(g.planes) + " x " + to_str(g.rows) + " x " + to_str(g.cols), "bands x N x N");
  RealStack out(t.bands, 1, t.j);
  const long half = long(t.n / 2);
  for (std::size_t y = 0; y < t.n; ++y)
    for (std::size_t x = 0; x < t.n; ++x) {
      const long dy = long(y) - half, dx = long(x) - half;
      int idx[4];
      double w[4];
      radial_lagrange4(std::sqrt(double(dy * dy + dx * dx)) * t.pitch_m, t.dr_m, idx, w);
      for (std::size_t b = 0; b < t.bands; ++b)
        for (int q = 0; q < 4; ++q) out.data[b * t.j + static_cast<std::size_t>(idx[q])] += w[q] * g(b, y, x);
    }
  return out;
}

RealStack radial_psf_native(const RadialTables& t, const std::vector<double>& h) {
  RealStack p = radial_render_native(t, radial_forward(t, h).i);
  normalize_planes(p);
  return p;
}

RealStack radial_psf_sensor(const RadialTables& t, const std::vector<double>& h) {
  RealStack s = resample_area(radial_psf_native(t, h), t.weights);
  normalize_planes(s);
  return s;
}

std::vector<double> radial_psf_sensor_vjp(const RadialTables& t, const std::vector<double>& h, const RealStack& g_s) {
  if (g_s.planes != t.bands || g_s.rows != t.s || g_s.cols != t.s)
    reject("g_psf_sensor", to_str(g_s.planes) + " x " + to_str(g_s.rows) + " x " + to_str(g_s.cols),
           "bands x S x S = " + to_str(t.bands) + " x " + to_str(t.s) + " x " + to_str(t.s));
  const RadialState st = radial_forward(t, h);
  RealStack native = radial_render_native(t, st.i);
  auto sums_of = [](const RealStack& x) {
    std::vector<double> s(x.planes, 0.0);
    for (std::size_t b = 0; b < x.planes; ++b)
      for (std::size_t e = 0; e < x.plane_size(); ++e) s[b] += x.plane(b)[e];
    return s;
  };
  const std::vector<double> sum_native = sums_of(native);
  normalize_planes(native);
  RealStack sensor = resample_area(native, t.weights);
  const std::vector<double> sum_sensor = sums_of(sensor);
  normalize_planes(sensor);
  RealStack g = normalize_vjp(g_s, sensor, sum_sensor);
  g = resample_area_adjoint(g, t.weights);
  g = normalize_vjp(g, native, sum_native);
  const RealStack gi = radial_render_native_adjoint(t, g);
  std::vector<cdouble> gu2(st.u2.size());
  for (std::size_t e = 0; e < gu2.size(); ++e) gu2[e] = 2.0 * gi.data[e] * st.u2[e];
  std::vector<cdouble> gg = radial_output_adjoint(t, gu2);
  for (std::size_t e = 0; e < gg.size(); ++e) gg[e] *= std::conj(t.tf[e]);
  const std::vector<cdouble> gc = radial_spectrum_adjoint(t, gg);
  std::vector<double> gh(t.rings, 0.0);
  for (std::size_t b = 0; b < t.bands; ++b)
    for (std::size_t r = 0; r < t.rings; ++r) {
      const cdouble gv = gc[b * t.rings + r], u = st.c[b * t.rings + r];
      gh[r] += t.kdn_per_m[b] * (gv.imag() * u.real() - gv.real() * u.imag());
    }
  return gh;
}

}  // namespace ref

}  // namespace qdo
