#include <doctest/doctest.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <limits>
#include <string>

#include "qdo/data/config.hpp"
#include "qdo/decode/decoder_spec.hpp"
#include "qdo/runtime/error.hpp"

using qdo::SystemConfig;

namespace {

void check_same(const SystemConfig& a, const SystemConfig& b) {
  CHECK(a.preset == b.preset);
  CHECK(a.n == b.n);
  CHECK(a.pitch_m == b.pitch_m);
  CHECK(a.wavelength_start_nm == b.wavelength_start_nm);
  CHECK(a.wavelength_step_nm == b.wavelength_step_nm);
  CHECK(a.bands == b.bands);
  CHECK(a.scene_distance_m == b.scene_distance_m);
  CHECK(a.scene_at_infinity == b.scene_at_infinity);
  CHECK(a.sensor_distance_m == b.sensor_distance_m);
  CHECK(a.aperture_radius_m == b.aperture_radius_m);
  CHECK(a.aperture_edge == b.aperture_edge);
  CHECK(a.material == b.material);
  CHECK(a.base_wavelength_nm == b.base_wavelength_nm);
  CHECK(a.base_plate_m == b.base_plate_m);
  CHECK(a.propagator == b.propagator);
  CHECK(a.padding_px == b.padding_px);
  CHECK(a.strict_sampling == b.strict_sampling);
  CHECK(a.sensor_pitch_m == b.sensor_pitch_m);
  CHECK(a.scene_size_px == b.scene_size_px);
  CHECK(a.camera == b.camera);
  CHECK(a.srf_interpolate == b.srf_interpolate);
  CHECK(a.convolution == b.convolution);
  CHECK(a.read_noise_sigma == b.read_noise_sigma);
  CHECK(a.full_well_photons == b.full_well_photons);
  CHECK(a.noise_seed == b.noise_seed);
  CHECK(a.cfa == b.cfa);
  CHECK(a.black_level_dn == b.black_level_dn);
  CHECK(a.gain == b.gain);
  CHECK(a.bit_depth == b.bit_depth);
}

SystemConfig from_json(const std::string& text) { return qdo::config_from_json_text(text, "test.json"); }

// The JSON override `"key": value_json` on the paper preset must be rejected naming `key`.
void check_json_rejected(const std::string& key, const std::string& value_json) {
  CAPTURE(key);
  CAPTURE(value_json);
  const std::string text = "{\"" + key + "\": " + value_json + "}";
  CHECK_THROWS_WITH_AS(from_json(text), doctest::Contains(key.c_str()), qdo::InputError);
  CHECK_THROWS_WITH_AS(from_json(text), doctest::Contains("test.json"), qdo::InputError);
}

}  // namespace

TEST_SUITE("config") {
  TEST_CASE("presets validate and match REFERENCE") {
    CHECK(qdo::preset_names() == std::vector<std::string>{"paper", "small"});
    for (const auto& name : qdo::preset_names()) CHECK_NOTHROW(qdo::preset_config(name).validate());
    const SystemConfig p = qdo::preset_config("paper");
    CHECK(p.preset == "paper");
    CHECK(p.n == 1024);
    CHECK(p.pitch_m == 4e-6);
    CHECK(std::abs(p.h_max_m() - 1.5369e-6) < 1e-9);
    CHECK(p.sensor_size_px() == 512);
    CHECK(p.scene_size_px == 512);
    CHECK(p.padding_px == p.n / 4);
    CHECK(p.read_noise_sigma == 0.001);
    CHECK(p.full_well_photons == 0);
    CHECK(p.cfa == qdo::Cfa::None);  // the sensor as built: today's sensor by default
    CHECK(p.black_level_dn == 0);
    CHECK(p.gain == 1);
    CHECK(p.bit_depth == 0);
    CHECK(p.convolution == qdo::ConvolutionMode::Linear);
    CHECK(p.propagator == qdo::Propagator::Fresnel);
    CHECK(p.aperture_radius() == doctest::Approx(511 * 4e-6));
    const auto wl = p.wavelengths_nm();
    REQUIRE(wl.size() == 31);
    CHECK(wl.front() == 400);
    CHECK(wl[15] == 550);
    CHECK(wl.back() == 700);
    SystemConfig q = p;
    q.aperture_radius_m = 1e-3;
    CHECK(q.aperture_radius() == 1e-3);
    CHECK_THROWS_WITH_AS(qdo::preset_config("huge"), doctest::Contains("small"), qdo::InputError);
    CHECK_THROWS_WITH_AS(qdo::preset_config("huge"), doctest::Contains("paper"), qdo::InputError);
  }

  TEST_CASE("small preset keeps the paper's NA and sampling ratio") {
    const SystemConfig p = qdo::preset_config("paper");
    const SystemConfig s = qdo::preset_config("small");
    CHECK(s.n == 256);
    CHECK(s.sensor_size_px() == 128);
    CHECK(s.scene_size_px == 128);
    auto na = [](const SystemConfig& c) { return static_cast<double>(c.n) / 2 * c.pitch_m / c.sensor_distance_m; };
    auto ratio = [](const SystemConfig& c, double wl_nm) {
      const double m = static_cast<double>(c.n + 2 * c.padding_px);
      return wl_nm * 1e-9 * c.sensor_distance_m / (m * c.pitch_m * c.pitch_m);
    };
    CHECK(na(s) == doctest::Approx(na(p)).epsilon(1e-12));
    CHECK(ratio(s, 700) == doctest::Approx(ratio(p, 700)).epsilon(1e-12));
    // With the release's (N/2 - 1) aperture the NA agrees to within 1 %.
    CHECK(s.aperture_radius() / s.sensor_distance_m == doctest::Approx(p.aperture_radius() / p.sensor_distance_m).epsilon(0.01));
    CHECK(s.h_max_m() == p.h_max_m());
  }

  TEST_CASE("JSON round trip") {
    for (const auto& name : qdo::preset_names()) {
      CAPTURE(name);
      const SystemConfig c = qdo::preset_config(name);
      check_same(from_json(qdo::config_to_json_text(c)), c);
    }
    const SystemConfig custom = from_json(R"({"preset": "small", "n": 128, "scene_distance_m": "inf",
        "material": "bk7", "propagator": "asm", "convolution": "circular", "pitch_m": 3.3e-6,
        "wavelength_start_nm": 420.5, "wavelength_step_nm": 7.25, "bands": 3, "padding_px": 0,
        "aperture_radius_m": 1.0e-4, "aperture_edge": "strict", "strict_sampling": true, "srf_interpolate": true,
        "sensor_pitch_m": 6.6e-6, "scene_size_px": 1, "camera": "my_srf.csv", "read_noise_sigma": 0.0123,
        "full_well_photons": 10000.5, "noise_seed": 18446744073709551615, "base_plate_m": 0,
        "base_wavelength_nm": 650, "sensor_distance_m": 0.02, "cfa": "gbrg", "bit_depth": 12,
        "black_level_dn": 256, "gain": 1.5})");
    CHECK(custom.cfa == qdo::Cfa::GBRG);
    CHECK(custom.bit_depth == 12);
    CHECK(custom.white_level_dn() == 4095);
    CHECK(custom.preset == "small");
    CHECK(custom.aperture_edge == qdo::ApertureEdge::Strict);
    CHECK(custom.n == 128);
    CHECK(custom.scene_at_infinity);
    CHECK(std::isinf(custom.scene_distance_m));
    CHECK(custom.material == "SCHOTT_N-BK7");
    CHECK(custom.propagator == qdo::Propagator::AngularSpectrum);
    CHECK(custom.convolution == qdo::ConvolutionMode::Circular);
    CHECK(custom.noise_seed == 18446744073709551615ull);
    const std::string text = qdo::config_to_json_text(custom);
    CHECK(text.find("\"inf\"") != std::string::npos);
    check_same(from_json(text), custom);
    // A number for scene_distance_m clears scene_at_infinity again; integers may be written as 1e3.
    const SystemConfig finite = from_json(R"({"scene_distance_m": 2.5, "n": 5.12e2})");
    CHECK_FALSE(finite.scene_at_infinity);
    CHECK(finite.scene_distance_m == 2.5);
    CHECK(finite.n == 512);
    // A file without "preset" has the paper's values but is not the paper preset: its provenance
    // (config.json, psf.h5 of calibrate and psf) names no preset.
    const SystemConfig bare = from_json(R"({"n": 512})");
    CHECK(bare.preset == "custom");
    CHECK(qdo::config_to_json_text(bare).find("\"preset\"") == std::string::npos);
    CHECK(bare.sensor_distance_m == qdo::preset_config("paper").sensor_distance_m);
    CHECK(from_json(R"({"preset": "paper", "n": 512})").preset == "paper");
  }

  TEST_CASE("JSON rejections name the key") {
    check_json_rejected("nn", "1024");                    // unknown key
    CHECK_THROWS_WITH_AS(from_json(R"({"pich_m": 4e-6})"), doctest::Contains("pitch_m"), qdo::InputError);
    check_json_rejected("n", "1023");                     // odd
    check_json_rejected("n", "0");
    check_json_rejected("n", "8");
    check_json_rejected("n", "32768");
    check_json_rejected("n", "\"1024\"");                 // wrong type
    check_json_rejected("n", "-1024");                    // negative integer
    check_json_rejected("n", "1024.5");                   // fractional
    check_json_rejected("bands", "true");
    check_json_rejected("pitch_m", "-4e-6");
    check_json_rejected("pitch_m", "0");
    check_json_rejected("pitch_m", "1");
    check_json_rejected("pitch_m", "null");
    check_json_rejected("scene_distance_m", "0");
    check_json_rejected("scene_distance_m", "-1");
    check_json_rejected("scene_distance_m", "\"infinity\"");
    check_json_rejected("sensor_distance_m", "0");
    check_json_rejected("sensor_distance_m", "-0.05");
    check_json_rejected("sensor_distance_m", "11");
    check_json_rejected("aperture_radius_m", "-1e-3");
    check_json_rejected("aperture_radius_m", "1");
    check_json_rejected("aperture_edge", "\"open\"");
    check_json_rejected("aperture_edge", "true");
    check_json_rejected("material", "\"unobtainium\"");
    check_json_rejected("propagator", "\"rayleigh\"");
    check_json_rejected("convolution", "\"cyclic\"");
    check_json_rejected("padding_px", "5000");
    check_json_rejected("sensor_pitch_m", "1e-6");
    check_json_rejected("scene_size_px", "0");
    check_json_rejected("camera", "\"\"");
    check_json_rejected("strict_sampling", "1");
    check_json_rejected("read_noise_sigma", "-0.1");
    check_json_rejected("full_well_photons", "-1");
    check_json_rejected("base_wavelength_nm", "200");
    check_json_rejected("base_plate_m", "-1");
    check_json_rejected("noise_seed", "-1");
    check_json_rejected("cfa", "\"rgbg\"");
    check_json_rejected("cfa", "1");
    check_json_rejected("bit_depth", "4");
    check_json_rejected("bit_depth", "32");
    check_json_rejected("gain", "0");
    check_json_rejected("black_level_dn", "1");
    check_json_rejected("preset", "\"huge\"");
    check_json_rejected("wavelength_step_nm", "0");
    // Wavelength outside the material's range: NOA61 starts at 400 nm.
    CHECK_THROWS_WITH_AS(from_json(R"({"material": "NOA61", "wavelength_start_nm": 300})"),
                         doctest::Contains("wavelength_start_nm"), qdo::InputError);
    CHECK_THROWS_WITH_AS(from_json(R"({"material": "NOA61", "wavelength_start_nm": 300})"),
                         doctest::Contains("NOA61"), qdo::InputError);
    // The last band out of range names the step and band count.
    CHECK_THROWS_WITH_AS(from_json(R"({"wavelength_step_nm": 100})"), doctest::Contains("bands"), qdo::InputError);
    // One band: any finite step is fine.
    CHECK(from_json(R"({"bands": 1, "wavelength_step_nm": 0, "wavelength_start_nm": 550})").wavelengths_nm() ==
          std::vector<double>{550});
  }

  TEST_CASE("malformed JSON, wrong top level, size cap") {
    CHECK_THROWS_WITH_AS(from_json("{\"n\": 1024,"), doctest::Contains("test.json"), qdo::InputError);
    CHECK_THROWS_WITH_AS(from_json("{\"n\": 1024,"), doctest::Contains("invalid JSON"), qdo::InputError);
    CHECK_THROWS_WITH_AS(from_json("[1, 2]"), doctest::Contains("object"), qdo::InputError);
    CHECK_THROWS_WITH_AS(from_json(""), doctest::Contains("test.json"), qdo::InputError);
    const std::string big = "{\"camera\": \"" + std::string(std::size_t{1} << 20, 'x') + "\"}";
    CHECK_THROWS_WITH_AS(from_json(big), doctest::Contains("1 MiB"), qdo::InputError);
  }

  TEST_CASE("validate rejects NaN, naming the key") {
    const double nan = std::numeric_limits<double>::quiet_NaN();
    const SystemConfig p = qdo::preset_config("paper");
    auto expect = [&](double SystemConfig::*field, const char* key) {
      CAPTURE(key);
      SystemConfig c = p;
      c.*field = nan;
      CHECK_THROWS_WITH_AS(c.validate(), doctest::Contains(key), qdo::InputError);
      CHECK_THROWS_WITH_AS(c.validate(), doctest::Contains("nan"), qdo::InputError);
    };
    expect(&SystemConfig::pitch_m, "pitch_m");
    expect(&SystemConfig::wavelength_start_nm, "wavelength_start_nm");
    expect(&SystemConfig::wavelength_step_nm, "wavelength_step_nm");
    expect(&SystemConfig::scene_distance_m, "scene_distance_m");
    expect(&SystemConfig::sensor_distance_m, "sensor_distance_m");
    expect(&SystemConfig::aperture_radius_m, "aperture_radius_m");
    expect(&SystemConfig::base_wavelength_nm, "base_wavelength_nm");
    expect(&SystemConfig::base_plate_m, "base_plate_m");
    expect(&SystemConfig::sensor_pitch_m, "sensor_pitch_m");
    expect(&SystemConfig::read_noise_sigma, "read_noise_sigma");
    expect(&SystemConfig::full_well_photons, "full_well_photons");
    expect(&SystemConfig::gain, "gain");
    expect(&SystemConfig::black_level_dn, "black_level_dn");
    SystemConfig inf_scene = p;
    inf_scene.scene_distance_m = std::numeric_limits<double>::infinity();
    CHECK_THROWS_WITH_AS(inf_scene.validate(), doctest::Contains("scene_distance_m"), qdo::InputError);
    inf_scene.scene_at_infinity = true;
    CHECK_NOTHROW(inf_scene.validate());
    SystemConfig bad_material = p;
    bad_material.material = "glass";
    CHECK_THROWS_WITH_AS(bad_material.validate(), doctest::Contains("material"), qdo::InputError);
    SystemConfig zero_bands = p;
    zero_bands.bands = 0;
    CHECK_THROWS_WITH_AS(zero_bands.validate(), doctest::Contains("bands"), qdo::InputError);
  }

  TEST_CASE("a key given twice in one JSON object is refused, naming the key and the file") {
    // nlohmann::json keeps the last of two equal keys silently: {"n": 256, "n": 4096} read as 4096.
    CHECK_THROWS_WITH_AS(from_json(R"({"n": 256, "bands": 4, "n": 4096})"), doctest::Contains("test.json: duplicate key 'n'"),
                         qdo::InputError);
    CHECK_THROWS_WITH_AS(from_json(R"({"read_noise_sigma": 0.01, "read_noise_sigma": 0.01})"),
                         doctest::Contains("duplicate key 'read_noise_sigma'"), qdo::InputError);
    CHECK_THROWS_WITH_AS(from_json(R"({"preset": "small", "preset": "paper"})"), doctest::Contains("duplicate key 'preset'"),
                         qdo::InputError);
    // Equal keys in different objects, and keys differing only in case, are not duplicates.
    CHECK(from_json(R"({"preset": "small", "bands": 4})").bands == 4);
    CHECK_THROWS_WITH_AS(from_json(R"({"N": 256})"), doctest::Contains("unknown key 'N'"), qdo::InputError);
    const std::string path = "/tmp/qdo_test_dup_" + std::to_string(std::rand()) + ".json";
    {
      std::ofstream out(path);
      out << "{\n  \"preset\": \"small\",\n  \"bands\": 4,\n  \"bands\": 31\n}\n";
    }
    CHECK_THROWS_WITH_AS(qdo::config_from_json_file(path), doctest::Contains((path + ": duplicate key 'bands'").c_str()), qdo::InputError);
    std::remove(path.c_str());
  }

  TEST_CASE("values beyond the float32 range are refused at validation, naming key, value and range") {
    // Finite doubles that overflow float32 (1e300 read noise wrote an all-Inf sensor.h5 in f32).
    for (const char* text : {R"({"read_noise_sigma": 1e300})", R"({"full_well_photons": 1e39})",
                             R"({"scene_distance_m": 1e39})", R"({"base_plate_m": 1e300})"}) {
      CAPTURE(text);
      CHECK_THROWS_WITH_AS(from_json(text), doctest::Contains("float32 range"), qdo::InputError);
    }
    CHECK_THROWS_WITH_AS(from_json(R"({"read_noise_sigma": 1e300})"), doctest::Contains("'read_noise_sigma' = 1e+300"),
                         qdo::InputError);
    CHECK_THROWS_WITH_AS(from_json(R"({"read_noise_sigma": 1e300})"), doctest::Contains("3.402823466e+38"), qdo::InputError);
    // Underflow to a float32 denormal or zero.
    CHECK_THROWS_WITH_AS(from_json(R"({"read_noise_sigma": 1e-300})"), doctest::Contains("'read_noise_sigma'"), qdo::InputError);
    CHECK_THROWS_WITH_AS(from_json(R"({"base_plate_m": 1e-40})"), doctest::Contains("'base_plate_m'"), qdo::InputError);
    // validate() itself, not only the JSON reader.
    SystemConfig c = qdo::preset_config("small");
    c.full_well_photons = 5e38;
    CHECK_THROWS_WITH_AS(c.validate(), doctest::Contains("'full_well_photons'"), qdo::InputError);
    // Inside the range: accepted.
    CHECK(from_json(R"({"read_noise_sigma": 0, "full_well_photons": 1e30, "scene_distance_m": 1e30})").full_well_photons == 1e30);
    CHECK(from_json(R"({"scene_distance_m": "inf"})").scene_at_infinity);
  }

  TEST_CASE("config files") {
    const std::string missing = "/nonexistent_dir_qdo/config.json";
    CHECK_THROWS_WITH_AS(qdo::config_from_json_file(missing), doctest::Contains(missing.c_str()), qdo::InputError);
    const std::string path = "/tmp/qdo_test_config_" + std::to_string(std::rand()) + ".json";
    {
      std::ofstream out(path);
      out << R"({"preset": "small", "bands": 4, "wavelength_step_nm": 100})";
    }
    const SystemConfig c = qdo::config_from_json_file(path);
    CHECK(c.n == 256);
    CHECK(c.wavelengths_nm().back() == 700);
    {
      std::ofstream out(path);
      out << R"({"preset": "small", "n": 255})";
    }
    CHECK_THROWS_WITH_AS(qdo::config_from_json_file(path), doctest::Contains(path.c_str()), qdo::InputError);
    CHECK_THROWS_WITH_AS(qdo::config_from_json_file(path), doctest::Contains("'n'"), qdo::InputError);
    std::remove(path.c_str());
  }
}

TEST_SUITE("config") {
  TEST_CASE("decoder specs: wiener, resunet, resunet:paper, resunet:depth=D,root=R; bad keys and values named") {
    using qdo::DecoderSpec;
    CHECK(qdo::decoder_spec_from_string("wiener").kind == DecoderSpec::Kind::Wiener);
    const DecoderSpec d = qdo::decoder_spec_from_string("resunet");
    CHECK(d.kind == DecoderSpec::Kind::ResUNet);
    CHECK(d.to_string() == "resunet:depth=4,root=16");
    CHECK(qdo::decoder_spec_from_string("resunet:paper").to_string() == "resunet:depth=7,root=32");
    CHECK(qdo::decoder_spec_from_string("resunet:depth=3,root=8").to_string() == "resunet:depth=3,root=8");
    CHECK(qdo::decoder_spec_from_string("resunet:root=8").to_string() == "resunet:depth=4,root=8");
    // The canonical form reads back as itself.
    for (const char* s : {"wiener", "resunet:depth=10,root=8", "resunet:depth=3,root=1024", "resunet:depth=1,root=1"})
      CHECK(qdo::decoder_spec_from_string(qdo::decoder_spec_from_string(s).to_string()).to_string() == s);
    auto refused = [](const std::string& spec, const char* named) {
      CAPTURE(spec);
      CHECK_THROWS_WITH_AS(qdo::decoder_spec_from_string(spec), doctest::Contains(named), qdo::InputError);
    };
    refused("unet", "--decoder");
    refused("resunet:", "nothing after");
    refused("resunet:depth=0", "'depth'");
    refused("resunet:depth=11", "'depth'");
    refused("resunet:root=x", "'root'");
    refused("resunet:root=", "'root'");
    refused("resunet:width=3", "width");
    refused("resunet:depth=3,depth=4", "given once");
    refused("resunet:depth", "key=value");
    // A network too wide to allocate is refused before any work: the widest
    // layer, root x 2^(depth-1), holds at most 4096 channels (the paper's: 2048).
    refused("resunet:depth=8,root=1024", "at most 4096 channels (this one: 131072)");
    refused("resunet:depth=10,root=16", "at most 4096 channels");
    CHECK_NOTHROW(qdo::decoder_spec_from_string("resunet:depth=8,root=32"));
  }
}
