// The qdo command line, run as a user would, and its input checks.
#include <cstdlib>
#include <fstream>
#include <map>
#include <set>
#include <sstream>

#include <nlohmann/json.hpp>

#include "common.hpp"
#include "qdo/data/io.hpp"
#include "qdo/design/recipe.hpp"

using namespace qdo;
using namespace qdo::test;

namespace {

void write_height_file(const std::string& path, std::size_t rows, std::size_t cols, double value, double pitch) {
  H5Dataset d{"/height_m", {rows, cols}, std::vector<double>(rows * cols, value), {{"pitch_m", pitch}}, {}};
  h5_write_unchecked(path, {d});  // NaN heights on purpose
}

}  // namespace

TEST_SUITE("cli") {
  TEST_CASE("qdo recipe: a command in one file prints every recipe item as the library sets it") {
    // The command is src/cli/cmd_recipe.cpp alone: it registers itself and the table, help and
    // dispatch find it.
    const Run help = qdo_run("--help");
    CHECK(help.out.find("recipe") != std::string::npos);
    const Run r = qdo_run("recipe --json");
    CAPTURE(r.out);
    REQUIRE(r.code == 0);
    const nlohmann::json j = nlohmann::json::parse(r.out.substr(r.out.find('{')));
    for (const std::string& name : qdo::recipe_names())
      for (const qdo::RecipeItem& it : qdo::recipe_items()) {
        CAPTURE(name);
        CAPTURE(it.option);
        CHECK(j.at("recipes").at(name).at(it.option).get<std::string>() == qdo::recipe_value(name, it.option));
        CHECK(j.at("what").at(it.option).get<std::string>() == it.what);
      }
    CHECK(j.at("not_reproduced").size() == qdo::recipe_gaps().size());
    const Run table = qdo_run("recipe --name release");
    REQUIRE(table.code == 0);
    for (const qdo::RecipeItem& it : qdo::recipe_items()) CHECK(table.out.find("--" + it.option) != std::string::npos);
    const std::string header = table.out.substr(0, table.out.find('\n'));
    CHECK(header.find("release") != std::string::npos);
    CHECK(header.find("qdo") == std::string::npos);  // one recipe's column only
    const Run bad = qdo_run("recipe --name paper");
    CHECK(bad.code == 2);
    CHECK(bad.out.find("--name") != std::string::npos);
  }

  TEST_CASE("qdo simulate --scene takes a CAVE PNG band folder, as --data does") {
    const auto dir = temp_dir("cli_pngscene");
    const std::string scene = (dir / "scene_ms").string(), out = (dir / "out").string();
    std::filesystem::create_directories(scene);
    for (int b = 1; b <= 31; ++b) {
      std::vector<unsigned char> px(16 * 16);
      for (std::size_t i = 0; i < px.size(); ++i) px[i] = static_cast<unsigned char>((i * 7 + static_cast<std::size_t>(b) * 5) % 256);
      write_png(scene + "/scene_ms_" + (b < 10 ? "0" : "") + std::to_string(b) + ".png", 16, 16, 1, px);
    }
    const Run r = qdo_run("simulate --preset small --design flat --scene " + scene + " --out " + out);
    CAPTURE(r.out);
    CHECK(r.code == 0);
    CHECK(r.out.find("scene 31 x 16 x 16") != std::string::npos);
    CHECK(std::filesystem::exists(out + "/sensor.h5"));
    // --key belongs to .mat / .h5 scenes only.
    const Run k = qdo_run("simulate --preset small --design flat --scene " + scene + " --key x --out " + out);
    CHECK(k.code != 0);
    CHECK(k.out.find("--key") != std::string::npos);
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("qdo psf writes a normalised PSF stack and figures") {
    const auto dir = temp_dir("cli_psf");
    const Run r = qdo_run("psf --preset small --design lens:550 --levels 8 --save native --out " + dir.string());
    CAPTURE(r.out);
    REQUIRE(r.code == 0);
    CHECK(r.out.find("sampling:") != std::string::npos);
    const H5Dataset psf = h5_read((dir / "psf.h5").string(), "/psf_native");
    REQUIRE(psf.shape == std::vector<std::size_t>{31, 256, 256});
    for (std::size_t b = 0; b < 31; ++b) {
      double s = 0;
      for (std::size_t i = 0; i < 256 * 256; ++i) s += psf.data[b * 256 * 256 + i];
      CHECK(s == doctest::Approx(1.0).epsilon(1e-4));
    }
    CHECK(h5_read((dir / "psf.h5").string(), "/wavelengths_nm").data.front() == 400.0);
    CHECK(std::filesystem::file_size(dir / "psf.png") > 1000);
    CHECK(std::filesystem::exists(dir / "design.png"));
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("qdo quantize writes a design with exactly L heights and its level table") {
    const auto dir = temp_dir("cli_q");
    const std::string full = (dir / "full.h5").string(), q = (dir / "q.h5").string();
    // A smooth ramp design in a file.
    Design d;
    d.height_m = Map2D(256, 256);
    d.pitch_m = 4e-6;
    for (std::size_t i = 0; i < d.height_m.data.size(); ++i) d.height_m.data[i] = 1.5e-6 * double(i % 256) / 255.0;
    write_design(full, d);
    const Run r = qdo_run("quantize --preset small --design " + full + " --levels 4 --placement wrapped --out " + q);
    CAPTURE(r.out);
    REQUIRE(r.code == 0);
    const Design dq = read_design(q);
    const std::set<double> distinct(dq.height_m.data.begin(), dq.height_m.data.end());
    CHECK(distinct.size() == 4);
    CHECK(dq.levels_m.size() == 4);
    for (double v : distinct) CHECK(std::find(dq.levels_m.begin(), dq.levels_m.end(), v) != dq.levels_m.end());
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("qdo simulate writes a sensor image of the built-in scene") {
    const auto dir = temp_dir("cli_sim");
    const Run r = qdo_run("simulate --preset small --design lens:550 --scene builtin --out " + dir.string());
    CAPTURE(r.out);
    REQUIRE(r.code == 0);
    const H5Dataset rgb = h5_read((dir / "sensor.h5").string(), "/rgb");
    CHECK(rgb.shape == std::vector<std::size_t>{3, 128, 128});
    CHECK(std::filesystem::exists(dir / "sensor.png"));
    // Lean by default: psf.h5 holds the sensor PSF stack (float32 storage for an f32 run) and not
    // the native-grid stack, which --save native adds; an unknown --save value is exit 2.
    const std::string psf = (dir / "psf.h5").string();
    CHECK(h5_has(psf, "/psf_sensor"));
    CHECK_FALSE(h5_has(psf, "/psf_native"));
    const auto lean = std::filesystem::file_size(psf);
    const auto dir2 = temp_dir("cli_sim_native");
    const Run n = qdo_run("simulate --preset small --design lens:550 --scene builtin --save native --out " + dir2.string());
    REQUIRE(n.code == 0);
    const std::string psf2 = (dir2 / "psf.h5").string();
    REQUIRE(h5_has(psf2, "/psf_native"));
    const H5Dataset native = h5_read(psf2, "/psf_native");
    CHECK(native.shape == std::vector<std::size_t>{31, 256, 256});
    // float32 storage: 4 bytes per value of both stacks (plus small datasets and metadata).
    const auto full = std::filesystem::file_size(psf2);
    CHECK(full - lean >= 31u * 256 * 256 * 4);
    CHECK(full - lean < 31u * 256 * 256 * 5);
    const Run bad = qdo_run("simulate --preset small --design lens:550 --save everything --out " + (dir2 / "x").string());
    CHECK(bad.code == 2);
    CHECK(bad.out.find("--save") != std::string::npos);
    CHECK_FALSE(std::filesystem::exists(dir2 / "x"));
    std::filesystem::remove_all(dir);
    std::filesystem::remove_all(dir2);
  }

  TEST_CASE("qdo --help, qdo <command> --help and qdo --version; an unknown option of any command is exit 2") {
    // Every command with every option it takes (each command's registration in src/cli/cmd_*.cpp
    // must declare each of them, and its help must show each).
    const std::map<std::string, std::vector<std::string>> commands = {
        {"devices", {}},
        {"config", {"preset", "config"}},
        {"psf", {"preset", "config", "design", "levels", "placement", "precision", "device", "out", "save"}},
        {"quantize", {"preset", "config", "design", "levels", "placement", "out"}},
        {"simulate", {"preset", "config", "design", "levels", "placement", "scene", "key", "precision", "device", "out", "resample-bands", "save"}},
        {"demo", {"preset", "levels", "device", "out", "precision", "epochs", "steps-per-epoch", "data"}},
        {"design", {"preset", "config", "mode", "levels", "placement", "parameterization", "objective", "target", "data", "epochs",
                    "steps-per-epoch", "t0", "t1", "lr", "lr-offsets", "decay", "beta", "height-noise-nm", "noise-sigma", "init", "seed",
                    "checkpoint-every", "max-steps", "resume", "check-gradients", "precision", "device", "out", "synthetic-scenes",
                    "batch", "psf-path"}},
        {"eval", {"data", "levels", "placement", "decoder", "noise-sigma", "pixels", "renders", "synthetic-scenes", "precision",
                  "device", "out"}},
        {"gradcheck", {"preset", "config", "mode", "levels", "placement", "parameterization", "objective", "target", "seed", "device",
                       "psf-path"}},
        {"image", {"preset", "config", "design", "levels", "placement", "scene", "key", "precision", "device", "tolerance", "tiles",
                   "tile-px", "out", "resample-bands", "exact"}},
        {"export", {"scheme", "out", "preset", "config", "min-feature-um", "max-levels", "max-height-nm", "dose-curve", "tolerance-nm"}},
        {"tolerance", {"etch-depth-error-nm", "overlay-um", "edge-blur-um", "height-noise-nm", "trials", "seed", "out", "scheme",
                       "oversample", "data", "synthetic-scenes", "noise-sigma", "precision", "device", "no-per-source", "save-psfs"}},
        {"sweep", {"grid", "preset", "config", "placement", "parameterization", "objective", "data", "test-data", "epochs",
                   "steps-per-epoch", "t0", "t1", "lr", "lr-offsets", "decay", "beta", "height-noise-nm", "noise-sigma", "init", "seed",
                   "synthetic-scenes", "eval-scenes", "batch", "precision", "device", "out", "psf-path"}},
        {"sweep-psf", {"design", "levels", "placement", "adaptive-from", "preset", "config", "precision", "device", "designs-per-pass",
                       "out"}},
        {"reconstruct", {"run", "capture", "darks", "psf", "design", "exposure", "crop", "demosaic", "overlap", "boundary", "noise-sigma", "points",
                         "boxes", "precision", "device", "out"}},
    };
    const Run top = qdo_run("--help");
    CAPTURE(top.out);
    CHECK(top.code == 0);
    for (const auto& [cmd, opts] : commands) {
      CAPTURE(cmd);
      CHECK(top.out.find("\n  " + cmd + " ") != std::string::npos);  // one line per command
      for (const char* h : {" --help", " -h"}) {
        const Run r = qdo_run(cmd + h);
        CAPTURE(r.out);
        CHECK(r.code == 0);
        CHECK(r.out.find("qdo " + cmd) != std::string::npos);
        for (const auto& o : opts) {
          CAPTURE(o);
          const std::size_t at = r.out.find("--" + o + " ");
          REQUIRE(at != std::string::npos);
          // Every option, flags included, has a description on its line.
          const std::string line = r.out.substr(at, r.out.find('\n', at) - at);
          CHECK(line.find_first_not_of(' ', line.find(' ')) != std::string::npos);
        }
      }
      const Run bad = qdo_run(cmd + " --bogus 3");
      CAPTURE(bad.out);
      CHECK(bad.code == 2);
      CHECK(bad.out.find("qdo " + cmd + ": error: ") != std::string::npos);
      CHECK(bad.out.find("--bogus") != std::string::npos);
    }
    // Defaults are shown; --name=value and a missing value.
    const Run dh = qdo_run("design --help");
    CHECK(dh.out.find("default: qdo+a") != std::string::npos);
    CHECK(dh.out.find("full, do, qdo, ste, qdo+a, qdo+m, or do-finetune") != std::string::npos);
    CHECK(dh.out.find("--decoder") != std::string::npos);
    const Run cfg = qdo_run("config --preset=small");
    CHECK(cfg.code == 0);
    CHECK(cfg.out.find("\"n\"") != std::string::npos);
    const Run miss = qdo_run("config --preset");
    CAPTURE(miss.out);
    CHECK(miss.code == 2);
    CHECK(miss.out.find("argument '--preset' = (missing)") != std::string::npos);
    const Run stray = qdo_run("config small");
    CHECK(stray.code == 2);
    CHECK(stray.out.find("small") != std::string::npos);
    // qdo --version: version, git revision, OpenCL devices, FFT backends; no device needed.
    const Run v = qdo_run("--version");
    CAPTURE(v.out);
    CHECK(v.code == 0);
    CHECK(v.out.find("qdo 0.1.0") != std::string::npos);
    CHECK(v.out.find("git revision ") != std::string::npos);
    CHECK(v.out.find("clFFT") != std::string::npos);
    CHECK(v.out.find("VkFFT") != std::string::npos);
    CHECK(v.out.find("FFTW") != std::string::npos);
    const auto dir = temp_dir("cli_version");
    std::filesystem::create_directories(dir / "no_vendors");
    const Run nv = qdo_run("--version", "OCL_ICD_VENDORS=" + (dir / "no_vendors").string());
    CAPTURE(nv.out);
    CHECK(nv.code == 0);
    CHECK(nv.out.find("no OpenCL platform") != std::string::npos);
    CHECK(nv.out.find("clFFT") != std::string::npos);
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("bad input fails before any work with an error naming the argument") {
    const auto dir = temp_dir("cli_bad");
    const std::string out = (dir / "never").string();
    auto expect = [&](const std::string& args, const std::string& needle, const std::string& env = "") {
      const Run r = qdo_run(args, env);
      CAPTURE(args);
      CAPTURE(r.out);
      CHECK(r.code != 0);
      CHECK(r.out.find(needle) != std::string::npos);
      CHECK_FALSE(std::filesystem::exists(out));  // nothing was started or written
    };
    const std::string nonsq = (dir / "nonsquare.h5").string(), nan = (dir / "nan.h5").string(), nods = (dir / "nods.h5").string();
    write_height_file(nonsq, 256, 200, 0.0, 4e-6);
    write_height_file(nan, 256, 256, std::nan(""), 4e-6);
    h5_write(nods, {H5Dataset{"/something_else", {2}, {1.0, 2.0}, {}, {}}});
    expect("psf --preset small --design " + nonsq + " --out " + out, "square");
    expect("psf --preset small --design " + nan + " --out " + out, "non-finite");
    expect("psf --preset small --design " + nods + " --out " + out, "/height_m");
    const std::string cfg0 = (dir / "z0.json").string(), cfgneg = (dir / "dneg.json").string(), cfgwl = (dir / "wl.json").string();
    std::ofstream(cfg0) << R"({"preset": "small", "sensor_distance_m": 0})";
    std::ofstream(cfgneg) << R"({"preset": "small", "scene_distance_m": -1})";
    std::ofstream(cfgwl) << R"({"preset": "small", "material": "NOA61", "wavelength_start_nm": 300})";
    expect("psf --config " + cfg0 + " --design flat --out " + out, "sensor_distance_m");
    expect("psf --config " + cfgneg + " --design flat --out " + out, "scene_distance_m");
    expect("psf --config " + cfgwl + " --design flat --out " + out, "NOA61");
    expect("psf --preset small --design lens:550 --levels 1 --out " + out, "--levels");
    expect("psf --preset small --design lens:550 --bogus 3 --out " + out, "--bogus");
    expect("psf --preset nope --design flat --out " + out, "preset");
    // A cube whose bands don't match the configuration.
    const std::string cube30 = (dir / "cube30.h5").string();
    std::vector<double> wl30(30);
    for (std::size_t k = 0; k < wl30.size(); ++k) wl30[k] = 400.0 + 10.0 * double(k);
    write_cube(cube30, RealStack(30, 8, 8, 0.5), wl30);
    expect("simulate --preset small --design flat --scene " + cube30 + " --out " + out, "31");
    // An SRF on another band grid.
    const std::string cam = (dir / "cam.csv").string(), cfgcam = (dir / "cam.json").string();
    std::ofstream(cam) << "wavelength_nm,R,G,B\n400,1,1,1\n500,1,1,1\n600,1,1,1\n700,1,1,1\n";
    std::ofstream(cfgcam) << R"({"preset": "small", "camera": ")" + cam + R"("})";
    expect("simulate --config " + cfgcam + " --design flat --scene builtin --out " + out, "camera");
    // No OpenCL platform at all (an empty ICD vendor directory).
    const auto empty = dir / "no_vendors";
    std::filesystem::create_directories(empty);
    expect("devices", "no OpenCL platform", "OCL_ICD_VENDORS=" + empty.string());
    std::filesystem::remove_all(dir);
  }
}
