#include "qdo/physics/doe_adjoint_reference.hpp"

#include <algorithm>
#include <cmath>
#include <cstdlib>

#include "qdo/runtime/error.hpp"

namespace qdo::ref {

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
    if (l != q.pinned_level()) r.g_offsets[static_cast<std::size_t>(l)] += alpha * h_max_m * 0.5 / denom * g_out.data[i];
  }
  return r;
}

}  // namespace qdo::ref
