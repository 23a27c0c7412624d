// Raw captures from qdo simulate (suite `simulate-raw`): --raw writes the capture as the sensor as
// built records it (mosaic, black level, bit depth, noise; checked on a red-only scene), and
// --capture psf-sweep writes a monochromator sweep and darks that qdo calibrate turns back into the
// design's PSF stack.
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <sstream>
#include <string>
#include <vector>

#include "common.hpp"
#include "qdo/data/config.hpp"
#include "qdo/data/io.hpp"
#include "qdo/physics/raw_reference.hpp"

using namespace qdo;
using namespace qdo::test;
namespace fs = std::filesystem;

namespace {

// A camera CSV on the 400 .. 700 nm grid: rows (R, G, B) per band from f(nm).
template <typename F>
std::string camera_csv(F f) {
  std::string t = "wavelength_nm,R,G,B\n";
  for (int k = 0; k < 31; ++k) {
    const double nm = 400 + 10 * k;
    const auto v = f(nm);
    t += std::to_string(int(nm)) + "," + std::to_string(v[0]) + "," + std::to_string(v[1]) + "," + std::to_string(v[2]) + "\n";
  }
  return t;
}

std::string slurp_file(const fs::path& p) {
  std::ifstream f(p);
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

struct Removed {
  fs::path dir;
  ~Removed() {
    std::error_code ec;
    fs::remove_all(dir, ec);
  }
};

}  // namespace

TEST_SUITE("simulate-raw") {
  TEST_CASE("--raw on a red-only scene: green and blue sites read the black level +- noise, 12-bit codes, the demosaic is red") {
    const fs::path dir = temp_dir("simraw");
    const Removed removed{dir};
    // R responds only at 610 .. 700 nm, G and B only below 600 nm; the scene is lit only at 610 .. 700 nm.
    write_text_atomic((dir / "camera.csv").string(), camera_csv([](double nm) {
                        return std::vector<double>{nm > 605 ? 1.0 : 0.0, nm < 595 ? 1.0 : 0.0, nm < 595 ? 0.5 + (600 - nm) / 400 : 0.0};
                      }));
    const double black = 64, sigma = 0.001;
    write_text_atomic((dir / "cfg.json").string(),
                      "{\"preset\": \"small\", \"cfa\": \"grbg\", \"black_level_dn\": 64, \"bit_depth\": 12, \"read_noise_sigma\": 0.001, "
                      "\"noise_seed\": 3, \"camera\": \"" + (dir / "camera.csv").string() + "\"}");
    const SystemConfig cfg = config_from_json_file((dir / "cfg.json").string());
    RealStack cube(cfg.bands, 64, 64);
    const std::vector<double> wl = cfg.wavelengths_nm();
    for (std::size_t b = 0; b < cfg.bands; ++b)
      for (std::size_t i = 0; i < cube.plane_size(); ++i) cube.plane(b)[i] = wl[b] > 605 ? 0.3 + 0.4 * double(i % 64) / 63 : 0.0;
    write_cube((dir / "red.h5").string(), cube, wl);
    const std::string base = "simulate --config " + (dir / "cfg.json").string() + " --design lens:550 --scene " + (dir / "red.h5").string();
    const Run r = qdo_run(base + " --raw --out " + (dir / "out").string(), "QDO_DEVICE=cpu");
    REQUIRE_MESSAGE(r.code == 0, r.out);
    CHECK(r.out.find("raw: cfa grbg, 12-bit, black level 64 DN") != std::string::npos);
    CHECK(r.out.find("demosaic mhc") != std::string::npos);
    const Map2D png = read_png16_gray((dir / "out/raw.png").string());
    const H5Dataset h5 = h5_read((dir / "out/raw.h5").string(), "/raw");
    REQUIRE(png.rows == 64);
    REQUIRE(png.cols == 64);
    CHECK(h5.data == png.data);
    const double span = cfg.white_level_dn() - black, noise_dn = sigma * span;  // ~4 DN
    double red_sum = 0, other_sum = 0;
    std::size_t red_n = 0, other_n = 0, off = 0;
    for (std::size_t y = 0; y < 64; ++y)
      for (std::size_t x = 0; x < 64; ++x) {
        const double v = png(y, x);
        CHECK(v == std::floor(v));
        CHECK(v >= 0);
        CHECK(v <= 4095);
        if (cfa_channel(Cfa::GRBG, y, x) == 0) {
          red_sum += v;
          ++red_n;
        } else {
          other_sum += v;
          ++other_n;
          // 6 sigma and the rounding's half DN: 4096 samples, none should stray.
          if (std::fabs(v - black) > 6 * noise_dn + 0.5) ++off;
        }
      }
    CAPTURE(off);
    CHECK(off == 0);
    CHECK(std::fabs(other_sum / double(other_n) - black) <= 5 * noise_dn / std::sqrt(double(other_n)) + 0.05);
    CHECK(red_sum / double(red_n) > black + 0.2 * span);  // the red sites see the scene (0.3 .. 0.7 of full well, blurred)
    // The demosaic in linear units: red carries the scene. (MHC's green and blue also carry red's
    // edges, by design: its gradient correction reads the site's own colour; bilinear's below do not.)
    auto planes = [](const fs::path& f) {
      const H5Dataset dm = h5_read(f.string(), "/rgb_demosaiced");
      REQUIRE(dm.shape == std::vector<std::size_t>{3, 64, 64});
      double r_mean = 0, gb_max = 0;
      for (std::size_t i = 0; i < 64 * 64; ++i) {
        r_mean += dm.data[i] / (64 * 64);
        gb_max = std::max({gb_max, std::fabs(dm.data[64 * 64 + i]), std::fabs(dm.data[2 * 64 * 64 + i])});
      }
      return std::make_pair(r_mean, gb_max);
    };
    const auto [r_mhc, gb_mhc] = planes(dir / "out/raw.h5");
    CHECK(r_mhc > 0.2);
    CHECK(gb_mhc > 10 * sigma);  // the red edges' correction
    CHECK(fs::exists(dir / "out/raw_demosaiced.png"));
    CHECK(fs::exists(dir / "out/sensor.png"));
    // The raw stage's noise is seeded: the same command gives the same raw frame.
    const Run again = qdo_run(base + " --raw --demosaic bilinear --out " + (dir / "again").string(), "QDO_DEVICE=cpu");
    REQUIRE_MESSAGE(again.code == 0, again.out);
    CHECK(read_png16_gray((dir / "again/raw.png").string()).data == png.data);
    CHECK(again.out.find("demosaic bilinear") != std::string::npos);
    // Bilinear: green and blue are averages of green and blue sites, noise around 0 (6 sigma and
    // the half-DN rounding over 8192 values).
    const auto [r_bil, gb_bil] = planes(dir / "again/raw.h5");
    CHECK(r_bil > 0.2);
    CHECK(gb_bil < 6 * sigma + 0.5 / span);
    // Without --raw nothing raw is written.
    const Run plain = qdo_run(base + " --out " + (dir / "plain").string(), "QDO_DEVICE=cpu");
    REQUIRE_MESSAGE(plain.code == 0, plain.out);
    CHECK_FALSE(fs::exists(dir / "plain/raw.png"));
    // Refusals, before any work (exit 2), naming the option and what is allowed.
    const Run none = qdo_run("simulate --preset small --design lens:550 --raw --out " + (dir / "none").string(), "QDO_DEVICE=cpu");
    CHECK(none.code == 2);
    CHECK(none.out.find("--raw") != std::string::npos);
    CHECK(none.out.find("mosaic") != std::string::npos);
    CHECK_FALSE(fs::exists(dir / "none"));
    const Run dm_only = qdo_run(base + " --demosaic mhc --out " + (dir / "dm").string(), "QDO_DEVICE=cpu");
    CHECK(dm_only.code == 2);
    CHECK(dm_only.out.find("only with --raw") != std::string::npos);
    const Run bad_dm = qdo_run(base + " --raw --demosaic ahd --out " + (dir / "dm2").string(), "QDO_DEVICE=cpu");
    CHECK(bad_dm.code == 2);
    CHECK(bad_dm.out.find("bilinear") != std::string::npos);
    const Run bad_cap = qdo_run(base + " --capture video --out " + (dir / "cap").string(), "QDO_DEVICE=cpu");
    CHECK(bad_cap.code == 2);
    CHECK(bad_cap.out.find("psf-sweep") != std::string::npos);
    const Run sweep_opt = qdo_run(base + " --peak 0.5 --out " + (dir / "pk").string(), "QDO_DEVICE=cpu");
    CHECK(sweep_opt.code == 2);
    CHECK(sweep_opt.out.find("only with --capture psf-sweep") != std::string::npos);
  }

  TEST_CASE("--capture psf-sweep: the sweep and darks it writes go through qdo calibrate back to the design's PSF stack") {
    const fs::path dir = temp_dir("simsweep");
    const Removed removed{dir};
    // Every colour responds at every band (as in the calibrate suite's sweep), so no colour is filled
    // from its neighbours: R rising, B falling, G a hump.
    write_text_atomic((dir / "camera.csv").string(), camera_csv([](double nm) {
                        const double u = (nm - 400) / 300;
                        return std::vector<double>{0.1 + 0.9 * u, 0.5 + 0.5 * std::exp(-std::pow((nm - 550) / 80, 2)), 1 - 0.9 * u};
                      }));
    write_text_atomic((dir / "cfg.json").string(),
                      "{\"preset\": \"small\", \"cfa\": \"rggb\", \"black_level_dn\": 64, \"bit_depth\": 12, \"read_noise_sigma\": 0.0005, "
                      "\"noise_seed\": 7, \"camera\": \"" + (dir / "camera.csv").string() + "\"}");
    const std::string cfg = "--config " + (dir / "cfg.json").string();
    const SystemConfig c = config_from_json_file((dir / "cfg.json").string());
    const std::size_t S = c.sensor_size_px(), F = S + 40;
    const Run s = qdo_run("simulate " + cfg + " --capture psf-sweep --design lens:550 --frame-size " + std::to_string(F) +
                              " --peak 0.6 --darks 4 --centre 81,95 --out " + (dir / "sweep").string(),
                          "QDO_DEVICE=cpu");
    REQUIRE_MESSAGE(s.code == 0, s.out);
    CHECK(s.out.find("0 % of frame pixels saturated") != std::string::npos);
    for (double nm : c.wavelengths_nm()) {
      char name[64];
      std::snprintf(name, sizeof name, "psf_%gnm.png", nm);
      CHECK(fs::exists(dir / "sweep/frames" / name));
    }
    for (int k = 0; k < 4; ++k) CHECK(fs::exists(dir / "sweep/darks" / ("dark_" + std::to_string(k) + ".png")));
    CHECK(fs::exists(dir / "sweep/frames.png"));
    // A dark frame: the black level with read noise (0.0005 of 4031 DN, ~2 DN) and the rounding.
    const Map2D dark = read_png16_gray((dir / "sweep/darks/dark_0.png").string());
    REQUIRE(dark.rows == F);
    double m = 0, v = 0;
    for (double x : dark.data) m += x / double(dark.data.size());
    for (double x : dark.data) v += (x - m) * (x - m) / double(dark.data.size() - 1);
    const double sd = std::hypot(0.0005 * 4031, 1 / std::sqrt(12.0));
    CHECK(std::fabs(m - 64) <= 5 * sd / std::sqrt(double(dark.data.size())));
    CHECK(std::fabs(std::sqrt(v) - sd) <= 0.05 * sd);
    // Band frames: the brightest pixel is black + 0.6 of the span (within noise and the
    // mosaic: the peak may fall on a colour at its full response).
    const Map2D f550 = read_png16_gray((dir / "sweep/frames/psf_550nm.png").string());
    const double top = *std::max_element(f550.data.begin(), f550.data.end());
    CHECK(top <= 64 + 0.6 * 4031 + 10);
    CHECK(top >= 64 + 0.2 * 4031);  // the axis may fall on a colour at 0.55 of the brightest
    // The stack imaged is the design's (qdo psf).
    const Run p = qdo_run("psf " + cfg + " --design lens:550 --out " + (dir / "known").string(), "QDO_DEVICE=cpu");
    REQUIRE_MESSAGE(p.code == 0, p.out);
    const RealStack known = read_psf_stack_file((dir / "known/psf.h5").string()).psf_sensor;
    CHECK(diff(read_psf_stack_file((dir / "sweep/psf.h5").string()).psf_sensor.data, known.data).max_abs <= 1e-12);
    // Calibrated back: the centre is the one given, and every band correlates with the design's
    // (the calibrate suite's bound for its own synthetic sweep).
    const Run cal = qdo_run("calibrate " + cfg + " --frames " + (dir / "sweep/frames").string() + " --darks " +
                                (dir / "sweep/darks").string() + " --design lens:550 --out " + (dir / "cal").string(),
                            "QDO_DEVICE=cpu");
    REQUIRE_MESSAGE(cal.code == 0, cal.out);
    CHECK(cal.out.find("centre (row 81, column 95)") != std::string::npos);
    std::istringstream rows(slurp_file(dir / "cal/compare.csv"));
    std::string line;
    std::getline(rows, line);
    std::size_t bands = 0;
    double worst = 1;
    while (std::getline(rows, line)) {
      const double corr = std::stod(line.substr(line.find(',') + 1));
      worst = std::min(worst, corr);
      CHECK_MESSAGE(corr > 0.97, line);
      ++bands;
    }
    MESSAGE("least correlation over bands: " << worst);
    CHECK(bands == c.bands);
    // Refusals: a centre whose window leaves the frame, a sweep without a bit depth.
    const Run off = qdo_run("simulate " + cfg + " --capture psf-sweep --design lens:550 --frame-size " + std::to_string(F) +
                                " --centre 10,95 --out " + (dir / "off").string(),
                            "QDO_DEVICE=cpu");
    CHECK(off.code == 2);
    CHECK(off.out.find("--centre") != std::string::npos);
    const Run scene = qdo_run("simulate " + cfg + " --capture psf-sweep --design lens:550 --scene builtin --out " + (dir / "sc").string(),
                              "QDO_DEVICE=cpu");
    CHECK(scene.code == 2);
    CHECK(scene.out.find("--scene") != std::string::npos);
  }
}
