// qdo reconstruct and the sensor as built: raw Bayer captures (black level, scaling, the device
// demosaic, DNG files), --sensor over the run's configuration, and --white flat-field frames.
#include <doctest/doctest.h>

#include <nlohmann/json.hpp>

#include <cmath>
#include <filesystem>
#include <fstream>

#include "commands_common.hpp"
#include "common.hpp"
#include "reconstruct_common.hpp"
#include "qdo/physics/demosaic_reference.hpp"
#include "qdo/data/io.hpp"
#include "qdo/data/io_raw.hpp"
#include "qdo/physics/raw_reference.hpp"
#include "qdo/asbuilt/reconstruct.hpp"
#include "qdo/physics/capture_pipeline.hpp"
#include "qdo/runtime/error.hpp"

using namespace qdo;
using namespace qdo::test;
using namespace qdo::test::commands_suite;
using namespace qdo::test::reconstruct_suite;
namespace fs = std::filesystem;
using nlohmann::json;

TEST_SUITE("reconstruct") {
  TEST_CASE("the demosaic error estimated from the capture alone tracks the true demosaic error") {
    // Sensor images with texture at several scales (gratings of 3 .. 24 px periods, an edge, colour
    // that differs between the channels), mosaicked (RGGB) and developed; the estimate (the
    // development re-mosaicked and developed again) against the true RMS error of the first
    // development, for both demosaics and three textures. Measured: 0.47 .. 0.89 of the truth.
    SystemConfig cfg = tiny();
    cfg.cfa = Cfa::RGGB;
    cfg.validate();
    const std::size_t H = 48, W = 56;
    for (const DemosaicMethod method : {DemosaicMethod::Bilinear, DemosaicMethod::MHC})
      for (const double period : {3.0, 8.0, 24.0}) {
        RealStack truth(3, H, W);
        for (std::size_t c = 0; c < 3; ++c)
          for (std::size_t y = 0; y < H; ++y)
            for (std::size_t x = 0; x < W; ++x)
              truth(c, y, x) = 0.4 + 0.15 * std::sin(2 * M_PI * (double(x) + 0.7 * double(y) * double(c + 1)) / period) +
                               (x > W / 2 ? 0.1 * double(c) : 0.0);
        PipelineOptions po;
        po.noise = false;
        po.raw = true;
        po.demosaic = method;
        CapturePipeline pipeline(runtime(), cfg, Precision::F64, po);
        RealStack mosaic(1, H, W);
        for (std::size_t y = 0; y < H; ++y)
          for (std::size_t x = 0; x < W; ++x) mosaic(0, y, x) = truth(std::size_t(cfa_channel(cfg.cfa, y, x)), y, x);
        const RealStack rgb = pipeline.develop(mosaic).demosaiced;
        double e2 = 0;
        std::size_t n = 0;
        for (std::size_t c = 0; c < 3; ++c)
          for (std::size_t y = 2; y + 2 < H; ++y)
            for (std::size_t x = 2; x + 2 < W; ++x) {
              e2 += std::pow(rgb(c, y, x) - truth(c, y, x), 2);
              ++n;
            }
        const double true_sigma = std::sqrt(e2 / double(n));
        const double est = estimate_demosaic_sigma(runtime(), Precision::F64, cfg, method, rgb);
        CAPTURE(int(method));
        CAPTURE(period);
        MESSAGE("demosaic " << int(method) << ", period " << period << " px: true error " << true_sigma << ", estimate " << est);
        CHECK(true_sigma > 1e-4);
        CHECK(est > 0.3 * true_sigma);
        CHECK(est < 1.2 * true_sigma);
      }
    CHECK_THROWS_AS(estimate_demosaic_sigma(runtime(), Precision::F64, cfg, DemosaicMethod::MHC, RealStack(3, 4, 4, 0.5)), InputError);
    SystemConfig rgb_cfg = cfg;
    rgb_cfg.cfa = Cfa::None;
    CHECK_THROWS_AS(estimate_demosaic_sigma(runtime(), Precision::F64, rgb_cfg, DemosaicMethod::MHC, RealStack(3, 8, 8, 0.5)), InputError);
  }

  TEST_CASE("raw Bayer captures: black level, scaling and the device demosaic as the reference does them; a wrong mosaic refused") {
    // A Wiener run whose sensor is a 12-bit RGGB mosaic with black level 64 DN.
    SystemConfig cfg = tiny();
    cfg.cfa = Cfa::RGGB;
    cfg.bit_depth = 12;
    cfg.black_level_dn = 64;
    cfg.validate();
    const auto dir = temp_dir("recon_raw");
    const std::string cfgf = (dir / "raw.json").string();
    std::ofstream(cfgf) << config_to_json_text(cfg) << "\n";
    const Run run = qdo_run("design --config " + cfgf + " --mode qdo+a --epochs 1 --steps-per-epoch 1 --synthetic-scenes 2 --out " +
                            (dir / "run").string());
    CAPTURE(run.out);
    REQUIRE(run.code == 0);
    const std::size_t S = cfg.sensor_size_px(), H = 24, W = 20;
    const RealStack rgb = wiener::simulate_measurement(smooth_scene(3, H, W, 21),
                                                       wiener::psf_to_otf(read_psf_stack_file((dir / "run" / "psf.h5").string()).psf_sensor, H, W),
                                                       sensor_response(cfg));
    Map2D dn(H, W);
    for (std::size_t y = 0; y < H; ++y)
      for (std::size_t x = 0; x < W; ++x)
        dn.data[y * W + x] = std::round(64 + std::clamp(rgb(std::size_t(cfa_channel(Cfa::RGGB, y, x)), y, x), 0.0, 1.0) * (4095 - 64));
    write_png16_gray((dir / "raw.png").string(), dn);
    // The library chain against the reference: raw_to_linear, then ref::demosaic (MHC).
    CaptureOptions co;
    co.captures = {(dir / "raw.png").string()};
    co.demosaic = "mhc";
    const CaptureFiles f = read_captures(cfg, co);
    const PreparedCapture pc = prepare_capture(runtime(), Precision::F32, cfg, co, f);
    RealStack raw(1, H, W);
    raw.data = dn.data;
    const RealStack expect = ref::demosaic(raw_to_linear(raw, cfg), Cfa::RGGB, DemosaicMethod::MHC);
    REQUIRE(pc.rgb.planes == 3);
    CHECK(max_abs_diff(pc.rgb, expect) < 1e-5);  // float32 device stage against the double reference
    // The command: a cube of the frame's size; 3-channel captures and a mosaic on the other
    // diagonal (the frame shifted by one column) are refused naming the file.
    const Run ok = qdo_run("reconstruct --run " + (dir / "run").string() + " --capture " + (dir / "raw.png").string() +
                           " --demosaic mhc --out " + (dir / "out").string());
    CAPTURE(ok.out);
    REQUIRE(ok.code == 0);
    const RealStack cube = read_cube_h5(dir / "out" / "cube.h5");
    CHECK(cube.rows == H);
    CHECK(cube.cols == W);
    CHECK(read_json(dir / "out" / "reconstruct.json").at("demosaic") == "mhc");
    // The same codes as a DNG (RGGB, black 64, white 4095 in its metadata): the same cube.
    // LibRaw reads no DNG under 22 x 22, so the frame is padded to the right.
    Map2D wide(H, W + 8, 64);
    for (std::size_t y = 0; y < H; ++y)
      for (std::size_t x = 0; x < W; ++x) wide.data[y * (W + 8) + x] = dn.data[y * W + x];
    write_png16_gray((dir / "wide.png").string(), wide);
    write_dng_mosaic((dir / "wide.dng").string(), wide, "rggb", 64, 4095);
    for (const char* file : {"wide.png", "wide.dng"}) {
      const Run w = qdo_run("reconstruct --run " + (dir / "run").string() + " --capture " + (dir / file).string() + " --demosaic mhc --out " +
                            (dir / (std::string("out_") + file)).string());
      CAPTURE(w.out);
      REQUIRE(w.code == 0);
    }
    CHECK(read_cube_h5(dir / "out_wide.dng" / "cube.h5").data == read_cube_h5(dir / "out_wide.png" / "cube.h5").data);
    write_dng_mosaic((dir / "gbrg.dng").string(), wide, "gbrg", 64, 4095);
    const Run wrong = qdo_run("reconstruct --run " + (dir / "run").string() + " --capture " + (dir / "gbrg.dng").string() + " --out " +
                              (dir / "out_gbrg").string());
    CHECK(wrong.code == 2);
    CHECK_MESSAGE(wrong.out.find("\"cfa\": \"gbrg\"") != std::string::npos, wrong.out);
    Map2D shifted(H, W - 1);
    for (std::size_t y = 0; y < H; ++y)
      for (std::size_t x = 0; x + 1 < W; ++x) shifted.data[y * (W - 1) + x] = dn.data[y * W + x + 1];
    write_png16_gray((dir / "shifted.png").string(), shifted);
    const Run bad = qdo_run("reconstruct --run " + (dir / "run").string() + " --capture " + (dir / "shifted.png").string() + " --out " +
                            (dir / "bad").string());
    CAPTURE(bad.out);
    CHECK(bad.code == 2);
    CHECK(bad.out.find("shifted.png") != std::string::npos);
    CHECK(bad.out.find("rggb") != std::string::npos);
    write_png16_rgb((dir / "rgb.png").string(), RealStack(3, S, S, 100.0));
    const Run bad2 = qdo_run("reconstruct --run " + (dir / "run").string() + " --capture " + (dir / "rgb.png").string() + " --out " +
                             (dir / "bad2").string());
    CHECK(bad2.code == 2);
    CHECK(bad2.out.find("rgb.png") != std::string::npos);
    // Cropped by one row and one column: RGGB read as BGGR, red and blue swapped, the green sites
    // still on their diagonal (the phase check cannot see it). The colours then lie outside what
    // the camera's responses can produce: refused, naming the file and the swapped layout. The
    // frame as captured passes the same check.
    Map2D cropped(H - 1, W - 1);
    for (std::size_t y = 0; y + 1 < H; ++y)
      for (std::size_t x = 0; x + 1 < W; ++x) cropped.data[y * (W - 1) + x] = dn.data[(y + 1) * W + x + 1];
    write_png16_gray((dir / "cropped.png").string(), cropped);
    const Run swapped = qdo_run("reconstruct --run " + (dir / "run").string() + " --capture " + (dir / "cropped.png").string() +
                                " --out " + (dir / "bad3").string());
    CAPTURE(swapped.out);
    CHECK(swapped.code == 2);
    CHECK(swapped.out.find("cropped.png") != std::string::npos);
    CHECK(swapped.out.find("\"bggr\"") != std::string::npos);
    RealStack as_captured(1, H, W);
    for (std::size_t i = 0; i < dn.data.size(); ++i) as_captured.data[i] = dn.data[i] - 64;
    CHECK_NOTHROW(check_mosaic_colours(as_captured, Cfa::RGGB, sensor_response(cfg), "raw.png"));
    // A grey scene shows nothing either way: never refused.
    RealStack grey(1, H, W, 500.0);
    CHECK_NOTHROW(check_mosaic_colours(grey, Cfa::BGGR, sensor_response(cfg), "grey.png"));
    fs::remove_all(dir);
  }

  TEST_CASE("qdo reconstruct --white: colour gains and pixel response divided out by the flat field; a dead white pixel refused") {
    const SharedRun& s = shared_run();
    const auto dir = temp_dir("recon_white");
    const std::size_t S = tiny().sensor_size_px(), H = S + 6, W = S + 10;
    const RealStack rgb = camera_image(s.dir, smooth_scene(3, H, W, 17));
    // The sensor's gains: R 1.25, G 1, B 0.8 and a 5 % pixel response pattern, scaled to mean 1.
    RealStack gain(3, H, W);
    const double channel[3] = {1.25, 1.0, 0.8};
    for (std::size_t c = 0; c < 3; ++c)
      for (std::size_t y = 0; y < H; ++y)
        for (std::size_t x = 0; x < W; ++x) gain(c, y, x) = channel[c] * (1 + 0.05 * std::sin(0.7 * double(y) + 1.3 * double(x) + double(c)));
    double mean = 0;
    for (double g : gain.data) mean += g / double(gain.data.size());
    for (double& g : gain.data) g /= mean;
    RealStack ideal(3, H, W), seen(3, H, W), white(3, H, W);
    for (std::size_t i = 0; i < rgb.data.size(); ++i) {
      const double v = 0.6 * std::clamp(rgb.data[i], 0.0, 1.0) * 65535.0;
      ideal.data[i] = std::round(v);
      seen.data[i] = std::round(v * gain.data[i]);
      white.data[i] = std::round(0.5 * 65535.0 * gain.data[i]);
    }
    write_png16_rgb((dir / "ideal.png").string(), ideal);
    write_png16_rgb((dir / "seen.png").string(), seen);
    fs::create_directories(dir / "white");
    write_png16_rgb((dir / "white" / "w0.png").string(), white);
    auto recon = [&](const std::string& cap, const std::string& extra, const std::string& out) {
      const Run r = qdo_run("reconstruct --run " + s.dir.string() + " --capture " + (dir / cap).string() + extra + " --out " +
                            (dir / out).string());
      CAPTURE(r.out);
      REQUIRE(r.code == 0);
      return read_cube_h5(dir / out / "cube.h5");
    };
    const RealStack want = recon("ideal.png", "", "ideal");
    const RealStack raw = recon("seen.png", "", "seen");
    const RealStack flat = recon("seen.png", " --white " + (dir / "white").string(), "flat");
    const double err_flat = max_abs_diff(flat, want), err_raw = max_abs_diff(raw, want);
    CAPTURE(err_flat);
    CAPTURE(err_raw);
    CHECK(err_flat < 2e-3);           // DN rounding of the three files only
    CHECK(err_raw > 20 * err_flat);   // the gains, left in, are visible
    const json j = read_json(dir / "flat" / "reconstruct.json");
    const auto g = j.at("white").at("channel_gains_rgb");
    CHECK(g.at(0).get<double>() / g.at(1).get<double>() == doctest::Approx(1.25).epsilon(2e-3));
    CHECK(g.at(2).get<double>() / g.at(1).get<double>() == doctest::Approx(0.8).epsilon(2e-3));
    // A dead pixel in the white frame: refused, naming it.
    white(1, 3, 4) = 0;
    fs::create_directories(dir / "dead");
    write_png16_rgb((dir / "dead" / "w0.png").string(), white);
    const Run dead = qdo_run("reconstruct --run " + s.dir.string() + " --capture " + (dir / "seen.png").string() + " --white " +
                             (dir / "dead").string() + " --out " + (dir / "dead_out").string());
    CHECK(dead.code == 2);
    CHECK_MESSAGE(dead.out.find("row 3, column 4") != std::string::npos, dead.out);
    fs::remove_all(dir);
  }

  TEST_CASE("qdo reconstruct --sensor: raw captures for a run trained on RGB, as its config.json edited by hand; non-sensor keys refused; --noise-sigma model") {
    const SharedRun& s = shared_run();  // a Wiener run of tiny(): RGB captures (cfa none)
    const auto dir = temp_dir("recon_sensor");
    const std::size_t H = 24, W = 28;
    const RealStack rgb = camera_image(s.dir, smooth_scene(tiny().bands, H, W, 5));
    Map2D dn(H, W);
    for (std::size_t y = 0; y < H; ++y)
      for (std::size_t x = 0; x < W; ++x)
        dn.data[y * W + x] = std::round(64 + std::clamp(rgb(std::size_t(cfa_channel(Cfa::RGGB, y, x)), y, x), 0.0, 1.0) * (4095 - 64));
    write_png16_gray((dir / "raw.png").string(), dn);
    std::ofstream(dir / "sensor.json") << R"({"cfa": "rggb", "bit_depth": 12, "black_level_dn": 64})";
    // Without it the run's sensor (RGB) refuses the mosaic, naming cfa.
    const Run plain = qdo_run("reconstruct --run " + s.dir.string() + " --capture " + (dir / "raw.png").string() + " --out " +
                              (dir / "plain").string());
    CHECK(plain.code == 2);
    CHECK_MESSAGE(plain.out.find("cfa") != std::string::npos, plain.out);
    const Run ok = qdo_run("reconstruct --run " + s.dir.string() + " --sensor " + (dir / "sensor.json").string() + " --capture " +
                           (dir / "raw.png").string() + " --out " + (dir / "with").string());
    CAPTURE(ok.out);
    REQUIRE(ok.code == 0);
    const json j = read_json(dir / "with" / "reconstruct.json");
    CHECK(j.at("sensor").at("values").at("cfa") == "rggb");
    CHECK(j.at("sensor").at("values").at("bit_depth") == 12);
    // The same as a copy of the run whose config.json says so (what a user had to do by hand).
    const fs::path edited = dir / "edited_run";
    fs::copy(s.dir, edited, fs::copy_options::recursive);
    json cfg = read_json(edited / "config.json");
    json& sys = cfg.at("system");
    sys["cfa"] = "rggb";
    sys["bit_depth"] = 12;
    sys["black_level_dn"] = 64;
    std::ofstream(edited / "config.json") << cfg.dump(2);
    const Run hand = qdo_run("reconstruct --run " + edited.string() + " --capture " + (dir / "raw.png").string() + " --out " +
                             (dir / "hand").string());
    REQUIRE_MESSAGE(hand.code == 0, hand.out);
    CHECK(read_cube_h5(dir / "with" / "cube.h5").data == read_cube_h5(dir / "hand" / "cube.h5").data);
    // Keys of the optics, and values the configuration refuses, are refused naming them.
    std::ofstream(dir / "optics.json") << R"({"cfa": "rggb", "pitch_m": 4e-6})";
    const Run optics = qdo_run("reconstruct --run " + s.dir.string() + " --sensor " + (dir / "optics.json").string() + " --capture " +
                               (dir / "raw.png").string() + " --out " + (dir / "optics").string());
    CHECK(optics.code == 2);
    CHECK_MESSAGE(optics.out.find("'pitch_m' is not a sensor key") != std::string::npos, optics.out);
    // --noise-sigma model: the sensor's noise at the capture's mean signal (read 0.002, 10,000
    // photons full well, 12 bits), the mean as the test's own mosaic gives it (within the
    // demosaic's reweighting of green, 15 %).
    std::ofstream(dir / "noisy_sensor.json")
        << R"({"cfa": "rggb", "bit_depth": 12, "black_level_dn": 64, "read_noise_sigma": 0.002, "full_well_photons": 10000})";
    const Run model = qdo_run("reconstruct --run " + s.dir.string() + " --sensor " + (dir / "noisy_sensor.json").string() + " --capture " +
                              (dir / "raw.png").string() + " --noise-sigma model --out " + (dir / "model").string());
    REQUIRE_MESSAGE(model.code == 0, model.out);
    const json jm = read_json(dir / "model" / "reconstruct.json");
    double v_mosaic = 0;
    for (double x : dn.data) v_mosaic += (x - 64) / (4095 - 64) / double(dn.data.size());
    const double v = jm.at("noise_sigma_model").at("mean_signal").get<double>();
    CHECK(v == doctest::Approx(v_mosaic).epsilon(0.15));
    const double lsb = 1.0 / 4095;
    // Plus the demosaic error the capture shows (this mosaic is of a smooth scene: small, not 0).
    const double dm = jm.at("noise_sigma_model").at("demosaic_sigma").get<double>();
    CHECK(dm > 0);
    CHECK(dm < 0.05);
    CHECK(jm.at("noise_sigma").get<double>() ==
          doctest::Approx(std::sqrt(0.002 * 0.002 + v / 10000 + lsb * lsb / 12 + dm * dm)).epsilon(1e-9));
    CHECK(jm.at("noise_sigma").get<double>() > 0.002);  // shot noise on top of the read noise
    // --noise-sigma ml: the sigma the capture's tiles ask for, recorded with its range.
    const Run ml = qdo_run("reconstruct --run " + s.dir.string() + " --sensor " + (dir / "noisy_sensor.json").string() + " --capture " +
                            (dir / "raw.png").string() + " --noise-sigma ml --out " + (dir / "ml").string());
    REQUIRE_MESSAGE(ml.code == 0, ml.out);
    const json jg = read_json(dir / "ml" / "reconstruct.json");
    const double sg = jg.at("noise_sigma_ml").at("sigma").get<double>();
    CHECK(jg.at("noise_sigma").get<double>() == sg);
    CHECK(sg >= jg.at("noise_sigma_ml").at("sigma_range")[0].get<double>());
    CHECK(sg <= jg.at("noise_sigma_ml").at("sigma_range")[1].get<double>());
    CHECK(jg.at("noise_sigma_ml").at("tiles").get<std::size_t>() == jm.at("tiles").get<std::size_t>());
    const Run word = qdo_run("reconstruct --run " + s.dir.string() + " --capture " + (dir / "raw.png").string() +
                             " --noise-sigma modle --out " + (dir / "word").string());
    CHECK(word.code == 2);
    CHECK_MESSAGE(word.out.find("--noise-sigma") != std::string::npos, word.out);
    std::ofstream(dir / "bad.json") << R"({"cfa": "rgbg"})";
    const Run bad = qdo_run("reconstruct --run " + s.dir.string() + " --sensor " + (dir / "bad.json").string() + " --capture " +
                            (dir / "raw.png").string() + " --out " + (dir / "bad").string());
    CHECK(bad.code == 2);
    CHECK_MESSAGE(bad.out.find("rgbg") != std::string::npos, bad.out);
    fs::remove_all(dir);
  }
}
