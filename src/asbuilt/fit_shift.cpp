// The lateral moves of the as-built fit (fit.hpp): the registration, the native PSF integrated by a
// moved sensor grid (integrate_registered) and its adjoint; the bilinear shift of a stack
// (shift_bilinear), which the starts use to move a sensor stack by whole pixels.
#include "qdo/asbuilt/fit.hpp"

#include <cmath>
#include <string>

#include "qdo/physics/optics.hpp"
#include "qdo/physics/psf_reference.hpp"
#include "qdo/runtime/error.hpp"

namespace qdo {

namespace {

// The bilinear weights of a shift s: s = i + f, i = floor(s), f in [0, 1); out(x) = (1 - f) in(x - i) + f in(x - i - 1).
struct ShiftSplit {
  long i = 0;
  double f = 0;
  explicit ShiftSplit(double s) {
    const double fl = std::floor(s);
    i = long(fl);
    f = s - fl;
  }
};

// Visits every (output index, input index, weight) of the shift; with derivative_axis 1 (0) the
// weights of its derivative in sx (sy) instead: d(1 - f)/ds = -1, d f/ds = +1 (the right derivative
// where s is a whole number).
template <typename F>
void for_each_tap(std::size_t planes, std::size_t rows, std::size_t cols, double sx, double sy, F&& f, int derivative_axis = -1) {
  const ShiftSplit x(sx), y(sy);
  double wx[2] = {1 - x.f, x.f}, wy[2] = {1 - y.f, y.f};
  if (derivative_axis == 1) wx[0] = -1, wx[1] = 1;
  if (derivative_axis == 0) wy[0] = -1, wy[1] = 1;
  const long r = long(rows), c = long(cols);
  for (std::size_t p = 0; p < planes; ++p) {
    const std::size_t base = p * rows * cols;
    for (long yy = 0; yy < r; ++yy)
      for (int a = 0; a < 2; ++a) {
        const long ys = yy - y.i - a;
        if (ys < 0 || ys >= r) continue;
        for (long xx = 0; xx < c; ++xx)
          for (int b = 0; b < 2; ++b) {
            const long xs = xx - x.i - b;
            if (xs < 0 || xs >= c) continue;
            f(base + std::size_t(yy * c + xx), base + std::size_t(ys * c + xs), wy[a] * wx[b]);
          }
      }
  }
}

void require_size(const std::vector<double>& v, std::size_t planes, std::size_t rows, std::size_t cols, const char* what) {
  if (v.size() != planes * rows * cols)
    throw Error(std::string("shift_bilinear: ") + what + " holds " + std::to_string(v.size()) + " values, expected " +
                shape(planes, rows, cols));
}

}  // namespace

std::vector<double> shift_bilinear(const std::vector<double>& in, std::size_t planes, std::size_t rows, std::size_t cols, double sx,
                                   double sy) {
  require_size(in, planes, rows, cols, "the input");
  std::vector<double> out(in.size(), 0.0);
  for_each_tap(planes, rows, cols, sx, sy, [&](std::size_t o, std::size_t i, double w) { out[o] += w * in[i]; });
  return out;
}

std::vector<double> shift_bilinear_derivative(const std::vector<double>& in, std::size_t planes, std::size_t rows, std::size_t cols,
                                              double sx, double sy, int axis) {
  require_size(in, planes, rows, cols, "the input");
  if (axis != 0 && axis != 1) throw Error("shift_bilinear_derivative: axis " + std::to_string(axis) + ", expected 0 (sy) or 1 (sx)");
  std::vector<double> out(in.size(), 0.0);
  for_each_tap(planes, rows, cols, sx, sy, [&](std::size_t o, std::size_t i, double w) { out[o] += w * in[i]; }, axis);
  return out;
}

namespace {

// The registration's weights per axis: the native grid (N at pitch_m) onto the sensor grid (S at
// sensor_pitch_m) moved by -s sensor px from the optical axis, so the content moves by +s (and, as
// in sensor_weights, by -aperture_offset / sensor pitch: the window is centred on the axis).
struct RegisteredWeights {
  AreaWeights wx, wy;
  RegisteredWeights(const SystemConfig& cfg, double sx, double sy)
      : wx(AreaWeights::make(cfg.n, cfg.pitch_m, cfg.sensor_size_px(), cfg.sensor_pitch_m, sx - axis_px(cfg.aperture_offset_x_m, cfg))),
        wy(AreaWeights::make(cfg.n, cfg.pitch_m, cfg.sensor_size_px(), cfg.sensor_pitch_m, sy - axis_px(cfg.aperture_offset_y_m, cfg))) {}
  static double axis_px(double offset_m, const SystemConfig& cfg) { return offset_m / cfg.sensor_pitch_m; }
};

void require_native(const RealStack& native, const SystemConfig& cfg, const char* what) {
  if (native.rows != cfg.n || native.cols != cfg.n)
    throw Error(std::string("integrate_registered: ") + what + " is " + shape(native) + ", expected planes x N x N with N = " +
                std::to_string(cfg.n));
}

// Unnormalised integration: out(p, oy, ox) = sum wy(oy, ty) wx(ox, tx) in(p, y0(oy) + ty, x0(ox) + tx).
RealStack integrate_raw(const RealStack& in, const RegisteredWeights& w) {
  const std::size_t n = in.rows, s = w.wx.s;
  RealStack rowsum(in.planes, n, s, 0.0), out(in.planes, s, s, 0.0);
  for (std::size_t p = 0; p < in.planes; ++p) {
    for (std::size_t y = 0; y < n; ++y)
      for (std::size_t ox = 0; ox < s; ++ox) {
        double acc = 0;
        for (std::size_t t = 0; t < w.wx.taps; ++t) {
          const long x = w.wx.start[ox] + long(t);
          if (x >= 0 && x < long(n)) acc += w.wx.w[ox * w.wx.taps + t] * in(p, y, std::size_t(x));
        }
        rowsum(p, y, ox) = acc;
      }
    for (std::size_t oy = 0; oy < s; ++oy)
      for (std::size_t t = 0; t < w.wy.taps; ++t) {
        const long y = w.wy.start[oy] + long(t);
        const double wt = w.wy.w[oy * w.wy.taps + t];
        if (y < 0 || y >= long(n) || wt == 0) continue;
        for (std::size_t ox = 0; ox < s; ++ox) out(p, oy, ox) += wt * rowsum(p, std::size_t(y), ox);
      }
  }
  return out;
}

// Its transpose: planes x S x S -> planes x N x N.
RealStack integrate_raw_adjoint(const RealStack& g, std::size_t n, const RegisteredWeights& w) {
  const std::size_t s = w.wx.s;
  RealStack rowsum(g.planes, n, s, 0.0), out(g.planes, n, n, 0.0);
  for (std::size_t p = 0; p < g.planes; ++p) {
    for (std::size_t oy = 0; oy < s; ++oy)
      for (std::size_t t = 0; t < w.wy.taps; ++t) {
        const long y = w.wy.start[oy] + long(t);
        const double wt = w.wy.w[oy * w.wy.taps + t];
        if (y < 0 || y >= long(n) || wt == 0) continue;
        for (std::size_t ox = 0; ox < s; ++ox) rowsum(p, std::size_t(y), ox) += wt * g(p, oy, ox);
      }
    for (std::size_t y = 0; y < n; ++y)
      for (std::size_t ox = 0; ox < s; ++ox)
        for (std::size_t t = 0; t < w.wx.taps; ++t) {
          const long x = w.wx.start[ox] + long(t);
          if (x >= 0 && x < long(n)) out(p, y, std::size_t(x)) += w.wx.w[ox * w.wx.taps + t] * rowsum(p, y, ox);
        }
  }
  return out;
}

std::vector<double> plane_sums(const RealStack& a) {
  std::vector<double> sums(a.planes, 0.0);
  for (std::size_t p = 0; p < a.planes; ++p)
    for (std::size_t i = 0; i < a.plane_size(); ++i) sums[p] += a.plane(p)[i];
  return sums;
}

}  // namespace

RealStack integrate_registered(const RealStack& native, const SystemConfig& cfg, double sx, double sy) {
  require_native(native, cfg, "the native stack");
  RealStack out = integrate_raw(native, RegisteredWeights(cfg, sx, sy));
  ref::normalize_planes(out);
  return out;
}

RealStack integrate_registered_adjoint(const RealStack& g_out, const RealStack& native, const SystemConfig& cfg, double sx, double sy) {
  require_native(native, cfg, "the native stack");
  const RegisteredWeights w(cfg, sx, sy);
  const std::size_t s = cfg.sensor_size_px();
  if (g_out.planes != native.planes || g_out.rows != s || g_out.cols != s)
    throw Error("integrate_registered_adjoint: the gradient is " + shape(g_out) + ", expected " + shape(native.planes, s, s));
  const RealStack raw = integrate_raw(native, w);
  const std::vector<double> sums = plane_sums(raw);
  RealStack y = raw;
  ref::normalize_planes(y);
  return integrate_raw_adjoint(ref::normalize_vjp(g_out, y, sums), cfg.n, w);
}

}  // namespace qdo
