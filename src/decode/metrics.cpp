// Reconstruction metrics (declared in include/qdo/decode/wiener.hpp, namespace metrics): PSNR, PSNR-H,
// SSIM, RMSE, ERGAS, SAM, with the conventions stated there.
#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include "qdo/runtime/error.hpp"
#include "qdo/decode/wiener.hpp"

namespace qdo {

namespace metrics {
namespace {

void check_pair(const RealStack& estimate, const RealStack& truth) {
  if (truth.size() == 0) reject("truth", shape(truth.planes, truth.rows, truth.cols), "a non-empty B x H x W cube");
  if (estimate.planes != truth.planes || estimate.rows != truth.rows || estimate.cols != truth.cols)
    reject("estimate", shape(estimate.planes, estimate.rows, estimate.cols),
           "the truth's shape " + shape(truth.planes, truth.rows, truth.cols));
}

double band_mse(const RealStack& estimate, const RealStack& truth, std::size_t b) {
  const double* e = estimate.plane(b);
  const double* t = truth.plane(b);
  double acc = 0;
  for (std::size_t i = 0; i < truth.plane_size(); ++i) acc += (e[i] - t[i]) * (e[i] - t[i]);
  return acc / double(truth.plane_size());
}

double psnr_of(double peak, double mse_value) {
  if (mse_value == 0) return std::numeric_limits<double>::infinity();
  return 10.0 * std::log10(peak * peak / mse_value);
}

}  // namespace

double mse(const RealStack& estimate, const RealStack& truth) {
  check_pair(estimate, truth);
  double acc = 0;
  for (std::size_t i = 0; i < truth.size(); ++i) acc += (estimate.data[i] - truth.data[i]) * (estimate.data[i] - truth.data[i]);
  return acc / double(truth.size());
}

double psnr(const RealStack& estimate, const RealStack& truth) { return psnr_of(1.0, mse(estimate, truth)); }

double psnr_hyper(const RealStack& estimate, const RealStack& truth) {
  check_pair(estimate, truth);
  double acc = 0;
  for (std::size_t b = 0; b < truth.planes; ++b) {
    const double* t = truth.plane(b);
    const double peak = *std::max_element(t, t + truth.plane_size());
    acc += psnr_of(peak, band_mse(estimate, truth, b));
  }
  return acc / double(truth.planes);
}

double psnr_per_band(const RealStack& estimate, const RealStack& truth) {
  check_pair(estimate, truth);
  double acc = 0;
  for (std::size_t b = 0; b < truth.planes; ++b) acc += psnr_of(1.0, band_mse(estimate, truth, b));
  return acc / double(truth.planes);
}

double rmse(const RealStack& estimate, const RealStack& truth) { return std::sqrt(mse(estimate, truth)); }

double ergas(const RealStack& estimate, const RealStack& truth) {
  check_pair(estimate, truth);
  double acc = 0;
  for (std::size_t b = 0; b < truth.planes; ++b) {
    const double* t = truth.plane(b);
    double mu = 0;
    for (std::size_t i = 0; i < truth.plane_size(); ++i) mu += t[i];
    mu /= double(truth.plane_size());
    if (mu == 0) reject("truth band " + to_str(b) + " mean", mu, "a non-zero mean (ERGAS divides by it)");
    acc += band_mse(estimate, truth, b) / (mu * mu);
  }
  return 100.0 * std::sqrt(acc / double(truth.planes));
}

double sam(const RealStack& estimate, const RealStack& truth) {
  check_pair(estimate, truth);
  const std::size_t n = truth.plane_size();
  if (n == 0) return 0.0;
  double acc = 0;
  for (std::size_t p = 0; p < n; ++p) {
    double dot = 0, ne = 0, nt = 0;
    for (std::size_t b = 0; b < truth.planes; ++b) {
      const double e = estimate.data[b * n + p], t = truth.data[b * n + p];
      dot += e * t;
      ne += e * e;
      nt += t * t;
    }
    // Zero spectra (see the header): both zero agree (0); one zero is orthogonal to anything (π/2).
    if (ne == 0 || nt == 0) {
      acc += (ne == 0 && nt == 0) ? 0.0 : M_PI / 2;
      continue;
    }
    const double cosine = std::clamp(dot / std::sqrt(ne * nt), -1.0, 1.0);
    acc += std::acos(cosine);
  }
  return acc / double(n);
}

double ssim(const RealStack& estimate, const RealStack& truth) {
  check_pair(estimate, truth);
  constexpr std::size_t kWin = 11;
  constexpr double kSigma = 1.5, kK1 = 0.01, kK2 = 0.03, kRange = 1.0;
  if (truth.rows < kWin || truth.cols < kWin)
    reject("image size", to_str(truth.rows) + " x " + to_str(truth.cols), "at least 11 x 11 (SSIM window, valid positions)");
  std::vector<double> g(kWin);
  double gsum = 0;
  for (std::size_t i = 0; i < kWin; ++i) {
    const double d = double(i) - double(kWin - 1) / 2.0;
    g[i] = std::exp(-d * d / (2.0 * kSigma * kSigma));
    gsum += g[i];
  }
  for (double& v : g) v /= gsum;
  const double c1 = (kK1 * kRange) * (kK1 * kRange), c2 = (kK2 * kRange) * (kK2 * kRange);
  const std::size_t h = truth.rows, w = truth.cols, oh = h - kWin + 1, ow = w - kWin + 1;
  // Separable "valid" Gaussian filtering of one rows x cols map: columns first, then rows.
  std::vector<double> tmp(oh * w), filtered[5], src(h * w);
  const auto filter = [&](std::vector<double>& out) {
    for (std::size_t y = 0; y < oh; ++y)
      for (std::size_t x = 0; x < w; ++x) {
        double acc = 0;
        for (std::size_t t = 0; t < kWin; ++t) acc += g[t] * src[(y + t) * w + x];
        tmp[y * w + x] = acc;
      }
    out.assign(oh * ow, 0.0);
    for (std::size_t y = 0; y < oh; ++y)
      for (std::size_t x = 0; x < ow; ++x) {
        double acc = 0;
        for (std::size_t t = 0; t < kWin; ++t) acc += g[t] * tmp[y * w + x + t];
        out[y * ow + x] = acc;
      }
  };
  double total = 0;
  for (std::size_t b = 0; b < truth.planes; ++b) {
    const double* xe = estimate.plane(b);
    const double* yt = truth.plane(b);
    const auto run = [&](int which, std::vector<double>& out) {
      for (std::size_t i = 0; i < h * w; ++i) {
        const double xv = xe[i], yv = yt[i];
        src[i] = which == 0 ? xv : which == 1 ? yv : which == 2 ? xv * xv : which == 3 ? yv * yv : xv * yv;
      }
      filter(out);
    };
    for (int k = 0; k < 5; ++k) run(k, filtered[k]);
    double band = 0;
    for (std::size_t i = 0; i < oh * ow; ++i) {
      const double mx = filtered[0][i], my = filtered[1][i];
      const double vx = filtered[2][i] - mx * mx, vy = filtered[3][i] - my * my, cxy = filtered[4][i] - mx * my;
      band += ((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2));
    }
    total += band / double(oh * ow);
  }
  return total / double(truth.planes);
}

}  // namespace metrics
}  // namespace qdo
