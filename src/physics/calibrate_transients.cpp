// Step 4 of qdo calibrate (calibrate.hpp): transient hot pixels found across a band's exposures
// and against the adjacent bands, not by spatial isolation (a speckle peak is isolated too).
#include <algorithm>
#include <cmath>
#include <limits>

#include "qdo/physics/calibrate.hpp"
#include "qdo/physics/raw_reference.hpp"
#include "qdo/runtime/error.hpp"

namespace qdo {
namespace {

double median_in_place(std::vector<double>& v) {
  if (v.empty()) return 0;
  const std::size_t m = v.size() / 2;
  std::nth_element(v.begin(), v.begin() + long(m), v.end());
  if (v.size() % 2) return v[m];
  return 0.5 * (v[m] + *std::max_element(v.begin(), v.begin() + long(m)));
}

}  // namespace

double PixelGain::operator()(std::size_t b, std::size_t y, std::size_t x) const {
  if (!dead.empty() && dead[y * cols + x]) return 0;
  const int c = cfa == Cfa::None ? 0 : cfa_channel(cfa, y, x);
  const double w = response[b][std::size_t(c)];
  if (!(w >= min_response) || w <= 0) return 0;
  return flat ? w * flat->data[y * cols + x] : w;
}

std::vector<Map2D> exposure_excess(const std::vector<Map2D>& exposures_dn, const std::vector<double>& sigma_dn,
                                   double shot_dn, double hot_sigma, const std::vector<char>& skip) {
  const std::size_t k = exposures_dn.size();
  if (k == 0 || sigma_dn.size() != k) throw InputError("exposure_excess: one noise sigma per exposure");
  const std::size_t n = exposures_dn[0].data.size();
  std::vector<Map2D> z(k, Map2D(exposures_dn[0].rows, exposures_dn[0].cols));
  if (k < 2) return z;
  // Each exposure's brightness against the per-pixel median of all (a monochromator's power
  // drifts between exposures): the median ratio over the pixels lit well above the noise.
  double sig_mean = 0;
  for (double s : sigma_dn) sig_mean += s / double(k);
  std::vector<double> alpha(k, 1.0), vals(k);
  {
    std::vector<std::vector<double>> ratios(k);
    for (std::size_t i = 0; i < n; ++i) {
      if (!skip.empty() && skip[i]) continue;
      for (std::size_t e = 0; e < k; ++e) vals[e] = exposures_dn[e].data[i];
      const double ref = median_in_place(vals);
      if (ref > hot_sigma * sig_mean)
        for (std::size_t e = 0; e < k; ++e) ratios[e].push_back(exposures_dn[e].data[i] / ref);
    }
    for (std::size_t e = 0; e < k; ++e)
      if (!ratios[e].empty()) alpha[e] = median_in_place(ratios[e]);
  }
  // z_e(p) = (value - alpha_e x median of the others' value / alpha) / sd of that difference: the
  // exposure's noise (read sigma_e, shot from the expected value, not its own) and the median's,
  // pi/2 / (k - 1) of one exposure's variance (the median of k - 1 Gaussian values; a mean for
  // k - 1 <= 2, where pi/2 is an upper bound).
  const double med_factor = 1.5708 / double(k - 1);
  std::vector<double> others;
  for (std::size_t i = 0; i < n; ++i) {
    if (!skip.empty() && skip[i]) continue;
    for (std::size_t e = 0; e < k; ++e) {
      others.clear();
      for (std::size_t o = 0; o < k; ++o)
        if (o != e) others.push_back(exposures_dn[o].data[i] / alpha[o]);
      const double expect = alpha[e] * median_in_place(others);
      const double var = (sigma_dn[e] * sigma_dn[e] + shot_dn * std::max(expect, 0.0)) * (1 + med_factor);
      z[e].data[i] = (exposures_dn[e].data[i] - expect) / std::sqrt(var);
    }
  }
  return z;
}

Map2D adjacent_band_ceiling(std::size_t b, const std::vector<Map2D>& mean_dn, const std::vector<double>& mean_sigma_dn,
                            const std::vector<std::size_t>& exposures, const PixelGain& gain, double own_sigma_dn,
                            double shot_dn, double hot_sigma) {
  const std::size_t bands = mean_dn.size(), rows = mean_dn[b].rows, cols = mean_dn[b].cols;
  const double inf = std::numeric_limits<double>::infinity();
  Map2D ceiling(rows, cols, inf);
  if (bands < 2) return ceiling;
  // The two nearest other bands (both neighbours inside the sweep, the next two at its ends).
  std::vector<std::size_t> adj;
  if (b > 0 && b + 1 < bands)
    adj = {b - 1, b + 1};
  else if (b == 0)
    adj = bands > 2 ? std::vector<std::size_t>{1, 2} : std::vector<std::size_t>{1};
  else
    adj = bands > 2 ? std::vector<std::size_t>{b - 1, b - 2} : std::vector<std::size_t>{b - 1};
  // Each band's scale A: the expected raw value of pixel p is A_b x gain_b(p) x psf_b(p) with psf
  // of unit sum, so A_b ~ sum of the band's signal / mean gain (the light falls on every colour).
  std::vector<double> scale(bands, 0);
  std::vector<std::size_t> scaled = adj;
  scaled.push_back(b);
  for (std::size_t a : scaled) {
    double sum = 0, gsum = 0;
    for (std::size_t y = 0; y < rows; ++y)
      for (std::size_t x = 0; x < cols; ++x) {
        const double g = gain(a, y, x);
        if (g > 0) sum += mean_dn[a](y, x), gsum += g;
      }
    scale[a] = gsum > 0 ? sum / gsum : 0;
  }
  if (!(scale[b] > 0)) return ceiling;
  for (std::size_t a : adj)
    if (!(scale[a] > 0)) return ceiling;
  // Band a in PSF units, u_a = mean_a / (gain_a A_a), and that value's noise variance (-inf and 0
  // where band a measures nothing).
  std::vector<Map2D> u(adj.size(), Map2D(rows, cols, -inf)), uvar(adj.size(), Map2D(rows, cols));
  for (std::size_t j = 0; j < adj.size(); ++j) {
    const std::size_t a = adj[j];
    for (std::size_t y = 0; y < rows; ++y)
      for (std::size_t x = 0; x < cols; ++x) {
        const double ga = gain(a, y, x);
        if (!(ga > 0)) continue;
        const double v = mean_dn[a](y, x), f = 1 / (ga * scale[a]);
        u[j](y, x) = f * v;
        uvar[j](y, x) =
            f * f * (mean_sigma_dn[a] * mean_sigma_dn[a] + shot_dn * std::max(v, 0.0) / double(exposures[a]));
      }
  }
  for (std::size_t y = 0; y < rows; ++y)
    for (std::size_t x = 0; x < cols; ++x) {
      const double gb = gain(b, y, x);
      if (!(gb > 0)) continue;
      const double to_b = gb * scale[b];  // PSF units -> DN of band b at this pixel
      double top = -inf;
      for (std::size_t j = 0; j < adj.size(); ++j) {
        // Band a's prediction of this pixel: the largest of its 3 x 3 neighbourhood's values (a
        // speckle moves by up to a pixel between 10 nm bands: r dlambda / lambda, 0.5 px at 27 px
        // from the axis), and that value's noise.
        double best = -inf, best_var = 0;
        for (long dy = -1; dy <= 1; ++dy)
          for (long dx = -1; dx <= 1; ++dx) {
            const long yy = long(y) + dy, xx = long(x) + dx;
            if (yy < 0 || xx < 0 || yy >= long(rows) || xx >= long(cols)) continue;
            const double v = u[j](std::size_t(yy), std::size_t(xx));
            if (v > best) best = v, best_var = uvar[j](std::size_t(yy), std::size_t(xx));
          }
        if (best == -inf) {
          top = inf;  // no prediction from this band: untestable
          break;
        }
        const double pred = std::max(best, 0.0) * to_b;
        const double own_var = own_sigma_dn * own_sigma_dn + shot_dn * pred;
        top = std::max(top, (1 + kAdjacentBandRise) * pred + hot_sigma * std::sqrt(own_var + best_var * to_b * to_b));
      }
      ceiling(y, x) = top;
    }
  return ceiling;
}

}  // namespace qdo
