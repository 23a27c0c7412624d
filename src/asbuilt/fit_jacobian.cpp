// The fit's Jacobian by differences of its model (fit_internal.hpp: difference_jacobian): the
// schemes of each column, apart from the model they difference.
#include <cmath>
#include <vector>

#include "qdo/runtime/error.hpp"

#include "fit_internal.hpp"

namespace qdo::fit_detail {

Eigen::MatrixXd difference_jacobian(const std::function<RealStack(const std::vector<double>&)>& model, const std::vector<double>& theta,
                                    const std::vector<JacobianColumn>& columns, std::size_t rows, const RealStack* at_theta) {
  if (columns.size() != theta.size())
    throw Error("difference_jacobian: " + std::to_string(columns.size()) + " columns for " + std::to_string(theta.size()) + " parameters");
  const std::size_t m = rows;
  Eigen::MatrixXd j(long(m), long(theta.size()));
  const auto set_column = [&](std::size_t k, const RealStack& fa, const RealStack& fb, double den) {
    if (fa.data.size() != m || fb.data.size() != m)
      throw Error("difference_jacobian: the model gave " + std::to_string(fa.data.size()) + " values, expected " + std::to_string(m));
    for (std::size_t i = 0; i < m; ++i) j(long(i), long(k)) = (fa.data[i] - fb.data[i]) / den;
  };
  const auto at = [&]() { return at_theta ? *at_theta : model(theta); };
  std::vector<std::size_t> order;
  for (std::size_t k = 0; k < columns.size(); ++k)
    if (!columns[k].late) order.push_back(k);
  for (std::size_t k = 0; k < columns.size(); ++k)
    if (columns[k].late) order.push_back(k);
  for (std::size_t k : order) {
    const JacobianColumn& c = columns[k];
    const double h = c.step;
    if (c.scheme == JacobianColumn::Scheme::Overlay) {
      // An overlay: the relief is linear in it between whole DOE pixels and kinks at each, so the
      // difference stays inside the current cell [floor, floor + 1) px (where the adjoint's
      // derivative is taken): central when both sides fit, else one-sided towards the cell's middle.
      const double px = theta[k] / c.pitch_m, frac = px - std::floor(px), hpx = h / c.pitch_m;
      const bool central = !at_theta && frac >= hpx && frac + hpx < 1;
      const double dir = frac < 0.5 ? 1.0 : -1.0;
      std::vector<double> a = theta, b = theta;
      a[k] += central ? h : dir * h;
      b[k] -= h;
      set_column(k, model(a), central ? model(b) : at(), central ? 2 * h : dir * h);
      continue;
    }
    if (c.scheme == JacobianColumn::Scheme::Offset) {
      // The offset: its whole pixels switch at each half pixel (optics.hpp move_relief, lround),
      // where the model steps by the light of the sensor window's edge column (fit.hpp). A
      // difference across a switch measures that step, not the slope (a sigma far too small
      // beside a truth on a switch): the differences stay on the offset's side of it, central
      // when both fit (and no stack at theta is given), else one-sided the way that does.
      const double u = (theta[k] - c.axis_m) / c.pitch_m, hpx = h / c.pitch_m;
      const long branch = std::lround(u);
      const bool up = std::lround(u + hpx) == branch, down = std::lround(u - hpx) == branch;
      if (!(up && down) || at_theta) {
        const double dir = up ? 1.0 : -1.0;
        std::vector<double> a = theta;
        a[k] += dir * h;
        set_column(k, model(a), at(), dir * h);
        continue;
      }
    }
    std::vector<double> a = theta, b = theta;
    a[k] += h;
    b[k] -= h;
    RealStack fa;
    try {
      fa = model(a);
    } catch (const InputError&) {
      // theta + h leaves the heights or the geometry the simulator takes (a level at the top of
      // its range): a backward difference from theta instead.
      set_column(k, at(), model(b), h);
      continue;
    }
    if (at_theta && c.one_sided) {
      set_column(k, fa, *at_theta, h);
      continue;
    }
    set_column(k, fa, model(b), 2 * h);
  }
  return j;
}

}  // namespace qdo::fit_detail
