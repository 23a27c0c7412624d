// qdo calibrate on PSFs a mask or a shrinkage can bias (suite `calibrate`,
// include/qdo/physics/calibrate.hpp): a DOE's faint wide halo below every 5 x 5 window's noise,
// kept by the signal mask's larger windows, and a compact core, whose light the joint estimate
// must keep. The speckle's own cases are tests/test_calibrate_speckle.cpp; the fixtures
// tests/calibrate_common.hpp.
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <random>
#include <string>
#include <vector>

#include "calibrate_common.hpp"
#include "common.hpp"
#include "qdo/data/io.hpp"
#include "qdo/physics/calibrate.hpp"
#include "qdo/physics/raw_reference.hpp"

using namespace qdo;
using namespace qdo::test;
namespace fs = std::filesystem;

TEST_SUITE("calibrate") {
  TEST_CASE("a faint wide halo below every 5 x 5 window's noise is kept; around a compact core alone the larger windows cost little") {
    // A DOE's focused band can hold much of its light in a halo at under one noise sigma per
    // pixel. Here each band is a core (a Gaussian of sd 1.2 px, 2400 DN peak) and a speckled
    // halo (exponential speckle of mean 1 DN per pixel over a disk of radius 56 px: 31 % of the
    // light beyond 8 px), through the weak camera's mosaic with Poisson-Gaussian noise (read 2
    // DN). The halo's 5 x 5 window mean (~1 DN times the colour's response) is under that
    // window's 4 sigma (1.6 DN) everywhere; the 11 x 11 and 23 x 23 windows see it.
    // With the default windows the light beyond 8 px comes back within the noise of its sum:
    // 4 sd of the per-pixel estimates' sum over those pixels (each pixel's variance
    // (read² + 1/12 + 0.2 raw) / w², w its colour's response) over the band's light, plus what
    // the mask may cut at the halo's rim (under one 23 x 23 window's light, 529 DN; measured
    // within 2.1 sd). With the 5 x 5 window alone it is cut: under half of it is kept (measured
    // 2-8 % of the light against 31 %).
    // The band's relative L2 error is then under a quarter of the 5 x 5 mask's (measured 0.07 ..
    // 0.20 x: 0.028 .. 0.078 against 0.33 .. 0.44).
    // The control, the core alone: a larger window lit by noise keeps that noise (a false alarm
    // keeps a window whose mean stood floor_sigma sd above its noise). Its relative L2 error
    // against the true band must stay within the 5 x 5 mask's plus 0.01 (measured: equal in 26 of
    // 31 bands, at most +0.005 in the others), and the median band's at 1.02 x the 5 x 5 mask's
    // (measured 1.00; larger windows tested on all their pixels, lit by the core they contain,
    // gave 1.045).
    const Speckle& s = speckle();
    const SystemConfig& cfg = s.noisy;
    const std::size_t S = s.known.rows, H = kSpeckleFrame, c0 = S / 2;
    const double span = cfg.white_level_dn() - cfg.black_level_dn, g_dn = span / 20000, read = 0.0005 * span;
    auto radius2 = [&](std::size_t y, std::size_t x) {
      return std::pow(double(y) - double(c0), 2) + std::pow(double(x) - double(c0), 2);
    };
    std::vector<double> ratios;  // core alone: per band, relative L2 over the 5 x 5 mask's
    for (const bool halo : {true, false}) {
      const std::string tag = halo ? "halo" : "core";
      const fs::path d = s.dir / tag;
      fs::create_directories(d / "frames");
      fs::create_directories(d / "darks");
      std::vector<Map2D> truth;
      for (std::size_t b = 0; b < cfg.bands; ++b) {
        std::mt19937_64 rng(700 + b);
        std::exponential_distribution<double> speck(1.0);
        Map2D t(S, S);
        for (std::size_t y = 0; y < S; ++y)
          for (std::size_t x = 0; x < S; ++x)
            t(y, x) = 2400 * std::exp(-radius2(y, x) / (2 * 1.2 * 1.2)) + (halo && radius2(y, x) < 56.0 * 56.0 ? speck(rng) : 0.0);
        RealStack rgb(3, H, H);
        for (std::size_t c = 0; c < 3; ++c)
          for (std::size_t y = 0; y < S; ++y)
            for (std::size_t x = 0; x < S; ++x)
              rgb(c, y + kOffY, x + kOffX) = t(y, x) / span * rel_response(s.srf, long(c), b);
        const auto raw = ref::raw_forward(rgb, cfg, 300 + b);
        Map2D f(H, H);
        f.data = raw.raw.data;
        write_png16_gray((d / "frames" / nm_name(cfg.wavelengths_nm()[b])).string(), f);
        truth.push_back(t);
      }
      for (std::size_t k = 0; k < 4; ++k) {
        const auto raw = ref::raw_forward(RealStack(3, H, H), cfg, 400 + k);
        Map2D f(H, H);
        f.data = raw.raw.data;
        write_png16_gray((d / "darks" / ("dark_" + std::to_string(k) + ".png")).string(), f);
      }
      CalibrationOptions o = speckle_options();
      const CalibrationResult r = calibrate_psf(cfg, (d / "frames").string(), (d / "darks").string(), o);
      o.mask_windows = {5};
      const CalibrationResult r5 = calibrate_psf(cfg, (d / "frames").string(), (d / "darks").string(), o);
      for (std::size_t b = 0; b < cfg.bands; ++b) {
        double total = 0, beyond = 0, got = 0, got5 = 0, var = 0, e2 = 0, e25 = 0, t2 = 0;
        for (std::size_t y = 0; y < S; ++y)
          for (std::size_t x = 0; x < S; ++x)
            total += truth[b](y, x);
        for (std::size_t y = 0; y < S; ++y)
          for (std::size_t x = 0; x < S; ++x) {
            const double t = truth[b](y, x) / total;
            e2 += std::pow(r.psf(b, y, x) - t, 2);
            e25 += std::pow(r5.psf(b, y, x) - t, 2);
            t2 += t * t;
            if (radius2(y, x) <= 8.0 * 8.0) continue;
            beyond += t;
            got += r.psf(b, y, x);
            got5 += r5.psf(b, y, x);
            const double w = rel_response(s.srf, cfa_channel(Cfa::RGGB, y + kOffY, x + kOffX), b);
            var += (read * read + 1.0 / 12 + g_dn * w * truth[b](y, x)) / (w * w);
          }
        const double sd = std::sqrt(var) / total, l2 = std::sqrt(e2 / t2), l25 = std::sqrt(e25 / t2);
        INFO(tag << " band " << b << ": light beyond 8 px " << got << " (5 x 5 alone " << got5 << "), true " << beyond
                 << ", sd of its sum " << sd << "; relative L2 " << l2 << " (5 x 5 alone " << l25 << ")");
        if (halo) {
          CHECK(std::abs(got - beyond) <= 4 * sd + 529 / total);
          CHECK(got5 < 0.5 * beyond);
          CHECK(l2 <= 0.25 * l25);
        } else {
          CHECK(l2 <= l25 + 0.01);
          ratios.push_back(l2 / l25);
        }
      }
    }
    // Noise kept around every core (a larger window lit by the core it contains) would raise the
    // error in every band; false alarms raise it in a few: the median band is the 5 x 5 mask's.
    std::nth_element(ratios.begin(), ratios.begin() + long(ratios.size() / 2), ratios.end());
    MESSAGE("core alone: median relative L2 over the 5 x 5 mask's " << ratios[ratios.size() / 2]);
    CHECK(ratios[ratios.size() / 2] <= 1.02);
  }

  TEST_CASE("Poisson-Gaussian noise on a compact core: the joint estimate keeps the peak and the light") {
    // A Gaussian core of sd 1.2 px (2400 DN peak) under the noise of the test above, two seeds.
    // A spread learned in absolute units from the 7 x 7 window is set by the faint pixels around
    // the peak and shrinks the peak onto its neighbours' mean: that lost 10-20 % of the light,
    // at 1.9 x the per-pixel estimate's error where every colour responds. The spread in units
    // of the local level keeps it: the joint estimate must be within 1.2 x the per-pixel
    // estimate's relative L2 error where all colours respond >= 0.5 (measured 0.38 .. 0.44 x),
    // below it where one is weak (< 0.2), and its sum within 4 sd of the per-pixel estimates'
    // sum of the truth (that sum's sd from each pixel's variance).
    const Speckle& s = speckle();
    const std::size_t S = s.known.rows, c0 = S / 2;
    const double rv = kReadDn * kReadDn + 1.0 / 12;
    Map2D truth(S, S), rvm(S, S, rv);
    for (std::size_t y = 0; y < S; ++y)
      for (std::size_t x = 0; x < S; ++x)
        truth(y, x) = 2400 * std::exp(-(std::pow(double(y) - double(c0), 2) + std::pow(double(x) - double(c0), 2)) /
                                      (2 * 1.2 * 1.2));
    for (unsigned seed = 1; seed <= 2; ++seed) {
      std::mt19937_64 rng(seed);
      for (std::size_t b = 0; b < s.clean.bands; ++b) {
        const auto [raw, w, wmin] = noisy_mosaic(truth, b, rng);
        double var = 0;
        for (std::size_t i = 0; i < S * S; ++i)
          var += (rv + kShotDn * w.data[i] * truth.data[i]) / (w.data[i] * w.data[i]);
        const JointEstimate je = joint_pixel_estimate(raw, w, rvm, kShotDn);
        double ej = 0, ep = 0, tt = 0, sj = 0, st = 0;
        for (std::size_t i = 0; i < S * S; ++i) {
          ej += std::pow(je.value.data[i] - truth.data[i], 2);
          ep += std::pow(raw.data[i] / w.data[i] - truth.data[i], 2);
          tt += truth.data[i] * truth.data[i];
          sj += je.value.data[i];
          st += truth.data[i];
        }
        const double rj = std::sqrt(ej / tt), rp = std::sqrt(ep / tt);
        INFO("seed " << seed << " band " << b << " least response " << wmin << ": joint " << rj << ", per-pixel " << rp
                     << ", ratio " << rj / rp << "; sum " << sj << " against " << st << " (sd " << std::sqrt(var) << ")");
        if (wmin >= 0.5) CHECK(rj <= 1.2 * rp);
        if (wmin < 0.2) CHECK(rj < rp);
        CHECK(std::abs(sj - st) <= 4 * std::sqrt(var));
      }
    }
  }
}
