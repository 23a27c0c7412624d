// Step 8 of qdo calibrate (calibrate.hpp: crop_band): one band's S x S crop, background, signal
// mask and unit sum.
#include <algorithm>
#include <cmath>
#include <vector>

#include "qdo/physics/calibrate.hpp"
#include "calibrate_internal.hpp"

namespace qdo {
using calibrate_detail::median_of;

Map2D crop_band(const Map2D& estimate, const Map2D& info, double sigma_dn, std::size_t y0, std::size_t x0,
                std::size_t s, double floor_sigma, bool ring_background, const std::vector<std::size_t>& mask_windows) {
  std::vector<double> ring;
  for (std::size_t y = 0; y < s; ++y)
    for (std::size_t x = 0; x < s; ++x)
      if (y < 2 || x < 2 || y + 2 >= s || x + 2 >= s) ring.push_back(estimate(y0 + y, x0 + x));
  const double bg = ring_background ? median_of(ring) : 0.0;
  // The signal mask, over the windows mask_windows (default 5, 11, 23 px). First the mean of
  // each pixel's first window (5 x 5) above floor_sigma of its own noise, the window kept whole
  // (grown by 2 px). That noise is sigma / sqrt(the window's sum of the pixels' own-estimate
  // precisions info): the noise of the best mean of their own estimates, which the joint
  // estimates' mean approaches (sigma / 5 for 25 pixels of one noise; the joint estimate's own sd
  // would count the noise its neighbourhood term shares with the next pixel's several times).
  // Then the 11 x 11 and the 23 x 23 windows, each tested on the light the smaller scales
  // have not kept (the window's pixels outside the mask so far, their mean against its noise), and
  // every pixel of a lit window kept: a DOE's wide halo, below the noise of every 5 x 5 window,
  // is kept where it stands above a larger window's, while around a compact PSF, whose light the
  // small scale already holds, the larger windows see noise and keep nothing (a window tested on
  // all its pixels would be lit by the core it contains and keep noise around every PSF).
  // Inside the mask values are kept (negatives spread, below), outside they are 0: noise is
  // neither clamped into a bias over all S² pixels nor are faint wings next to the signal cut.
  Map2D v(s, s), prec(s, s);
  for (std::size_t y = 0; y < s; ++y)
    for (std::size_t x = 0; x < s; ++x) {
      v(y, x) = estimate(y0 + y, x0 + x) - bg;
      prec(y, x) = info(y0 + y, x0 + x);
    }
  // Sums over the (2 rad + 1)² window of each pixel, inside the crop, of f(y, x) where the mask
  // is 0 (integral images, (s + 1)², row-major).
  Map2D mask(s, s);
  auto window_sums = [&](long rad, const Map2D& f) {
    std::vector<double> in((s + 1) * (s + 1), 0.0);
    for (std::size_t y = 0; y < s; ++y)
      for (std::size_t x = 0; x < s; ++x)
        in[(y + 1) * (s + 1) + x + 1] = (mask(y, x) > 0 ? 0.0 : f(y, x)) + in[y * (s + 1) + x + 1] +
                                        in[(y + 1) * (s + 1) + x] - in[y * (s + 1) + x];
    Map2D out(s, s);
    for (std::size_t y = 0; y < s; ++y)
      for (std::size_t x = 0; x < s; ++x) {
        // The window's rows [ya, yb) and columns [xa, xb), inside the crop.
        const auto lo = [&](std::size_t i) { return std::size_t(std::max(0L, long(i) - rad)); };
        const auto hi = [&](std::size_t i) { return std::size_t(std::min(long(s), long(i) + rad + 1)); };
        const std::size_t ya = lo(y), yb = hi(y), xa = lo(x), xb = hi(x);
        out(y, x) = in[yb * (s + 1) + xb] - in[ya * (s + 1) + xb] - in[yb * (s + 1) + xa] + in[ya * (s + 1) + xa];
      }
    return out;
  };
  Map2D ones(s, s);
  for (double& o : ones.data) o = 1;
  for (std::size_t k = 0; k < mask_windows.size(); ++k) {
    const long rad = long(mask_windows[k] / 2);
    const Map2D sv = window_sums(rad, v), sp = window_sums(rad, prec), sn = window_sums(rad, ones);
    Map2D lit(s, s);
    bool any = false;
    for (std::size_t y = 0; y < s; ++y)
      for (std::size_t x = 0; x < s; ++x) {
        // At least half the window still unmasked: a window mostly inside the mask tests a few
        // pixels at its edge, which the smaller scale has already judged (a window cut by the
        // crop's edge counts its pixels inside).
        const double half = 0.5 * double((2 * rad + 1) * (2 * rad + 1));  // of the window's pixels
        const bool test = k == 0 || sn(y, x) >= half;
        if (test && sp(y, x) > 0 && sv(y, x) / sn(y, x) > floor_sigma * sigma_dn / std::sqrt(sp(y, x))) {
          lit(y, x) = 1;
          any = true;
        }
      }
    if (!any) continue;
    // Every pixel of a lit window joins the mask: a separable box dilation of lit by rad, each
    // axis by running counts (a pixel is reached when a lit one lies within rad along it).
    const auto reached = [&](const std::vector<double>& prefix, std::size_t i) {
      const long a = std::max(0L, long(i) - rad), b = std::min(long(s), long(i) + rad + 1);
      return prefix[std::size_t(b)] - prefix[std::size_t(a)] > 0;
    };
    Map2D rows(s, s);
    std::vector<double> prefix(s + 1);
    for (std::size_t y = 0; y < s; ++y) {
      for (std::size_t x = 0; x < s; ++x) prefix[x + 1] = prefix[x] + lit(y, x);
      for (std::size_t x = 0; x < s; ++x) rows(y, x) = reached(prefix, x) ? 1 : 0;
    }
    for (std::size_t x = 0; x < s; ++x) {
      for (std::size_t y = 0; y < s; ++y) prefix[y + 1] = prefix[y] + rows(y, x);
      for (std::size_t y = 0; y < s; ++y)
        if (reached(prefix, y)) mask(y, x) = 1;
    }
  }
  Map2D kept(s, s);
  for (std::size_t i = 0; i < s * s; ++i) kept.data[i] = mask.data[i] > 0 ? v.data[i] : 0.0;
  // Negative values (noise) are spread onto their positive neighbours, so the band's sum stays
  // an unbiased estimate of its energy (clamping them would add 0.4 sigma per masked pixel):
  // first the 8-neighbours, then, for what is left, ever wider squares (radius 2 .. 6), as a
  // faint halo's negatives can outweigh their 8 neighbours' light; what no positive pixel
  // within 6 px takes is set to 0.
  for (const long rad : {1L, 1L, 2L, 2L, 3L, 4L, 6L})
    for (std::size_t y = 0; y < s; ++y)
      for (std::size_t x = 0; x < s; ++x) {
        if (kept(y, x) >= 0) continue;
        const long ya = std::max(0L, long(y) - rad), yb = std::min(long(s) - 1, long(y) + rad);
        const long xa = std::max(0L, long(x) - rad), xb = std::min(long(s) - 1, long(x) + rad);
        double pos = 0;
        for (long yy = ya; yy <= yb; ++yy)
          for (long xx = xa; xx <= xb; ++xx) pos += std::max(kept(std::size_t(yy), std::size_t(xx)), 0.0);
        if (pos <= 0) continue;
        const double f = std::max(1 + kept(y, x) / pos, 0.0);  // each positive neighbour keeps this fraction
        const double taken = std::min(-kept(y, x), pos);
        for (long yy = ya; yy <= yb; ++yy)
          for (long xx = xa; xx <= xb; ++xx)
            if (kept(std::size_t(yy), std::size_t(xx)) > 0) kept(std::size_t(yy), std::size_t(xx)) *= f;
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
