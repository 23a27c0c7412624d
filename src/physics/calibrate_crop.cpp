// Step 8 of qdo calibrate (calibrate.hpp: crop_band): one band's S x S crop, background, signal
// mask and unit sum.
#include <algorithm>
#include <cmath>
#include <vector>

#include "qdo/physics/calibrate.hpp"

namespace qdo {
namespace {

double median_of(std::vector<double> v) {
  if (v.empty()) return 0;
  const std::size_t m = v.size() / 2;
  std::nth_element(v.begin(), v.begin() + long(m), v.end());
  return v[m];
}

}  // namespace

Map2D crop_band(const Map2D& estimate, const Map2D& info, double sigma_dn, std::size_t y0, std::size_t x0,
                std::size_t s, double floor_sigma, bool ring_background) {
  std::vector<double> ring;
  for (std::size_t y = 0; y < s; ++y)
    for (std::size_t x = 0; x < s; ++x)
      if (y < 2 || x < 2 || y + 2 >= s || x + 2 >= s) ring.push_back(estimate(y0 + y, x0 + x));
  const double bg = ring_background ? median_of(ring) : 0.0;
  // The signal mask: the 5 x 5 mean of the crop above floor_sigma of its own noise, grown by
  // 2 px. That noise is sigma / sqrt(the window's sum of the pixels' own-estimate precisions
  // info): the noise of the best mean of their own estimates, which the joint estimates'
  // mean approaches (sigma / 5 for 25 pixels of one noise; the joint estimate's own sd would
  // count the noise its neighbourhood term shares with the next pixel's several times).
  // Inside the mask values are kept (negatives 0), outside they are 0: noise is neither
  // clamped into a bias over all S² pixels nor are faint wings next to the signal cut.
  Map2D v(s, s), prec(s, s);
  for (std::size_t y = 0; y < s; ++y)
    for (std::size_t x = 0; x < s; ++x) {
      v(y, x) = estimate(y0 + y, x0 + x) - bg;
      prec(y, x) = info(y0 + y, x0 + x);
    }
  // window_mean: the window's mean; any: 1 when a value in it is positive; sum: its sum.
  enum class Box { window_mean, any, sum };
  auto box = [&](const Map2D& m, std::size_t y, std::size_t x, long rad, Box what) {
    double acc = 0;
    int n = 0;
    for (long dy = -rad; dy <= rad; ++dy)
      for (long dx = -rad; dx <= rad; ++dx) {
        const long yy = long(y) + dy, xx = long(x) + dx;
        if (yy < 0 || xx < 0 || yy >= long(s) || xx >= long(s)) continue;
        const double e = m(std::size_t(yy), std::size_t(xx));
        if (what == Box::any && e > 0) return 1.0;
        acc += e;
        ++n;
      }
    return what == Box::any ? 0.0 : what == Box::sum ? acc : acc / n;
  };
  Map2D lit(s, s);
  for (std::size_t y = 0; y < s; ++y)
    for (std::size_t x = 0; x < s; ++x) {
      const double p = box(prec, y, x, 2, Box::sum);
      lit(y, x) = p > 0 && box(v, y, x, 2, Box::window_mean) > floor_sigma * sigma_dn / std::sqrt(p) ? 1 : 0;
    }
  Map2D kept(s, s);
  for (std::size_t y = 0; y < s; ++y)
    for (std::size_t x = 0; x < s; ++x) kept(y, x) = box(lit, y, x, 2, Box::any) > 0 ? v(y, x) : 0.0;
  // Negative values (noise) are spread onto their positive 8-neighbours, so the band's sum
  // stays an unbiased estimate of its energy (clamping them would add 0.4 sigma per masked
  // pixel); what no positive neighbour takes after 4 passes is set to 0.
  for (int pass = 0; pass < 4; ++pass)
    for (std::size_t y = 0; y < s; ++y)
      for (std::size_t x = 0; x < s; ++x) {
        if (kept(y, x) >= 0) continue;
        double pos = 0;
        for (long dy = -1; dy <= 1; ++dy)
          for (long dx = -1; dx <= 1; ++dx) {
            const long yy = long(y) + dy, xx = long(x) + dx;
            if ((dy || dx) && yy >= 0 && xx >= 0 && yy < long(s) && xx < long(s))
              pos += std::max(kept(std::size_t(yy), std::size_t(xx)), 0.0);
          }
        if (pos <= 0) continue;
        const double f = std::max(1 + kept(y, x) / pos, 0.0);  // each positive neighbour keeps this fraction
        const double taken = std::min(-kept(y, x), pos);
        for (long dy = -1; dy <= 1; ++dy)
          for (long dx = -1; dx <= 1; ++dx) {
            const long yy = long(y) + dy, xx = long(x) + dx;
            if ((dy || dx) && yy >= 0 && xx >= 0 && yy < long(s) && xx < long(s) &&
                kept(std::size_t(yy), std::size_t(xx)) > 0)
              kept(std::size_t(yy), std::size_t(xx)) *= f;
          }
        kept(y, x) += taken;
      }
  Map2D out(s, s);
  double sum = 0;
  for (std::size_t i = 0; i < s * s; ++i) sum += out.data[i] = std::max(kept.data[i], 0.0);
  if (sum > 0)
    for (double& o : out.data) o /= sum;
  return out;
}

}  // namespace qdo
