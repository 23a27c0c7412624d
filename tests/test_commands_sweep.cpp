// The qdo commands end to end (doctest suite "commands"): sweep-psf, sweep, tolerance and
// export, run as a user would (the qdo binary through the shell), checking what each one writes.
// The shared run and the tiny configuration are in commands_common.hpp.
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cstdint>
#include <fstream>
#include <set>
#include <sstream>

#include "commands_common.hpp"
#include "qdo/design/design_run.hpp"
#include "qdo/fab/fab.hpp"
#include "qdo/data/io.hpp"
#include "qdo/design/run.hpp"

using namespace qdo;
using namespace qdo::test;
using namespace qdo::test::commands_suite;
namespace fs = std::filesystem;
using nlohmann::json;

TEST_SUITE("commands") {
  TEST_CASE("qdo sweep-psf --adaptive-from: one unit-sum PSF stack per requested variant") {
    const SharedRun& s = shared_run();
    REQUIRE(s.result.code == 0);
    const auto dir = temp_dir("cmd_sweeppsf");
    const Run r = qdo_run("sweep-psf --design " + s.dir.string() + " --levels 2,4 --adaptive-from " + s.dir.string() + " --out " +
                          dir.string());
    CAPTURE(r.out);
    REQUIRE(r.code == 0);
    const std::vector<std::string> labels = {"full", "L2", "L4", "L4-adaptive"};
    const json j = read_json(dir / "sweep.json");
    REQUIRE(j.size() == labels.size());
    for (std::size_t k = 0; k < labels.size(); ++k) {
      CAPTURE(labels[k]);
      CHECK(j[k].at("variant") == labels[k]);
      CHECK(j[k].at("rel_l2").size() == 3);
      const H5Dataset p = h5_read((dir / "psf.h5").string(), "/psf_" + labels[k]);
      REQUIRE(p.shape.size() == 3);
      CHECK(p.shape[0] == 3);
      CHECK(p.shape[1] == tiny().sensor_size_px());
      for (double sum : plane_sums(p)) CHECK(sum == doctest::Approx(1.0).epsilon(1e-4));
    }
    CHECK(j[0].at("levels") == 0);
    CHECK(j[0].at("deviation_nm").get<double>() == 0.0);
    for (double v : j[0].at("rel_l2")) CHECK(v == 0.0);
    for (double v : j[0].at("peak_ratio")) CHECK(v == doctest::Approx(1.0));
    CHECK(j[1].at("levels") == 2);
    CHECK(j[3].at("levels") == kLevels);
    // Coarser quantization moves the heights further from H_f.
    CHECK(j[1].at("deviation_nm").get<double>() > j[2].at("deviation_nm").get<double>());
    CHECK(j[2].at("deviation_nm").get<double>() > 0);
    // The adaptive variant is the run's own fabricated design: its deviation is design.h5's.
    const Design fab = read_design((s.dir / "design.h5").string()), full = read_design((s.dir / "design_full.h5").string());
    double dev = 0;
    for (std::size_t i = 0; i < fab.height_m.data.size(); ++i) dev += std::fabs(fab.height_m.data[i] - full.height_m.data[i]);
    dev /= double(fab.height_m.data.size());
    CHECK(j[3].at("deviation_nm").get<double>() == doctest::Approx(dev * 1e9).epsilon(1e-6));
    // ... and its PSF stack is the run's psf.h5 (same heights, same f32 PSF chain, batched here).
    CHECK(diff(h5_read((dir / "psf.h5").string(), "/psf_L4-adaptive").data, h5_read((s.dir / "psf.h5").string(), "/psf_sensor").data).rel_l2 <=
          10 * kEps32);
    CHECK(csv_rows(dir / "sweep.csv") == labels.size() * 3);
    CHECK(fs::exists(dir / "psf_L4-adaptive.png"));
    // --adaptive-from needs a qdo+a run folder.
    CHECK(qdo_run("sweep-psf --design " + s.dir.string() + " --levels 2 --adaptive-from " + (dir / "nope").string() + " --out " +
                  (dir / "x").string()).code == 2);
    fs::remove_all(dir);
  }

  TEST_CASE("qdo sweep: one table row per grid cell, DO trained once") {
    const auto dir = temp_dir("cmd_sweep");
    const Run r = qdo_run("sweep " + cfg_arg() + " --grid levels=2,4 --grid mode=do,do-refit --epochs 2 --steps-per-epoch 1 --t0 0.5 "
                          "--t1 1.5 --synthetic-scenes 3 --eval-scenes 2 --out " + dir.string());
    CAPTURE(r.out);
    REQUIRE(r.code == 0);
    // Cells: the full-precision reference + 2 levels x 2 modes.
    const CsvTable t1 = read_csv((dir / "table1.csv").string());
    REQUIRE(t1.column("psnr_db").size() == 5);
    std::set<std::string> cells;
    for (std::size_t i = 0; i < 5; ++i) {
      cells.insert(t1.raw[0][i] + "/" + t1.raw[1][i]);
      CHECK(std::isfinite(t1.column("psnr_db")[i]));
      CHECK(t1.column("psnr_db")[i] > 10);
      CHECK(t1.column("ssim")[i] > 0);
      CHECK(t1.column("ssim")[i] <= 1);
    }
    CHECK(cells.size() == 5);
    CHECK(cells.count("2/do") == 1);
    CHECK(cells.count("4/do-refit") == 1);
    // Table 2: do and do-refit share the DOE, so their deviation is the same; 2 levels deviate more than 4.
    const CsvTable t2 = read_csv((dir / "table2.csv").string());
    std::map<std::string, double> dev;
    for (std::size_t i = 0; i < t2.column("deviation_nm").size(); ++i) dev[t2.raw[0][i] + "/" + t2.raw[1][i]] = t2.column("deviation_nm")[i];
    REQUIRE(dev.count("2/do"));
    REQUIRE(dev.count("2/do-refit"));
    REQUIRE(dev.count("4/do"));
    CHECK(dev["2/do"] == dev["2/do-refit"]);
    CHECK(dev["2/do"] > dev["4/do"]);
    // One training run (DO, full precision), finished.
    CHECK(fs::exists(dir / "runs" / "do" / "DONE"));
    CHECK(fs::exists(dir / "table1.md"));
    CHECK(fs::exists(dir / "psnr_vs_levels.png"));
    CHECK(csv_rows(dir / "runs" / "do" / "log.csv") == 2);
    // sweep-psf --adaptive-from refuses a run that is not qdo+a (input error naming the mode).
    const Run ad = qdo_run("sweep-psf --design " + (dir / "runs" / "do").string() + " --levels 2 --adaptive-from " +
                           (dir / "runs" / "do").string() + " --out " + (dir / "x").string());
    CHECK(ad.code == 2);
    CHECK(ad.out.find("qdo+a") != std::string::npos);
    // An unknown grid axis is an input error.
    CHECK(qdo_run("sweep " + cfg_arg() + " --grid colour=red --out " + (dir / "y").string()).code == 2);
    // The sweep's identity is the folder, not how a path to it is spelt: --collect from the parent
    // folder with a relative, a ./ and a trailing-slash spelling finds every cell finished, and
    // deletes no stamp (a Slurm array and its collect step spell paths as they like).
    std::vector<fs::path> stamps;
    for (const auto& e : fs::recursive_directory_iterator(dir))
      if (e.path().filename() == "inputs") stamps.push_back(e.path());
    REQUIRE(stamps.size() == 5);
    const std::string grid = " --grid levels=2,4 --grid mode=do,do-refit --epochs 2 --steps-per-epoch 1 --t0 0.5 --t1 1.5 "
                             "--synthetic-scenes 3 --eval-scenes 2 --collect --into-existing --out ";
    const std::string name = dir.filename().string();
    for (const std::string& spelt : {name, "./" + name + "/", (dir / "." / "runs" / "..").string()}) {
      CAPTURE(spelt);
      const Run c = qdo_run("sweep " + cfg_arg() + grid + spelt, "cd " + dir.parent_path().string() + " &&");
      CAPTURE(c.out);
      CHECK(c.code == 0);
      for (const auto& st : stamps) CHECK(fs::exists(st));
    }
    // A collect that finds unfinished cells only reads: a cell's stale stamp stays until a run
    // evaluates that cell again.
    const fs::path one = stamps.front();
    write_text_atomic(one.string(), "0123456789abcdef\n");
    CHECK(qdo_run("sweep " + cfg_arg() + grid + dir.string()).code == 2);
    CHECK(slurp(one) == "0123456789abcdef\n");
    fs::remove_all(dir);
  }

  TEST_CASE("qdo tolerance: zero perturbation gives zero spread, errors give per-source scenarios") {
    const SharedRun& s = shared_run();
    REQUIRE(s.result.code == 0);
    const auto dir = temp_dir("cmd_tol");
    const std::string common = " --trials 2 --synthetic-scenes 2 --oversample 1 --seed 5 ";
    {
      const Run r = qdo_run("tolerance " + s.dir.string() + common + "--etch-depth-error-nm 0 --overlay-um 0 --out " + (dir / "zero").string());
      CAPTURE(r.out);
      REQUIRE(r.code == 0);
      const json j = read_json(dir / "zero" / "tolerance.json");
      REQUIRE(j.at("scenarios").size() == 1);
      const json& all = j.at("scenarios")[0];
      CHECK(all.at("scenario") == "all");
      CHECK(all.at("trials") == 2);
      const double nominal = j.at("nominal").at("psnr_db").get<double>();
      CHECK(std::isfinite(nominal));
      CHECK(std::fabs(all.at("calibrated").at("psnr_db").at("std").get<double>()) < 1e-9);
      CHECK(all.at("calibrated").at("psnr_db").at("mean").get<double>() == doctest::Approx(nominal).epsilon(1e-9));
      CHECK(all.at("nominal_decoder").at("psnr_db").at("mean").get<double>() == doctest::Approx(nominal).epsilon(1e-9));
      const CsvTable t = read_csv((dir / "zero" / "tolerance.csv").string());
      REQUIRE(t.column("psf_rel_change").size() == 2);
      for (double v : t.column("psf_rel_change")) CHECK(v < 1e-12);
      for (double v : t.column("height_rms_change_nm")) CHECK(v < 1e-9);
    }
    {
      const Run r = qdo_run("tolerance " + s.dir.string() + common + "--etch-depth-error-nm 30 --overlay-um 2 --out " + (dir / "err").string());
      CAPTURE(r.out);
      REQUIRE(r.code == 0);
      const json j = read_json(dir / "err" / "tolerance.json");
      // auto: binary-coded masks cannot make qdo+a's learned (non-uniform) levels, so nested: L - 1 masks.
      CHECK(j.at("scheme") == "nested");
      CHECK(j.at("masks").size() == std::size_t(kLevels - 1));
      std::vector<std::string> names;
      for (const auto& sc : j.at("scenarios")) names.push_back(sc.at("scenario"));
      CHECK(names == std::vector<std::string>{"all", "etch depth", "overlay"});
      const CsvTable t = read_csv((dir / "err" / "tolerance.csv").string());
      REQUIRE(t.column("psf_rel_change").size() == 3 * 2);
      for (std::size_t i = 0; i < t.raw[0].size(); ++i) {
        CAPTURE(t.raw[0][i]);
        CHECK(t.column("psf_rel_change")[i] > 0);  // every trial moves the PSF
        CHECK(std::isfinite(t.column("psnr_db")[i]));
      }
      for (const char* f : {"tolerance.md", "psnr_by_scenario.png"}) CHECK(fs::exists(dir / "err" / f));
    }
    CHECK(qdo_run("tolerance " + s.dir.string() + " --trials 0 --out " + (dir / "x").string()).code == 2);
    CHECK(qdo_run("tolerance " + s.dir.string() + " --overlay-um -1 --out " + (dir / "x").string()).code == 2);
    fs::remove_all(dir);
  }

  TEST_CASE("qdo export writes a GDSII mask set and a manifest that rebuild design.h5") {
    const SharedRun& s = shared_run();
    REQUIRE(s.result.code == 0);
    const auto dir = temp_dir("cmd_export");
    // qdo+a's learned levels are not subset sums of binary etch depths: binary masks are refused
    // (input error naming the alternatives), nested masks (L - 1 layers, free step heights) work.
    const Run bin = qdo_run("export " + s.dir.string() + " --scheme binary --out " + (dir / "bin").string());
    CHECK(bin.code == 2);
    CHECK(bin.out.find("--scheme nested") != std::string::npos);
    const Run r = qdo_run("export " + s.dir.string() + " --scheme nested --out " + dir.string());
    CAPTURE(r.out);
    REQUIRE(r.code == 0);
    // GDSII: HEADER (length 6, type 0x00 0x02, version 600), then BGNLIB (length 28, 0x01 0x02); ENDLIB last.
    const std::string g = slurp(dir / "masks.gds");
    REQUIRE(g.size() > 64);
    const std::vector<std::uint8_t> head(g.begin(), g.begin() + 10), tail(g.end() - 4, g.end());
    CHECK(head == std::vector<std::uint8_t>{0x00, 0x06, 0x00, 0x02, 0x02, 0x58, 0x00, 0x1C, 0x01, 0x02});
    CHECK(tail == std::vector<std::uint8_t>{0x00, 0x04, 0x04, 0x00});
    // The manifest lists the design's L levels with their heights and the L - 1 nested masks.
    const Design d = read_design((s.dir / "design.h5").string());
    const json m = read_json(dir / "manifest.json");
    CHECK(m.at("scheme") == "nested");
    REQUIRE(m.at("levels").size() == std::size_t(kLevels));
    for (std::size_t l = 0; l < std::size_t(kLevels); ++l)
      CHECK(m.at("levels")[l].at("height_nm").get<double>() == doctest::Approx(d.levels_m[l] * 1e9).epsilon(1e-9));
    std::size_t pixels = 0;
    for (const auto& l : m.at("levels")) pixels += l.at("pixels").get<std::size_t>();
    CHECK(pixels == 32 * 32);
    CHECK(m.at("masks").size() == std::size_t(kLevels - 1));
    CHECK(m.at("grid").at("n") == 32);
    // Read back from the GDS and the manifest alone, the masks rebuild design.h5.
    const fab::Reconstruction rec = fab::reconstruct_export(dir.string());
    REQUIRE(rec.height_m.data.size() == d.height_m.data.size());
    double worst = 0;
    for (std::size_t i = 0; i < d.height_m.data.size(); ++i) worst = std::max(worst, std::fabs(rec.height_m.data[i] - d.height_m.data[i]));
    CHECK(worst < 1e-12);  // metres; well under the 0.001 nm level tolerance
    CHECK(std::count_if(rec.level_of_pixel.begin(), rec.level_of_pixel.end(), [](std::int32_t v) { return v < 0; }) == 0);
    CHECK(fs::exists(dir / "manifest.md"));
    CHECK(fs::exists(dir / "mask_L1.png"));
    // A bad scheme, or a fab constraint the design breaks (fewer levels allowed than it has): exit 2.
    CHECK(qdo_run("export " + s.dir.string() + " --scheme stencil --out " + (dir / "x").string()).code == 2);
    CHECK(qdo_run("export " + s.dir.string() + " --scheme nested --max-levels 2 --out " + (dir / "y").string()).code == 2);
    fs::remove_all(dir);
  }
}
