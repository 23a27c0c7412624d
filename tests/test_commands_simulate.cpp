// The qdo commands end to end (doctest suite "commands"): simulate (its sensor image against the
// library's, --formation release, cubes checked for what they say) and demo, run as a user
// would (the qdo binary through the shell), checking what each one writes.
// The shared run and the tiny configuration are in commands_common.hpp.
//
// `qdo demo` has no --config, so it runs on the small preset (N = 256, 31 bands) with 2 steps
// per design.
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cstdint>
#include <fstream>
#include <set>
#include <sstream>

#include "commands_common.hpp"
#include "qdo/physics/cpu_reference.hpp"
#include "qdo/design/design_run.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/data/io.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/release.hpp"
#include "qdo/physics/release_reference.hpp"
#include "qdo/design/run.hpp"
#include "qdo/physics/simulator.hpp"

using namespace qdo;
using namespace qdo::test;
using namespace qdo::test::commands_suite;
namespace fs = std::filesystem;
using nlohmann::json;

TEST_SUITE("commands") {
  TEST_CASE("qdo simulate --formation release equals the release reference; its refusals") {
    const auto dir = temp_dir("cmd_release");
    SystemConfig c = tiny();
    c.aperture_edge = ApertureEdge::Strict;
    const fs::path cfg_file = dir / "strict.json";
    std::ofstream(cfg_file) << config_to_json_text(c) << "\n";
    const std::string cfg = "--config " + cfg_file.string();
    const RealStack scene = random_cube(c.bands, 16, 16, 5);  // S = 16 (the sensor size), N = 32: G = 48
    write_cube((dir / "scene.h5").string(), scene, c.wavelengths_nm());
    for (const Precision p : {Precision::F32, Precision::F64}) {
      if (p == Precision::F64 && !runtime().has_fp64()) continue;
      CAPTURE(to_string(p));
      const fs::path out = dir / to_string(p);
      const Run r = qdo_run("simulate " + cfg + " --design lens:550 --formation release --scene " + (dir / "scene.h5").string() +
                            " --precision " + to_string(p) + " --out " + out.string());
      CAPTURE(r.out);
      REQUIRE(r.code == 0);
      CHECK(r.out.find("formation: release") != std::string::npos);
      Simulator sim(runtime(), c, Precision::F64);
      sim.set_heights(lens_design(c, 550));
      sim.compute_psf();
      RealStack want = ref::sensor_integrate(ref::release_blur(scene, sim.psf_native()), sim.srf());
      ref::add_noise(want, c.read_noise_sigma, c.full_well_photons, c.noise_seed, 0);
      for (double& v : want.data) v = std::min(v, 1.0);  // the command clips at full scale
      const H5Dataset rgb = h5_read((out / "sensor.h5").string(), "/rgb");
      REQUIRE(rgb.shape == std::vector<std::size_t>{3, 16, 16});
      // The PSF itself in float32 (1e-6) dominates the float32 tolerance.
      CHECK(diff(rgb.data, want.data).rel_l2 <= (p == Precision::F64 ? 1e-12 : 2e-5));
    }
    const std::string base = "simulate " + cfg + " --design flat --out " + (dir / "x").string();
    Run r = qdo_run(base + " --formation tf");
    CHECK(r.code == 2);
    CHECK(r.out.find("--formation") != std::string::npos);
    write_cube((dir / "wide.h5").string(), random_cube(c.bands, 14, 12, 6), c.wavelengths_nm());
    r = qdo_run(base + " --formation release --scene " + (dir / "wide.h5").string());
    CHECK(r.code == 2);
    CHECK(r.out.find("square") != std::string::npos);
    // A scene of another size would be scaled by N / S, not by the pitch ratio (2 here): refused,
    // for smaller and larger scenes alike.
    for (std::size_t side : {14u, 20u, 31u}) {
      CAPTURE(side);
      write_cube((dir / "other.h5").string(), random_cube(c.bands, side, side, 7), c.wavelengths_nm());
      r = qdo_run(base + " --formation release --scene " + (dir / "other.h5").string());
      CHECK(r.code == 2);
      CHECK(r.out.find("a scene of the configuration's sensor size, 16 x 16") != std::string::npos);
      CHECK(r.out.find("the physical scale is 2") != std::string::npos);
    }
    CHECK_FALSE(fs::exists(dir / "x"));
    fs::remove_all(dir);
  }

  TEST_CASE("qdo simulate's sensor image equals the library's") {
    const SharedRun& s = shared_run();
    REQUIRE(s.result.code == 0);
    const auto dir = temp_dir("cmd_sim");
    const SystemConfig c = tiny();
    // A random 3-band scene in our cube format.
    const RealStack scene = random_cube(c.bands, 24, 20, 11);
    write_cube((dir / "scene.h5").string(), scene, c.wavelengths_nm());
    const std::string design = (s.dir / "design.h5").string();
    for (const Precision p : {Precision::F32, Precision::F64}) {
      if (p == Precision::F64 && !runtime().has_fp64()) continue;  // f32 alone is still compared
      CAPTURE(to_string(p));
      const fs::path out = dir / to_string(p);
      const Run r = qdo_run("simulate " + cfg_arg() + " --design " + design + " --scene " + (dir / "scene.h5").string() +
                            " --precision " + to_string(p) + " --out " + out.string());
      CAPTURE(r.out);
      REQUIRE(r.code == 0);
      Simulator sim(runtime(), c, p);
      Camera cam(sim);
      sim.set_heights(read_design(design).height_m);
      sim.compute_psf();
      const RealStack want = cam.images({scene}, no_skipping()).front();
      const H5Dataset rgb = h5_read((out / "sensor.h5").string(), "/rgb");
      REQUIRE(rgb.shape == std::vector<std::size_t>{3, want.rows, want.cols});
      CHECK(want.rows == 24);
      CHECK(want.cols == 20);
      const auto dd = diff(rgb.data, want.data);
      CHECK(dd.rel_l2 <= 10 * eps(p));
      CHECK(dd.max_abs <= 10 * eps(p));
      // The PSF the command wrote is the library's too, and the design it used is design.h5.
      const H5Dataset psf = h5_read((out / "psf.h5").string(), "/psf_sensor");
      CHECK(diff(psf.data, sim.psf_sensor().data).max_abs <= 10 * eps(p));
      CHECK(h5_read((out / "psf.h5").string(), "/height_m").data == read_design(design).height_m.data);
      for (const char* f : {"sensor.png", "scene.png", "psf.png"}) CHECK(fs::exists(out / f));
    }
    fs::remove_all(dir);
  }

  TEST_CASE("cubes mean what they say: band axis checked or resampled, radiance rule, sensor clipped at full scale") {
    const auto dir = temp_dir("cmd_cubes");
    const SystemConfig c = tiny();  // 3 bands: 450, 500, 550 nm
    const RealStack scene = random_cube(c.bands, 16, 16, 5);
    // A band axis 10 nm off the configuration's: refused before any work, naming both grids.
    write_cube((dir / "shifted.h5").string(), scene, {460, 510, 560});
    const fs::path out = dir / "out";
    Run r = qdo_run("simulate " + cfg_arg() + " --design flat --scene " + (dir / "shifted.h5").string() + " --out " + out.string());
    CAPTURE(r.out);
    CHECK(r.code == 2);
    CHECK(r.out.find("460 ... 560 nm") != std::string::npos);
    CHECK(r.out.find("450 ... 550 nm") != std::string::npos);
    CHECK_FALSE(fs::exists(out));
    // A reversed axis with --resample-bands: the cube is reordered, with a note, and images as
    // the correctly ordered cube does.
    RealStack reversed(c.bands, 16, 16);
    for (std::size_t b = 0; b < c.bands; ++b)
      std::copy(scene.plane(c.bands - 1 - b), scene.plane(c.bands - 1 - b) + 256, reversed.plane(b));
    write_cube((dir / "reversed.h5").string(), reversed, {550, 500, 450});
    write_cube((dir / "ordered.h5").string(), scene, c.wavelengths_nm());
    r = qdo_run("simulate " + cfg_arg() + " --design flat --scene " + (dir / "reversed.h5").string() + " --out " +
                (dir / "rev").string() + " --resample-bands");
    CAPTURE(r.out);
    REQUIRE(r.code == 0);
    CHECK(r.out.find("resampled") != std::string::npos);
    REQUIRE(qdo_run("simulate " + cfg_arg() + " --design flat --scene " + (dir / "ordered.h5").string() + " --out " +
                    (dir / "ord").string()).code == 0);
    CHECK(h5_read((dir / "rev" / "sensor.h5").string(), "/rgb").data == h5_read((dir / "ord" / "sensor.h5").string(), "/rgb").data);

    // Radiance: strongly negative refused (exit 2, naming the file); an HDR cube (values up to
    // 543) divided by its maximum, with a note, so the image stays within full scale.
    RealStack neg = scene;
    neg.data[17] = -0.5;
    write_cube((dir / "neg.h5").string(), neg, c.wavelengths_nm());
    r = qdo_run("simulate " + cfg_arg() + " --design flat --scene " + (dir / "neg.h5").string() + " --out " + (dir / "n").string());
    CHECK(r.code == 2);
    CHECK(r.out.find("neg.h5") != std::string::npos);
    CHECK(r.out.find("negative") != std::string::npos);
    CHECK_FALSE(fs::exists(dir / "n"));
    RealStack hdr = scene;
    for (double& v : hdr.data) v *= 543.0;
    write_cube((dir / "hdr.h5").string(), hdr, c.wavelengths_nm());
    r = qdo_run("simulate " + cfg_arg() + " --design flat --scene " + (dir / "hdr.h5").string() + " --out " + (dir / "h").string());
    CAPTURE(r.out);
    REQUIRE(r.code == 0);
    CHECK(r.out.find("divided by that maximum") != std::string::npos);
    const H5Dataset hdr_rgb = h5_read((dir / "h" / "sensor.h5").string(), "/rgb");
    CHECK(*std::max_element(hdr_rgb.data.begin(), hdr_rgb.data.end()) <= 1.0);

    // The sensor saturates: with read noise sigma 0.5 many values exceed full scale; they read as
    // 1, and the fraction is printed and stored with the image.
    SystemConfig noisy = c;
    noisy.read_noise_sigma = 0.5;
    std::ofstream(dir / "noisy.json") << config_to_json_text(noisy) << "\n";
    r = qdo_run("simulate --config " + (dir / "noisy.json").string() + " --design flat --scene " + (dir / "ordered.h5").string() +
                " --out " + (dir / "noisy").string());
    CAPTURE(r.out);
    REQUIRE(r.code == 0);
    const H5Dataset rgb = h5_read((dir / "noisy" / "sensor.h5").string(), "/rgb");
    const auto at_full = std::count(rgb.data.begin(), rgb.data.end(), 1.0);
    CHECK(*std::max_element(rgb.data.begin(), rgb.data.end()) == 1.0);
    CHECK(at_full > 0);
    CHECK(rgb.num_attrs.at("clipped_fraction") == doctest::Approx(double(at_full) / double(rgb.data.size())));
    CHECK(rgb.num_attrs.at("max_before_clip") > 1.0);
    CHECK(r.out.find("clipped at full scale") != std::string::npos);
    fs::remove_all(dir);
  }

  TEST_CASE("qdo demo deletes nothing it did not make: a user's files in DIR/do or DIR/qdoa are refused, exit 2") {
    const auto dir = temp_dir("cmd_demo_owned");
    fs::create_directories(dir / "do");
    std::ofstream(dir / "do" / "notes.txt") << "mine";
    // A folder qdo did not make: refused by the rule of every --out (claim_output_dir), naming it.
    const Run foreign = qdo_run("demo --preset small --levels 2 --epochs 2 --steps-per-epoch 1 --out " + dir.string());
    CHECK(foreign.code == 2);
    CHECK(foreign.out.find("qdo did not make, holding do") != std::string::npos);
    CHECK(foreign.out.find("--into-existing") != std::string::npos);
    // A folder an earlier demo made: its run folders are still checked, and a user's file in one refused.
    std::ofstream(dir / ".qdo-out") << "{\"made_by\": \"qdo\", \"command\": \"demo\"}\n";
    const Run r = qdo_run("demo --preset small --levels 2 --epochs 2 --steps-per-epoch 1 --data none --out " +
                           dir.string());
    CAPTURE(r.out);
    CHECK(r.code == 2);
    CHECK(r.out.find((dir / "do").string()) != std::string::npos);
    CHECK(slurp(dir / "do" / "notes.txt") == "mine");
    CHECK_FALSE(fs::exists(dir / "qdoa"));  // checked before any work
    // A file where demo's run folder would go is refused too.
    fs::remove_all(dir / "do");
    std::ofstream(dir / "qdoa") << "also mine";
    const Run f = qdo_run("demo --preset small --levels 2 --epochs 2 --steps-per-epoch 1 --out " + dir.string());
    CHECK(f.code == 2);
    CHECK(slurp(dir / "qdoa") == "also mine");
    fs::remove_all(dir);
  }

  TEST_CASE("qdo demo at the smallest size it accepts writes its runs, evaluations and summary") {
    const auto dir = temp_dir("cmd_demo");
    // demo has no --config: the small preset (N = 256, 31 bands) is its smallest system; 2 epochs of
    // 1 step each is its smallest schedule. --data none leaves the CAVE rows out.
    const Run r = qdo_run("demo --preset small --levels 2 --epochs 2 --steps-per-epoch 1 --data none --out " +
                           dir.string());
    CAPTURE(r.out);
    REQUIRE(r.code == 0);
    for (const char* run : {"qdoa", "do"}) {
      CAPTURE(run);
      CHECK(csv_rows(dir / run / "log.csv") == 2);
      const Design d = read_design((dir / run / "design.h5").string());
      CHECK(d.height_m.rows == 256);
      CHECK(d.levels_m.size() == 2);
      CHECK(std::set<double>(d.height_m.data.begin(), d.height_m.data.end()).size() <= 2);
    }
    CHECK(design_run_options_from_json(slurp(dir / "qdoa" / "config.json"), "qdoa").design.mode == DesignMode::QDOA);
    CHECK(design_run_options_from_json(slurp(dir / "do" / "config.json"), "do").design.mode == DesignMode::DO);
    // Four evaluation cells on the synthetic test set, each with finite metrics, none on CAVE.
    std::size_t cells = 0;
    for (const auto& e : fs::directory_iterator(dir / "eval")) {
      const std::string name = e.path().filename().string();
      CAPTURE(name);
      CHECK(name.find("_synthetic") != std::string::npos);
      const json m = read_json(e.path() / "metrics.json");
      CHECK(std::isfinite(m.at("mean").at("psnr_db").get<double>()));
      ++cells;
    }
    CHECK(cells == 4);
    const std::string md = slurp(dir / "summary.md");
    CHECK(md.find("# qdo demo") != std::string::npos);
    std::size_t rows = 0;
    for (std::size_t at = md.find("| synthetic |"); at != std::string::npos; at = md.find("| synthetic |", at + 1)) ++rows;
    CHECK(rows == 4);
    CHECK(md.find("CAVE") == std::string::npos);
    CHECK(fs::file_size(dir / "chart_scene.png") > 100);
    CHECK(fs::file_size(dir / "chart_sensor_qdoa.png") > 100);
    // A rerun over its own output replaces its run files and keeps anything else put there.
    std::ofstream(dir / "do" / "notes.txt") << "mine";
    const Run again = qdo_run("demo --preset small --levels 2 --epochs 2 --steps-per-epoch 1 --data none --out " +
                               dir.string());
    CAPTURE(again.out);
    CHECK(again.code == 0);
    CHECK(slurp(dir / "do" / "notes.txt") == "mine");
    CHECK(csv_rows(dir / "do" / "log.csv") == 2);
    // --epochs below 2 is refused (input error) before any device work.
    const Run one = qdo_run("demo --epochs 1 --out " + (dir / "x").string());
    CHECK(one.code == 2);
    CHECK(one.out.find("--epochs") != std::string::npos);
    fs::remove_all(dir);
  }
}
