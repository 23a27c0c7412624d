// qdo calibrate (suite `calibrate`, include/qdo/physics/calibrate.hpp): a synthetic monochromator sweep
// made from a known simulated PSF stack through the sensor as built (ref::raw_forward: RGGB
// mosaic, black level, read noise, 12-bit quantization) with an offset, a fixed hot pixel (in the
// darks too) and a transient one, is calibrated back to the known stack; every refusal exits 2
// naming the file; the output is accepted by `qdo simulate --psf`. A DOE's speckled PSF with
// colours of weak response is tests/test_calibrate_speckle.cpp.
#include <tiffio.h>

#include <tuple>
#include <random>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "common.hpp"
#include "qdo/physics/calibrate.hpp"
#include "qdo/data/config.hpp"
#include "qdo/data/io.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/raw_reference.hpp"

using namespace qdo;
using namespace qdo::test;
namespace fs = std::filesystem;

namespace {

// The sensor settings of the sweep; "camera" (a CSV written next to it) is added by config_text.
constexpr const char* kConfig =
    R"({"preset": "small", "cfa": "rggb", "black_level_dn": 64, "bit_depth": 12, "read_noise_sigma": 0.0005, "noise_seed": 7)";
std::string config_text(const fs::path& dir, const std::string& cfa = "rggb") {
  std::string t = kConfig;
  t.replace(t.find("rggb"), 4, cfa);
  return t + ", \"camera\": \"" + (dir / "camera.csv").string() + "\"}";
}
// A camera whose three colours all respond at 430 .. 670 nm (R rising, B falling, G a hump), so
// only the defocused end bands (400 .. 420 nm: R; 680 .. 700 nm: B) fill a colour from neighbours.
std::string camera_csv() {
  std::string t = "wavelength_nm,R,G,B\n";
  for (int k = 0; k < 31; ++k) {
    const double u = k / 30.0, nm = 400 + 10 * k;
    t += std::to_string(int(nm)) + "," + std::to_string(0.1 + 0.9 * u) + "," +
         std::to_string(0.5 + 0.5 * std::exp(-std::pow((nm - 550) / 80, 2))) + "," + std::to_string(1 - 0.9 * u) + "\n";
  }
  return t;
}
constexpr std::size_t kOffY = 13, kOffX = 27, kMargin = 40;

std::string nm_name(double nm) {
  char b[64];
  std::snprintf(b, sizeof b, "psf_%gnm.png", nm);
  return b;
}

// The known stack (qdo psf, lens:550) and a sweep of it in DIR/frames and DIR/darks.
struct Sweep {
  fs::path dir, cfg_path;
  SystemConfig cfg;
  RealStack known;          // bands x S x S
  std::vector<double> amp;  // per band, peak of the brightest colour in full-scale units
};

const Sweep& sweep() {
  static Sweep sw = [] {
    Sweep s;
    s.dir = temp_dir("calibrate");
    static const struct Removed {  // the sweep's folder goes when the test binary ends
      fs::path dir;
      ~Removed() {
        std::error_code ec;
        fs::remove_all(dir, ec);
      }
    } removed{s.dir};
    s.cfg_path = s.dir / "cfg.json";
    write_text_atomic((s.dir / "camera.csv").string(), camera_csv());
    write_text_atomic(s.cfg_path.string(), config_text(s.dir));
    s.cfg = config_from_json_file(s.cfg_path.string());
    const Run r = qdo_run("psf --config " + s.cfg_path.string() + " --design lens:550 --out " + (s.dir / "known").string(),
                          "QDO_DEVICE=cpu");
    REQUIRE_MESSAGE(r.code == 0, r.out);
    s.known = read_psf_stack_file((s.dir / "known/psf.h5").string()).psf_sensor;
    const std::size_t S = s.known.rows, H = S + kMargin, bands = s.cfg.bands;
    const Eigen::MatrixXd srf = sensor_response(s.cfg);
    fs::create_directories(s.dir / "frames");
    fs::create_directories(s.dir / "darks");
    const double black = s.cfg.black_level_dn;
    for (std::size_t b = 0; b < bands; ++b) {
      double peak = 0;
      for (std::size_t i = 0; i < S * S; ++i) peak = std::max(peak, s.known.data[b * S * S + i]);
      const double top = std::max({srf(0, long(b)), srf(1, long(b)), srf(2, long(b))});
      s.amp.push_back(0.6 / peak);
      RealStack rgb(3, H, H);
      for (std::size_t c = 0; c < 3; ++c)
        for (std::size_t y = 0; y < S; ++y)
          for (std::size_t x = 0; x < S; ++x) rgb(c, y + kOffY, x + kOffX) = s.amp[b] * s.known(b, y, x) * srf(long(c), long(b)) / top;
      const auto raw = ref::raw_forward(rgb, s.cfg, b);
      Map2D f(H, H);
      for (std::size_t i = 0; i < H * H; ++i) f.data[i] = raw.raw.data[i];
      f(5, H - 6) += 800;                 // fixed hot pixel (also in the darks)
      if (b == 3) f(H - 8, 9) = 3000;     // transient hot pixel
      write_png16_gray((s.dir / "frames" / nm_name(s.cfg.wavelengths_nm()[b])).string(), f);
    }
    for (std::size_t k = 0; k < 4; ++k) {
      const auto raw = ref::raw_forward(RealStack(3, H, H), s.cfg, 100 + k);
      Map2D f(H, H);
      for (std::size_t i = 0; i < H * H; ++i) f.data[i] = raw.raw.data[i];
      f(5, H - 6) += 800;
      write_png16_gray((s.dir / "darks" / ("dark_" + std::to_string(k) + ".png")).string(), f);
    }
    (void)black;
    return s;
  }();
  return sw;
}

// A copy of the sweep's frames folder as DIR/<tag>.
fs::path frames_copy(const std::string& tag) {
  const fs::path to = sweep().dir / tag;
  fs::create_directories(to);
  for (const auto& e : fs::directory_iterator(sweep().dir / "frames")) fs::copy_file(e.path(), to / e.path().filename());
  return to;
}

// qdo calibrate with a configuration, frames and darks of the test's choice, into DIR/<out>.
Run calibrate_with(const fs::path& cfg, const fs::path& frames, const fs::path& darks, const std::string& out,
                   const std::string& extra = "") {
  return qdo_run("calibrate --config " + cfg.string() + " --frames " + frames.string() + " --darks " + darks.string() + " --out " +
                     (sweep().dir / out).string() + " " + extra,
                 "QDO_DEVICE=cpu");
}

// ... with the sweep's configuration and darks.
Run calibrate(const fs::path& frames, const std::string& out, const std::string& extra = "") {
  return calibrate_with(sweep().cfg_path, frames, sweep().dir / "darks", out, extra);
}

}  // namespace

TEST_SUITE("calibrate") {
  TEST_CASE("wavelengths from file names") {
    CHECK(wavelength_from_file_name("a/psf_550nm.png") == 550);
    CHECK(wavelength_from_file_name("x_y_552.5nm.PNG") == 552.5);
    CHECK(wavelength_from_file_name("psf550.png") < 0);
  }

  TEST_CASE("a synthetic sweep is calibrated back to the known stack, and simulate --psf takes it") {
    const Sweep& s = sweep();
    const Run r = calibrate(s.dir / "frames", "out", "--design lens:550");
    REQUIRE_MESSAGE(r.code == 0, r.out);
    // The fixed hot pixel (in the darks) in each of the 31 bands, and the transient of band 3,
    // found against the adjacent bands (no other pixel: a lit ring is no transient).
    CHECK_MESSAGE(r.out.find("32 hot pixels replaced, 1 of them transient") != std::string::npos, r.out);
    const auto got = read_psf_stack_file((s.dir / "out/psf.h5").string());
    REQUIRE(got.psf_sensor.planes == s.known.planes);
    REQUIRE(got.psf_sensor.rows == s.known.rows);
    const std::size_t S = s.known.rows, n = S * S;
    // Expected: the known stack through the noise-free part of the steps (the ring's median
    // subtracted, negatives 0, unit sum: the known PSF has energy out to the crop's edge).
    // Tolerance from the noise: band b's noise in unit-sum units is sigma_b = sigma_dn /
    // (w_b * A_b * (white - black)), sigma_dn = read noise 0.0005 of white - black (~2 DN) with
    // the 12-bit rounding, w_b the band's least colour response (0.1 .. 1: every colour is used,
    // none filled blind), A_b the brightest colour's peak. A pixel errs by its own noise (<= 5
    // sigma over S² = 16384 pixels; the joint estimate leans on its neighbours only where they
    // predict it, so no more), by a wing the signal mask cut (a pixel whose 5 x 5 mean is below 4
    // sigma / 5: up to ~9 sigma on a ring's edge) and by the normalisation (the sum's noise,
    // sqrt(masked pixels) sigma_b, up to 2 % of the peak): 14 sigma_b + 2 % of the peak. L1 over
    // the band: mean |noise| (0.8 sigma) per pixel, at most S² sigma_b. (Until the joint estimate,
    // bands with a colour below 0.2 of the largest, 400 .. 420 and 680 .. 700 nm, had that colour
    // filled from its neighbours, exact only where the PSF is smooth at 2 px, which the defocus
    // rings there are not; they were held to the L1 bound + 0.1 only, measured 0.05 .. 0.11.)
    const double span = s.cfg.white_level_dn() - s.cfg.black_level_dn;
    const double sigma_dn = std::hypot(0.0005 * span, 1 / std::sqrt(12.0));
    const Eigen::MatrixXd srf = sensor_response(s.cfg);
    for (std::size_t b = 0; b < s.cfg.bands; ++b) {
      std::vector<double> ring, expect(n);
      for (std::size_t y = 0; y < S; ++y)
        for (std::size_t x = 0; x < S; ++x)
          if (y < 2 || x < 2 || y + 2 >= S || x + 2 >= S) ring.push_back(s.known(b, y, x));
      std::nth_element(ring.begin(), ring.begin() + long(ring.size() / 2), ring.end());
      double esum = 0;
      for (std::size_t i = 0; i < n; ++i) esum += expect[i] = std::max(0.0, s.known.data[b * n + i] - ring[ring.size() / 2]);
      const double top = std::max({srf(0, long(b)), srf(1, long(b)), srf(2, long(b))});
      double w = 1;
      for (long c = 0; c < 3; ++c) w = std::min(w, srf(c, long(b)) / top);
      const double sigma_b = sigma_dn / (w * s.amp[b] * span);
      double worst = 0, l1 = 0, peak = 0;
      for (std::size_t i = 0; i < n; ++i) {
        const double d = std::abs(got.psf_sensor.data[b * n + i] - expect[i] / esum);
        worst = std::max(worst, d);
        l1 += d;
        peak = std::max(peak, expect[i] / esum);
      }
      INFO("band " << b << ": max error " << worst << " (sigma_b " << sigma_b << ", peak " << peak << "), L1 " << l1);
      CHECK(worst <= 14 * sigma_b + 0.02 * peak);
      CHECK(l1 <= double(n) * sigma_b);
    }
    // The signal mask as used, in psf.h5's provenance.
    CHECK(h5_read_root_attrs((s.dir / "out/psf.h5").string()).at("signal_mask") == "windows 5,11,23 px at 4 sigma");
    const std::string csv = slurp(s.dir / "out/compare.csv");
    CHECK(csv.find("correlation") != std::string::npos);
    CHECK(fs::exists(s.dir / "out/compare.png"));
    // The sweep was made from lens:550 itself: every band correlates with the simulated one.
    std::istringstream rows(csv);
    std::string line;
    std::getline(rows, line);
    std::size_t count = 0;
    while (std::getline(rows, line)) {
      const double corr = std::stod(line.substr(line.find(',') + 1));
      CHECK_MESSAGE(corr > 0.97, line);
      ++count;
    }
    CHECK(count == s.cfg.bands);
    CHECK(fs::exists(s.dir / "out/psf.png"));
    const Run sim = qdo_run("simulate --config " + s.cfg_path.string() + " --psf " + (s.dir / "out/psf.h5").string() + " --out " +
                                (s.dir / "sim").string(),
                            "QDO_DEVICE=cpu");
    CHECK_MESSAGE(sim.code == 0, sim.out);
  }

  TEST_CASE("16-bit TIFF and DNG frames and darks calibrate exactly as the PNG ones; RGB TIFF frames, broken DNGs and DNG metadata that contradicts the configuration are refused") {
    const Sweep& s = sweep();
    // The io round trip: grayscale and RGB code values unchanged.
    RealStack rgb(3, 5, 7);
    for (std::size_t i = 0; i < rgb.data.size(); ++i) rgb.data[i] = double((i * 2654435761u) % 65536);
    write_tiff16((s.dir / "rgb.tif").string(), rgb);
    CHECK(read_tiff16((s.dir / "rgb.tif").string()).data == rgb.data);
    CHECK(read_capture16((s.dir / "rgb.tif").string()).planes == 3);
    CHECK_THROWS_WITH_AS(read_tiff16((s.dir / "darks" / "dark_0.png").string()), doctest::Contains("not a readable TIFF"), InputError);
    CHECK_THROWS_WITH_AS(read_capture16((s.dir / "x.bmp").string()), doctest::Contains("x.bmp"), InputError);

    const fs::path tf = s.dir / "tiff_frames", td = s.dir / "tiff_darks";
    fs::create_directories(tf);
    fs::create_directories(td);
    const auto to_tiff = [](const fs::path& from, const fs::path& to) {
      const Map2D g = read_png16_gray(from.string());
      RealStack t(1, g.rows, g.cols);
      t.data = g.data;
      write_tiff16(to.string(), t);
    };
    for (const auto& e : fs::directory_iterator(s.dir / "frames")) to_tiff(e.path(), tf / e.path().filename().replace_extension(".tif"));
    for (const auto& e : fs::directory_iterator(s.dir / "darks")) to_tiff(e.path(), td / e.path().filename().replace_extension(".tiff"));
    const Run png = calibrate(s.dir / "frames", "o_png");
    REQUIRE_MESSAGE(png.code == 0, png.out);
    const Run tif = calibrate_with(s.cfg_path, tf, td, "o_tif");
    REQUIRE_MESSAGE(tif.code == 0, tif.out);
    CHECK(read_psf_stack_file((s.dir / "o_tif/psf.h5").string()).psf_sensor.data ==
          read_psf_stack_file((s.dir / "o_png/psf.h5").string()).psf_sensor.data);

    const fs::path bad = s.dir / "tiff_rgb";
    fs::create_directories(bad);
    for (const auto& e : fs::directory_iterator(tf)) fs::copy_file(e.path(), bad / e.path().filename());
    write_tiff16((bad / nm_name(550)).replace_extension(".tif").string(), RealStack(3, s.known.rows + kMargin, s.known.rows + kMargin, 64));
    const Run r = calibrate(bad, "o_tiff_rgb");
    CHECK(r.code == 2);
    CHECK_MESSAGE(r.out.find("this one is RGB") != std::string::npos, r.out);
    // Several pages (a stack of exposures) and untyped samples are refused, naming the file and
    // what it holds, in the reader that calibrate and reconstruct share.
    auto write_pages = [&](const fs::path& path, int pages, std::uint16_t format) {
      TIFF* t = TIFFOpen(path.string().c_str(), "w");
      REQUIRE(t != nullptr);
      const std::vector<std::uint16_t> row(7, 1000);
      for (int p = 0; p < pages; ++p) {
        TIFFSetField(t, TIFFTAG_IMAGEWIDTH, 7);
        TIFFSetField(t, TIFFTAG_IMAGELENGTH, 5);
        TIFFSetField(t, TIFFTAG_BITSPERSAMPLE, 16);
        TIFFSetField(t, TIFFTAG_SAMPLESPERPIXEL, 1);
        TIFFSetField(t, TIFFTAG_SAMPLEFORMAT, format);
        TIFFSetField(t, TIFFTAG_PHOTOMETRIC, PHOTOMETRIC_MINISBLACK);
        TIFFSetField(t, TIFFTAG_PLANARCONFIG, PLANARCONFIG_CONTIG);
        for (std::uint32_t y = 0; y < 5; ++y) REQUIRE(TIFFWriteScanline(t, const_cast<std::uint16_t*>(row.data()), y, 0) >= 0);
        REQUIRE(TIFFWriteDirectory(t));
      }
      TIFFClose(t);
    };
    write_pages(s.dir / "pages.tif", 3, SAMPLEFORMAT_UINT);
    write_pages(s.dir / "one_page.tif", 1, SAMPLEFORMAT_UINT);
    write_pages(s.dir / "untyped.tif", 1, SAMPLEFORMAT_VOID);
    CHECK(read_tiff16((s.dir / "one_page.tif").string()).data == std::vector<double>(35, 1000.0));
    CHECK_THROWS_WITH_AS(read_tiff16((s.dir / "pages.tif").string()), doctest::Contains("pages.tif': holds 3 pages"), InputError);
    CHECK_THROWS_WITH_AS(read_tiff16((s.dir / "untyped.tif").string()), doctest::Contains("SampleFormat 4"), InputError);
    const fs::path paged = s.dir / "tiff_paged";
    fs::create_directories(paged);
    for (const auto& e : fs::directory_iterator(tf)) fs::copy_file(e.path(), paged / e.path().filename());
    fs::copy_file(s.dir / "pages.tif", paged / "psf_550nm.tif", fs::copy_options::overwrite_existing);
    const Run rp = calibrate(paged, "o_paged");
    CHECK(rp.code == 2);
    CHECK_MESSAGE(rp.out.find("holds 3 pages") != std::string::npos, rp.out);
    const fs::path dng = frames_copy("dng");
    std::ofstream(dng / "psf_550nm.dng") << "not a frame";
    const Run rd = calibrate(dng, "o_dng");
    CHECK(rd.code == 2);
    CHECK_MESSAGE(rd.out.find("psf_550nm.dng") != std::string::npos, rd.out);
    // Camera raw: the same codes as DNG files (the configuration's RGGB mosaic, black 64 DN, white
    // 4095 DN in the metadata) calibrate exactly as the PNG frames do.
    const auto to_dng = [](const fs::path& from, const fs::path& to, const std::string& cfa, double black) {
      write_dng_mosaic(to.string(), read_png16_gray(from.string()), cfa, black, 4095);
    };
    const fs::path df = s.dir / "dng_frames", dd = s.dir / "dng_darks";
    fs::create_directories(df);
    fs::create_directories(dd);
    for (const auto& e : fs::directory_iterator(s.dir / "frames")) to_dng(e.path(), df / e.path().filename().replace_extension(".dng"), "rggb", 64);
    for (const auto& e : fs::directory_iterator(s.dir / "darks")) to_dng(e.path(), dd / e.path().filename().replace_extension(".DNG"), "rggb", 64);
    const Run raw = calibrate_with(s.cfg_path, df, dd, "o_dng_ok");
    REQUIRE_MESSAGE(raw.code == 0, raw.out);
    CHECK(read_psf_stack_file((s.dir / "o_dng_ok/psf.h5").string()).psf_sensor.data ==
          read_psf_stack_file((s.dir / "o_png/psf.h5").string()).psf_sensor.data);
    // Metadata that contradicts the configuration: named, with the setting to change.
    for (const auto& [cfa, black, expect] : std::vector<std::tuple<std::string, double, std::string>>{
             {"grbg", 64, "\"cfa\": \"grbg\""}, {"rggb", 60, "\"black_level_dn\": 60"}}) {
      CAPTURE(cfa);
      const fs::path odd = s.dir / ("dng_" + cfa + "_" + std::to_string(int(black)));
      fs::create_directories(odd);
      for (const auto& e : fs::directory_iterator(df)) fs::copy_file(e.path(), odd / e.path().filename());
      to_dng(s.dir / "frames" / nm_name(550), odd / "psf_550nm.dng", cfa, black);
      const Run r2 = calibrate_with(s.cfg_path, odd, dd, "o_" + odd.filename().string());
      CHECK(r2.code == 2);
      CHECK_MESSAGE(r2.out.find("psf_550nm.dng") != std::string::npos, r2.out);
      CHECK_MESSAGE(r2.out.find(expect) != std::string::npos, r2.out);
    }
  }

  TEST_CASE("--white: frames seen through unequal colour gains and pixel responses calibrate as the plain ones once the flat field divides them") {
    const Sweep& s = sweep();
    const double black = s.cfg.black_level_dn, top = s.cfg.white_level_dn();
    // The sensor's gains: R 1.2, G 1, B 0.85 and a 3 % pixel response pattern, mean 1.
    const Map2D first = read_png16_gray((s.dir / "frames" / nm_name(550)).string());
    const std::size_t R = first.rows, C = first.cols;
    Map2D gain(R, C);
    const double colour[3] = {1.2, 1.0, 0.85};
    double mean = 0;
    for (std::size_t y = 0; y < R; ++y)
      for (std::size_t x = 0; x < C; ++x) {
        gain(y, x) = colour[cfa_channel(Cfa::RGGB, y, x)] * (1 + 0.03 * std::sin(0.9 * double(y) + 1.7 * double(x)));
        mean += gain(y, x) / double(R * C);
      }
    for (double& g : gain.data) g /= mean;
    const fs::path gf = s.dir / "gained_frames", wf = s.dir / "whites";
    fs::create_directories(gf);
    fs::create_directories(wf);
    for (const auto& e : fs::directory_iterator(s.dir / "frames")) {
      Map2D m = read_png16_gray(e.path().string());
      for (std::size_t i = 0; i < m.data.size(); ++i) m.data[i] = std::min(top - 1, std::round(black + (m.data[i] - black) * gain.data[i]));
      write_png16_gray((gf / e.path().filename()).string(), m);
    }
    for (int k = 0; k < 2; ++k) {
      Map2D w(R, C);
      for (std::size_t i = 0; i < w.data.size(); ++i) w.data[i] = std::round(black + 1800 * gain.data[i]);
      write_png16_gray((wf / ("white_" + std::to_string(k) + ".png")).string(), w);
    }
    const Run plain = calibrate(s.dir / "frames", "o_plain");
    REQUIRE_MESSAGE(plain.code == 0, plain.out);
    const Run raw = calibrate(gf, "o_gained");
    REQUIRE_MESSAGE(raw.code == 0, raw.out);
    const Run flat = calibrate(gf, "o_flat", "--white " + wf.string());
    REQUIRE_MESSAGE(flat.code == 0, flat.out);
    const RealStack want = read_psf_stack_file((s.dir / "o_plain/psf.h5").string()).psf_sensor;
    auto rel = [&](const std::string& out) {
      const RealStack got = read_psf_stack_file((s.dir / out / "psf.h5").string()).psf_sensor;
      double num = 0, den = 0;
      for (std::size_t i = 0; i < want.data.size(); ++i) {
        num += (got.data[i] - want.data[i]) * (got.data[i] - want.data[i]);
        den += want.data[i] * want.data[i];
      }
      return std::sqrt(num / den);
    };
    const double err_flat = rel("o_flat"), err_raw = rel("o_gained");
    CAPTURE(err_flat);
    CAPTURE(err_raw);
    CHECK(err_flat < 0.01);             // the frames' 12-bit rounding, twice (measured 0.0037)
    CHECK(err_raw > 3 * err_flat);      // the gains, left in, are visible
    const H5Dataset g = h5_read((s.dir / "o_flat/psf.h5").string(), "/white_channel_gains");
    REQUIRE(g.data.size() == 3);
    CHECK(g.data[0] / g.data[1] == doctest::Approx(1.2).epsilon(5e-3));
    CHECK(g.data[2] / g.data[1] == doctest::Approx(0.85).epsilon(5e-3));
  }

  TEST_CASE("--centre: auto takes the frame's centre within 4 px of the light's centroid, else the centroid with a note; centroid, frame and ROW,COL on request") {
    // The sweep puts the lens's axis (its centroid: the lens PSF is symmetric) at frame pixel
    // (kOffY + S/2, kOffX + S/2) = (77, 91) of 168 x 168, 9.9 px from the frame's centre (84, 84).
    const Sweep& s = sweep();
    const std::size_t S = s.known.rows;
    const long ay = long(kOffY + S / 2), ax = long(kOffX + S / 2);
    auto attrs = [&](const std::string& out) { return h5_read_root_attrs((s.dir / out / "psf.h5").string()); };
    {  // far from the frame's centre: the centroid, said in a note and in psf.h5
      const Run r = calibrate(s.dir / "frames", "c_far");
      REQUIRE_MESSAGE(r.code == 0, r.out);
      CHECK(attrs("c_far").at("centre_row_col") == std::to_string(ay) + "," + std::to_string(ax));
      CHECK(attrs("c_far").at("centre_rule").rfind("centroid (automatic: ", 0) == 0);
      CHECK_MESSAGE(r.out.find("give --centre ROW,COL at the axis's pixel") != std::string::npos, r.out);
    }
    {  // --centre frame: the frame's centre whatever the light
      const Run r = calibrate(s.dir / "frames", "c_frame", "--centre frame");
      REQUIRE_MESSAGE(r.code == 0, r.out);
      CHECK(attrs("c_frame").at("centre_row_col") == "84,84");
      CHECK(attrs("c_frame").at("centre_rule") == "frame centre");
    }
    // The frames and darks cropped to rows 6 .. 149 and columns 16 .. 159 (even offsets keep the
    // RGGB phase): 144 x 144 with its centre (72, 72) at the sweep's (78, 88), where the light's
    // centroid is (71, 75) in the crop: 3.2 px away.
    const std::size_t r0 = 6, c0 = 16, F = 144;
    auto crop_folder = [&](const fs::path& from, const fs::path& to) {
      fs::create_directories(to);
      for (const auto& e : fs::directory_iterator(from)) {
        const Map2D f = read_png16_gray(e.path().string());
        Map2D c(F, F);
        for (std::size_t y = 0; y < F; ++y)
          for (std::size_t x = 0; x < F; ++x) c(y, x) = f(r0 + y, c0 + x);
        write_png16_gray((to / e.path().filename()).string(), c);
      }
    };
    crop_folder(s.dir / "frames", s.dir / "crop_frames");
    crop_folder(s.dir / "darks", s.dir / "crop_darks");
    auto cropped = [&](const std::string& out, const std::string& extra) {
      return calibrate_with(s.cfg_path, s.dir / "crop_frames", s.dir / "crop_darks", out, extra);
    };
    const Run aut = cropped("c_auto", "");
    REQUIRE_MESSAGE(aut.code == 0, aut.out);
    const std::string cy = std::to_string(ay - long(r0)), cx = std::to_string(ax - long(c0));
    CHECK(cy + "," + cx == "71,75");
    CHECK(attrs("c_auto").at("centre_row_col") == "72,72");
    CHECK(attrs("c_auto").at("centre_rule").rfind("frame centre (automatic: the light's centroid (", 0) == 0);
    CHECK_MESSAGE(aut.out.find("give --centre") == std::string::npos, aut.out);
    const Run cen = cropped("c_centroid", "--centre centroid");
    REQUIRE_MESSAGE(cen.code == 0, cen.out);
    CHECK(attrs("c_centroid").at("centre_row_col") == cy + "," + cx);
    CHECK(attrs("c_centroid").at("centre_rule") == "centroid");
    // The automatic frame centre is the given one, pixel for pixel; the centroid's stack is the
    // same light one pixel up and three to the right of it.
    const Run giv = cropped("c_given", "--centre 72,72");
    REQUIRE_MESSAGE(giv.code == 0, giv.out);
    CHECK(attrs("c_given").at("centre_rule") == "given");
    const RealStack a = read_psf_stack_file((s.dir / "c_auto/psf.h5").string()).psf_sensor;
    const RealStack g = read_psf_stack_file((s.dir / "c_given/psf.h5").string()).psf_sensor;
    const RealStack c = read_psf_stack_file((s.dir / "c_centroid/psf.h5").string()).psf_sensor;
    CHECK(max_abs_diff(a.data, g.data) == 0);
    const std::size_t b = 15;  // 550 nm, the lens's focus: a compact peak
    auto argmax = [&](const RealStack& st) {
      const auto* p = st.data.data() + b * S * S;
      return std::size_t(std::max_element(p, p + S * S) - p);
    };
    CHECK(argmax(c) == (S / 2) * S + S / 2);
    CHECK(argmax(a) == (S / 2 - 1) * S + S / 2 + 3);
    for (const char* bad : {"middle", "1,2,3"}) {
      const Run r = cropped("c_bad", std::string("--centre ") + bad);
      CHECK(r.code == 2);
      CHECK_MESSAGE((r.out.find("--centre") != std::string::npos && r.out.find("centroid, frame, or ROW,COL") != std::string::npos), r.out);
      CHECK(!fs::exists(s.dir / "c_bad/psf.h5"));
    }
  }

  TEST_CASE("refusals exit 2 naming the file") {
    const Sweep& s = sweep();
    const std::size_t H = s.known.rows + kMargin;
    {  // a missing band
      const fs::path d = frames_copy("missing");
      fs::remove(d / nm_name(430));
      const Run r = calibrate(d, "o_missing");
      CHECK(r.code == 2);
      CHECK_MESSAGE(r.out.find("no frame for the configured band 430 nm") != std::string::npos, r.out);
      CHECK(!fs::exists(s.dir / "o_missing/psf.h5"));
    }
    {  // a wavelength that is not a band
      const fs::path d = frames_copy("extra");
      fs::copy_file(d / nm_name(430), d / nm_name(435));
      const Run r = calibrate(d, "o_extra");
      CHECK(r.code == 2);
      CHECK_MESSAGE(r.out.find(nm_name(435)) != std::string::npos, r.out);
    }
    {  // a saturated frame
      const fs::path d = frames_copy("saturated");
      Map2D f = read_png16_gray((d / nm_name(550)).string());
      f(H / 2, H / 2) = s.cfg.white_level_dn();
      write_png16_gray((d / nm_name(550)).string(), f);
      const Run r = calibrate(d, "o_sat");
      CHECK(r.code == 2);
      CHECK_MESSAGE((r.out.find(nm_name(550)) != std::string::npos && r.out.find("saturated") != std::string::npos), r.out);
    }
    {  // frames of different sizes
      const fs::path d = frames_copy("size");
      write_png16_gray((d / nm_name(600)).string(), Map2D(H - 2, H, 64));
      const Run r = calibrate(d, "o_size");
      CHECK(r.code == 2);
      CHECK_MESSAGE((r.out.find(nm_name(600)) != std::string::npos && r.out.find("differs") != std::string::npos), r.out);
    }
    {  // a frame too dark (a dark frame in place of the 450 nm frame)
      const fs::path d = frames_copy("dark");
      fs::remove(d / nm_name(450));
      fs::copy_file(s.dir / "darks/dark_0.png", d / nm_name(450));
      const Run r = calibrate(d, "o_dark");
      CHECK(r.code == 2);
      CHECK_MESSAGE((r.out.find(nm_name(450)) != std::string::npos && r.out.find("too dark") != std::string::npos), r.out);
    }
    {  // the crop leaves the frame
      const Run r = calibrate(s.dir / "frames", "o_crop", "--centre 10,10");
      CHECK(r.code == 2);
      CHECK_MESSAGE((r.out.find("leaves the") != std::string::npos && r.out.find(".png") != std::string::npos), r.out);
    }
    for (const char* bad : {"4", "5,5", "11,5", "1", "301", "5,x"}) {  // signal-mask windows
      const Run r = calibrate(s.dir / "frames", "o_windows", std::string("--mask-windows ") + bad);
      CHECK(r.code == 2);
      CHECK_MESSAGE(r.out.find("--mask-windows") != std::string::npos, r.out);
      CHECK(!fs::exists(s.dir / "o_windows/psf.h5"));
    }
    {  // a capture whose mosaic is not the configured one
      const fs::path cfg = s.dir / "bggr.json";
      write_text_atomic(cfg.string(), config_text(s.dir, "bggr"));
      const Run r = calibrate_with(cfg, s.dir / "frames", s.dir / "darks", "o_cfa");
      CHECK(r.code == 2);
      CHECK_MESSAGE((r.out.find("mosaic does not match") != std::string::npos && r.out.find("\"rggb\"") != std::string::npos &&
                     r.out.find(".png") != std::string::npos),
                    r.out);
    }
    {  // mosaic frames calibrated as a monochrome sensor ("cfa": "none"): refused, naming the layout they show
      const fs::path cfg = s.dir / "mono.json";
      write_text_atomic(cfg.string(), config_text(s.dir, "none"));
      const Run r = calibrate_with(cfg, s.dir / "frames", s.dir / "darks", "o_mono");
      CHECK(r.code == 2);
      CHECK_MESSAGE((r.out.find("\"cfa\": \"none\"") != std::string::npos && r.out.find("\"rggb\"") != std::string::npos), r.out);
      CHECK(!fs::exists(s.dir / "o_mono/psf.h5"));
    }
  }

  TEST_CASE("darks that do not match the frames: refused with --background none, noted or refused with ring; the frames as darks") {
    // Darks 15 DN off the frames' background (read noise ~2 DN) were accepted silently: the
    // background check compares each dark-subtracted frame's unlit level with 0.
    const Sweep& s = sweep();
    for (const double shift : {15.0, -15.0}) {
      CAPTURE(shift);
      const fs::path d = s.dir / ("darks_shift_" + std::to_string(int(shift)));
      fs::create_directories(d);
      for (const auto& e : fs::directory_iterator(s.dir / "darks")) {
        Map2D f = read_png16_gray(e.path().string());
        for (double& v : f.data) v += shift;
        write_png16_gray((d / e.path().filename()).string(), f);
      }
      auto run = [&](const std::string& bg, const std::string& out) {
        return calibrate_with(s.cfg_path, s.dir / "frames", d, out, "--background " + bg);
      };
      const Run none = run("none", "o_dshift_none");
      CHECK(none.code == 2);
      CHECK_MESSAGE((none.out.find("were not taken as this frame was") != std::string::npos && none.out.find(".png") != std::string::npos),
                    none.out);
      CHECK(!fs::exists(s.dir / "o_dshift_none/psf.h5"));
      const Run ring = run("ring", "o_dshift_ring_" + std::to_string(int(shift)));
      if (shift > 0) {  // darks brighter than the frames' unlit pixels: not darks of these frames
        CHECK(ring.code == 2);
        CHECK_MESSAGE(ring.out.find("brighter than the frame") != std::string::npos, ring.out);
      } else {  // darks dimmer: a constant offset the ring subtracts, said in stdout and psf.h5
        CHECK_MESSAGE(ring.code == 0, ring.out);
        CHECK_MESSAGE(ring.out.find("background sits at") != std::string::npos, ring.out);
        const auto attrs = h5_read_root_attrs((s.dir / ("o_dshift_ring_" + std::to_string(int(shift))) / "psf.h5").string());
        CHECK(attrs.at("notes").find("background sits at") != std::string::npos);
        const auto bg = h5_read((s.dir / ("o_dshift_ring_" + std::to_string(int(shift))) / "psf.h5").string(), "/background_dn");
        for (double v : bg.data) CHECK(v == doctest::Approx(-shift).epsilon(0.25));
      }
    }
    // Matching darks: every frame's background within a few tenths of the noise of 0, and no note
    // (the centre chosen, so that --centre auto's note on a point source off the frame's centre
    // does not stand in for one).
    const Run ok = calibrate(s.dir / "frames", "o_dmatch", "--centre centroid");
    REQUIRE_MESSAGE(ok.code == 0, ok.out);
    CHECK(ok.out.find("note: ") == std::string::npos);
    const auto bg = h5_read((s.dir / "o_dmatch/psf.h5").string(), "/background_dn");
    const auto noise = h5_read((s.dir / "o_dmatch/psf.h5").string(), "/noise_dn");
    for (std::size_t b = 0; b < bg.data.size(); ++b) CHECK(std::abs(bg.data[b]) <= noise.data[b]);
    // The frames folder given as --darks: said so, not "too dark".
    const Run same = calibrate_with(s.cfg_path, s.dir / "frames", s.dir / "frames", "o_dsame");
    CHECK(same.code == 2);
    CHECK_MESSAGE(same.out.find("is also a frame") != std::string::npos, same.out);
  }
}
