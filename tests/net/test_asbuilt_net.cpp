// A network run's decoder adapted to the camera as built: `qdo design --mode
// do-finetune --from RUN --psf FILE | --design FILE` trains the do run's network on with the
// measured (or fitted) PSF frozen, records the file in config.json, split.json and design.h5, and
// `qdo eval` / `qdo reconstruct` of the fine-tuned run use that PSF. Suite "net" (LibTorch).
#include <nlohmann/json.hpp>

#include <filesystem>

#include "torch_common.hpp"  // LibTorch, then doctest's CHECK macros and the common helpers
#include "qdo/data/io.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/physics/simulator.hpp"

using namespace qdo;
using namespace qdo::test;
namespace fs = std::filesystem;

TEST_SUITE("net") {
  TEST_CASE("do-finetune for a measured PSF or a fitted design: starts from the run's network, trains with the file's PSF, records it") {
    const auto dir = temp_dir("net_asbuilt");
    const SystemConfig cfg = tiny_config(32, 3);
    const std::string cfgf = (dir / "tiny.json").string();
    write_text_atomic(cfgf, config_to_json_text(cfg));
    const std::string d = (dir / "do").string();
    const Run r1 = qdo_run("design --mode do --decoder resunet:depth=2,root=4 --config " + cfgf +
                           " --epochs 1 --steps-per-epoch 2 --synthetic-scenes 2 --batch 2 --out " + d);
    CAPTURE(r1.out);
    REQUIRE(r1.code == 0);
    // A "measured" stack: a diffractive lens's PSF, another camera than the do run's DOE.
    {
      Simulator sim(runtime(), cfg, Precision::F32);
      sim.set_heights(lens_design(cfg, 550));
      sim.compute_psf();
      write_psf((dir / "measured.h5").string(), sim.psf_sensor(), cfg.wavelengths_nm(), cfg.sensor_pitch_m);
    }
    const std::string ft = "design --mode do-finetune --from " + d + " --finetune-steps 2 --out ";
    const Run a = qdo_run(ft + (dir / "a").string());
    CAPTURE(a.out);
    REQUIRE(a.code == 0);
    // --psf with the do run's own psf.h5 (its quantized DOE's stack): the same fine-tune, loss for
    // loss, as the plain do-finetune, which starts from the run's network.
    const Run b = qdo_run(ft + (dir / "b").string() + " --psf " + d + "/psf.h5");
    CAPTURE(b.out);
    REQUIRE(b.code == 0);
    const CsvTable la = read_csv((dir / "a" / "log.csv").string()), lb = read_csv((dir / "b" / "log.csv").string());
    REQUIRE(la.column("loss").size() == 2);
    CHECK(la.column("loss") == lb.column("loss"));
    // Another PSF, another training.
    const Run c = qdo_run(ft + (dir / "c").string() + " --psf " + (dir / "measured.h5").string());
    CAPTURE(c.out);
    REQUIRE(c.code == 0);
    const CsvTable lc = read_csv((dir / "c" / "log.csv").string());
    CHECK(lc.column("loss")[0] != la.column("loss")[0]);
    // Recorded: config.json, split.json and design.h5's provenance name the file.
    const auto jc = nlohmann::json::parse(slurp(dir / "c" / "config.json"));
    CHECK(jc.at("design").at("finetune_psf") == (dir / "measured.h5").string());
    CHECK(nlohmann::json::parse(slurp(dir / "c" / "split.json")).at("finetune_psf") == (dir / "measured.h5").string());
    CHECK(slurp(dir / "c" / "design.h5").find((dir / "measured.h5").string()) != std::string::npos);
    // A fitted design: its PSF simulated; recorded as finetune_design.
    const Run f = qdo_run(ft + (dir / "f").string() + " --design " + d + "/design_full.h5");
    CAPTURE(f.out);
    REQUIRE(f.code == 0);
    CHECK(nlohmann::json::parse(slurp(dir / "f" / "config.json")).at("design").at("finetune_design") == d + "/design_full.h5");
    // The fine-tuned run is evaluated through its PSF by default, matched (its network was trained for it).
    const Run ev = qdo_run("eval " + (dir / "c").string() + " --synthetic-scenes 2 --renders 0 --out " + (dir / "ev").string());
    CAPTURE(ev.out);
    REQUIRE(ev.code == 0);
    CHECK(nlohmann::json::parse(slurp(dir / "ev" / "metrics.json")).at("psf").get<std::string>().find("measured.h5") != std::string::npos);
    // Reconstruct with it: its PSF is the default; another one is refused (a network cannot be refit).
    const std::size_t s = cfg.sensor_size_px();
    write_png16_rgb((dir / "cap.png").string(), RealStack(3, s, s, 20000.0));
    const Run rc = qdo_run("reconstruct --run " + (dir / "c").string() + " --capture " + (dir / "cap.png").string() + " --out " +
                           (dir / "rc").string());
    CAPTURE(rc.out);
    REQUIRE(rc.code == 0);
    CHECK(nlohmann::json::parse(slurp(dir / "rc" / "reconstruct.json")).at("psf").get<std::string>().find("measured.h5") != std::string::npos);
    const Run rc2 = qdo_run("reconstruct --run " + d + " --capture " + (dir / "cap.png").string() + " --psf " +
                            (dir / "measured.h5").string() + " --out " + (dir / "rc2").string());
    CHECK(rc2.code == 2);
    CHECK(rc2.out.find("do-finetune") != std::string::npos);
    // Refused before any work: a PSF for another grid (4 bands), named; --psf with --levels.
    write_psf((dir / "psf4.h5").string(), RealStack(4, s, s, 1.0 / double(s * s)), tiny_config(32, 4).wavelengths_nm(), cfg.sensor_pitch_m);
    const Run bad = qdo_run(ft + (dir / "bad").string() + " --psf " + (dir / "psf4.h5").string());
    CHECK(bad.code == 2);
    CHECK(bad.out.find("psf4.h5") != std::string::npos);
    CHECK(!fs::exists(dir / "bad" / "config.json"));
    const Run bad2 = qdo_run(ft + (dir / "bad2").string() + " --psf " + (dir / "measured.h5").string() + " --levels 2");
    CHECK(bad2.code == 2);
    CHECK(bad2.out.find("--levels") != std::string::npos);
    fs::remove_all(dir);
  }
}
