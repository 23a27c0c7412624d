// The calibration's speckle fixtures (suite `calibrate`: tests/test_calibrate_speckle.cpp,
// tests/test_calibrate_halo.cpp): a DOE's speckled PSF through a camera with colours of weak
// response, the frames' geometry, the calibration options that take the true axis, and the
// Poisson-Gaussian mosaic of the joint-estimate tests.
#pragma once
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <random>
#include <string>
#include <system_error>
#include <vector>

#include "common.hpp"
#include "qdo/data/config.hpp"
#include "qdo/data/io.hpp"
#include "qdo/physics/calibrate.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/raw_reference.hpp"

namespace qdo::test {

namespace fs = std::filesystem;

// Where the PSF's S x S window sits in a frame (as the lens sweep of tests/test_calibrate.cpp).
inline constexpr std::size_t kOffY = 13, kOffX = 27;

inline std::string nm_name(double nm) {
  char b[64];
  std::snprintf(b, sizeof b, "psf_%gnm.png", nm);
  return b;
}


// ---- A speckled PSF (a DOE's: structure one pixel wide) ----
// The design: the 550 nm lens with a random relief of 8 x 8 DOE-pixel blocks added (heights
// uniform in one 2 pi phase, wrapped), so the point images to a speckle cloud of ~27 px radius
// (the blocks' diffraction angle lambda / 32 um at z = 12.5 mm) of grains lambda z / D = 6.7 um,
// under one 8 um pixel; the speckle moves and changes between bands as a DOE's does.
// The camera: R rising 0.05 .. 1, B falling 1 .. 0.05, G a hump 0.5 .. 1, so R is weak (< 0.2 of
// the band's largest colour) at 400 .. 440 nm and B at 660 .. 700 nm; all three respond at >= 0.5
// only near 550 nm.
inline std::string weak_camera_csv() {
  std::string t = "wavelength_nm,R,G,B\n";
  for (int k = 0; k < 31; ++k) {
    const double u = k / 30.0, nm = 400 + 10 * k;
    t += std::to_string(int(nm)) + "," + std::to_string(0.05 + 0.95 * u) + "," +
         std::to_string(0.5 + 0.5 * std::exp(-std::pow((nm - 550) / 80, 2))) + "," + std::to_string(1 - 0.95 * u) +
         "\n";
  }
  return t;
}

struct Speckle {
  fs::path dir;
  SystemConfig clean, noisy;  // noise-free (12-bit rounding only) and Poisson-Gaussian sensors
  RealStack known;            // bands x S x S, the design's PSF (qdo psf)
  std::vector<double> amp;    // per band: the known stack's peak at 0.6 of the span (top colour)
  Eigen::MatrixXd srf;        // 3 x bands
};

// Read noise 0.0005 of the span (~2 DN), full well 20000 electrons (0.2 DN per electron: shot
// sd 22 DN at a 2400 DN peak).
inline constexpr const char* kSpeckleClean =
    R"({"preset": "small", "cfa": "rggb", "black_level_dn": 64, "bit_depth": 12, "read_noise_sigma": 0, "noise_seed": 3)";
inline constexpr const char* kSpeckleNoisy =
    R"({"preset": "small", "cfa": "rggb", "black_level_dn": 64, "bit_depth": 12, "read_noise_sigma": 0.0005, "full_well_photons": 20000, "noise_seed": 3)";

inline const Speckle& speckle() {
  static Speckle sp = [] {
    Speckle s;
    s.dir = temp_dir("calibrate_speckle");
    static const struct Removed {
      fs::path dir;
      ~Removed() {
        std::error_code ec;
        fs::remove_all(dir, ec);
      }
    } removed{s.dir};
    write_text_atomic((s.dir / "camera.csv").string(), weak_camera_csv());
    const std::string cam = ", \"camera\": \"" + (s.dir / "camera.csv").string() + "\"}";
    write_text_atomic((s.dir / "clean.json").string(), kSpeckleClean + cam);
    write_text_atomic((s.dir / "noisy.json").string(), kSpeckleNoisy + cam);
    s.clean = config_from_json_file((s.dir / "clean.json").string());
    s.noisy = config_from_json_file((s.dir / "noisy.json").string());
    Design d;
    d.height_m = lens_design(s.clean, 550);
    d.pitch_m = s.clean.pitch_m;
    const double hmax = s.clean.h_max_m();
    std::mt19937_64 rng(5);
    std::uniform_real_distribution<double> u(0, hmax);
    const std::size_t N = d.height_m.rows, blk = 8;
    std::vector<double> block((N / blk) * (N / blk));
    for (double& v : block) v = u(rng);
    for (std::size_t y = 0; y < N; ++y)
      for (std::size_t x = 0; x < N; ++x)
        d.height_m(y, x) = std::fmod(d.height_m(y, x) + block[(y / blk) * (N / blk) + x / blk], hmax);
    write_design((s.dir / "speckle.h5").string(), d);
    const Run r = qdo_run("psf --config " + (s.dir / "clean.json").string() + " --design " +
                              (s.dir / "speckle.h5").string() + " --out " + (s.dir / "known").string(),
                          "QDO_DEVICE=cpu");
    REQUIRE_MESSAGE(r.code == 0, r.out);
    s.known = read_psf_stack_file((s.dir / "known/psf.h5").string()).psf_sensor;
    s.srf = sensor_response(s.clean);
    const std::size_t S = s.known.rows;
    for (std::size_t b = 0; b < s.clean.bands; ++b) {
      double peak = 0;
      for (std::size_t i = 0; i < S * S; ++i) peak = std::max(peak, s.known.data[b * S * S + i]);
      s.amp.push_back(0.6 / peak);
    }
    return s;
  }();
  return sp;
}

// Colour c's response at band b relative to the band's largest colour.
inline double rel_response(const Eigen::MatrixXd& srf, long c, std::size_t b) {
  return srf(c, long(b)) / std::max({srf(0, long(b)), srf(1, long(b)), srf(2, long(b))});
}


// The speckle's frames: 256 x 256, so that most pixels are unlit (the noise sigma is the MAD of
// the frame; the speckle and its side lobes fill much of the S x S = 128 x 128 window).
inline constexpr std::size_t kSpeckleFrame = 256;


// Calibration options of the speckle tests: the true axis as the centre (no registration in the
// comparison) and the dark alone as background (the speckle has energy out to the crop's edge).
inline CalibrationOptions speckle_options() {
  CalibrationOptions o;
  o.ring_background = false;
  o.centre = CentreRule::given;
  o.centre_row = long(kOffY + speckle().known.rows / 2);
  o.centre_col = long(kOffX + speckle().known.rows / 2);
  return o;
}


// The noise of the joint-estimate tests: 12 bits, read noise 0.0005 of the span (2 DN), 0.2 DN
// per electron (full well 20000), Poisson-Gaussian.
inline constexpr double kSpan = 4031, kShotDn = kSpan / 20000, kReadDn = 0.0005 * kSpan;

// Band b's RGGB mosaic (S x S, pixel (0, 0) red) of truth (DN per unit response, S x S) under that
// noise, drawn from rng pixel by pixel in row-major order: raw codes, each pixel's relative
// response w, and the least response.
struct NoisyMosaic {
  Map2D raw, w;
  double wmin = 1;
};
inline NoisyMosaic noisy_mosaic(const Map2D& truth, std::size_t b, std::mt19937_64& rng) {
  const Speckle& s = speckle();
  const std::size_t S = truth.rows;
  std::normal_distribution<double> gauss(0, kReadDn);
  NoisyMosaic m{Map2D(S, S), Map2D(S, S)};
  for (std::size_t y = 0; y < S; ++y)
    for (std::size_t x = 0; x < S; ++x) {
      m.w(y, x) = rel_response(s.srf, cfa_channel(Cfa::RGGB, y, x), b);
      m.wmin = std::min(m.wmin, m.w(y, x));
      std::poisson_distribution<long> pois(m.w(y, x) * truth(y, x) / kShotDn);
      m.raw(y, x) = std::round(kShotDn * double(pois(rng)) + gauss(rng));
    }
  return m;
}

}  // namespace qdo::test
