// The bilinear registration shift of the as-built fit (fit.hpp: shift_bilinear) and its adjoints
// with respect to the input and to the shift.
#include "qdo/design/fit.hpp"

#include <cmath>
#include <string>

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

// Visits every (output index, input index, weight, d weight / d sx, d weight / d sy) of the shift.
template <typename F>
void for_each_tap(std::size_t planes, std::size_t rows, std::size_t cols, double sx, double sy, F&& f) {
  const ShiftSplit x(sx), y(sy);
  const double wx[2] = {1 - x.f, x.f}, wy[2] = {1 - y.f, y.f}, dw[2] = {-1, 1};
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
            f(base + std::size_t(yy * c + xx), base + std::size_t(ys * c + xs), wy[a] * wx[b], wy[a] * dw[b], dw[a] * wx[b]);
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
  for_each_tap(planes, rows, cols, sx, sy, [&](std::size_t o, std::size_t i, double w, double, double) { out[o] += w * in[i]; });
  return out;
}

std::vector<double> shift_bilinear_adjoint(const std::vector<double>& g_out, std::size_t planes, std::size_t rows, std::size_t cols,
                                           double sx, double sy) {
  require_size(g_out, planes, rows, cols, "the gradient");
  std::vector<double> g(g_out.size(), 0.0);
  for_each_tap(planes, rows, cols, sx, sy, [&](std::size_t o, std::size_t i, double w, double, double) { g[i] += w * g_out[o]; });
  return g;
}

void shift_bilinear_derivative(const std::vector<double>& in, const std::vector<double>& g_out, std::size_t planes, std::size_t rows,
                               std::size_t cols, double sx, double sy, double& d_sx, double& d_sy) {
  require_size(in, planes, rows, cols, "the input");
  require_size(g_out, planes, rows, cols, "the gradient");
  d_sx = d_sy = 0;
  for_each_tap(planes, rows, cols, sx, sy, [&](std::size_t o, std::size_t i, double, double dx, double dy) {
    d_sx += g_out[o] * dx * in[i];
    d_sy += g_out[o] * dy * in[i];
  });
}

}  // namespace qdo
