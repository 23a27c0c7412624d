// PSF sweeps across levels (batched designs) and the experiment grid.
#include <filesystem>
#include <fstream>

#include "common.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"
#include "qdo/design/run.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/design/design_run.hpp"
#include "qdo/evaluate/sweep.hpp"

using namespace qdo;
using namespace qdo::test;

namespace {

DesignRunOptions tiny_base() {
  DesignRunOptions o;
  o.cfg = tiny_config(32, 3);
  o.design.steps_per_epoch = 2;
  o.design.t0_epochs = 1;
  o.design.t1_epochs = 3;
  o.design.seed = 2;
  o.epochs = 3;
  o.synthetic_scenes = 3;
  o.precision = Precision::F32;
  o.quiet = true;
  return o;
}

}  // namespace

TEST_SUITE("sweep") {
  TEST_CASE("a batched pass over several designs equals one design at a time") {
    const SystemConfig c = tiny_config(48, 3);
    std::vector<Map2D> maps = {lens_design(c, 500), random_heights(c.n, c.h_max_m(), 3), flat_design(c)};
    Simulator batch(runtime(), c, Precision::F32, 3);
    batch.set_heights_batch(maps);
    batch.compute_psf();
    const RealStack all = batch.psf_sensor();
    REQUIRE(all.planes == 9);
    for (std::size_t d = 0; d < 3; ++d) {
      Simulator one(runtime(), c, Precision::F32);
      one.set_heights(maps[d]);
      one.compute_psf();
      const RealStack p = one.psf_sensor();
      std::vector<double> part(all.plane(d * 3), all.plane(d * 3) + p.size());
      CAPTURE(d);
      CHECK(diff(part, p.data).max_abs <= 1e-12);  // identical arithmetic, only batched
      for (std::size_t b = 0; b < 3; ++b)
        CHECK(batch.sampling().bands[d * 3 + b].energy_outside_window == one.sampling().bands[b].energy_outside_window);
    }
    CHECK_THROWS_AS(batch.psf_sensor_vjp(all), qdo::Error);  // adjoints need one design
  }

  TEST_CASE("PSF sweep: L = 32 is within 2 % of full precision on a smooth design; metrics move with L") {
    PsfSweepOptions o;
    o.cfg = tiny_config(64, 3);
    o.cfg.padding_px = 24;  // sampled adequately: lambda z <= M pitch^2
    o.cfg.wavelength_start_nm = 450;
    o.cfg.wavelength_step_nm = 25;
    o.design_full_m = lens_design(o.cfg, 475);
    for (int L : {2, 4, 8, 16, 32}) {
      PsfSweepVariant v;
      v.quantizer.levels = L;
      v.label = "L" + std::to_string(L);
      o.variants.push_back(v);
    }
    o.max_designs_per_pass = 4;  // two passes: exercises the chunking
    const auto dir = temp_dir("sweep_psf");
    o.out = dir.string();
    const auto rows = sweep_psf(runtime(), o);
    REQUIRE(rows.size() == 6);
    CHECK(rows[0].label == "full");
    auto mean = [](const std::vector<double>& v) {
      double s = 0;
      for (double x : v) s += x;
      return s / double(v.size());
    };
    CAPTURE(mean(rows[5].rel_l2));
    CHECK(mean(rows[5].rel_l2) <= 0.02);  // the stated tolerance at L = 32
    for (std::size_t k = 2; k < rows.size(); ++k) {
      CHECK(rows[k].deviation_nm < rows[k - 1].deviation_nm);
      CHECK(mean(rows[k].rel_l2) < mean(rows[k - 1].rel_l2));
    }
    CHECK(mean(rows[1].peak_ratio) < mean(rows[5].peak_ratio));
    for (const char* f : {"sweep.csv", "sweep.json", "psf.h5", "psf_L4.png", "rel_l2_vs_variant.png"}) CHECK(std::filesystem::exists(dir / f));
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("experiment grid: every cell lands in the tables, a killed sweep resumes without redoing finished cells") {
    const auto dir = temp_dir("grid");
    GridOptions g;
    g.base = tiny_base();
    g.levels = {2, 4};
    g.modes = {"do", "do-refit", "qdo+a"};
    g.eval_synthetic_scenes = 2;
    g.out = dir.string();
    // A "killed" earlier sweep: the qdo+a run at L = 4 stopped after 2 of its 6 steps, no DONE.
    DesignRunOptions partial = g.base;
    partial.design.mode = DesignMode::QDOA;
    partial.design.quantizer.levels = 4;
    partial.out = (dir / "runs" / "qdo+a_L4").string();
    partial.max_steps = 2;
    run_design(runtime(), partial, false);
    const auto cells = run_grid(runtime(), g);
    REQUIRE(cells.size() == 1 + 2 * 3);
    const DesignState st = load_checkpoint((dir / "runs" / "qdo+a_L4" / "checkpoint.h5").string(), 16, 4);
    CHECK(st.step == 6);  // resumed to the end
    std::ifstream t1(dir / "table1.md");
    std::string text((std::istreambuf_iterator<char>(t1)), std::istreambuf_iterator<char>());
    for (const char* needle : {"| full |", "| 2 | do |", "| 4 | do-refit |", "| 4 | qdo+a |"}) CHECK(text.find(needle) != std::string::npos);
    // do and do-refit differ exactly in the decoder: same DOE (deviation), different reconstruction.
    for (int L : {2, 4}) {
      const GridCell *d = nullptr, *r = nullptr;
      for (const auto& c : cells) {
        if (c.levels == L && c.mode == "do") d = &c;
        if (c.levels == L && c.mode == "do-refit") r = &c;
      }
      REQUIRE(d);
      REQUIRE(r);
      CHECK(d->deviation_nm == r->deviation_nm);
      CHECK(d->mean.psnr != r->mean.psnr);
    }
    // A second call redoes nothing: the cells' metrics files are not rewritten.
    const auto stamp = std::filesystem::last_write_time(dir / "cells" / "qdo+a_L2" / "metrics.json");
    const auto again = run_grid(runtime(), g);
    CHECK(std::filesystem::last_write_time(dir / "cells" / "qdo+a_L2" / "metrics.json") == stamp);
    CHECK(again.size() == cells.size());
    CHECK(again.back().mean.psnr == doctest::Approx(cells.back().mean.psnr).epsilon(1e-6));
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("experiment grid: Fresnel lens and CASSI cells with the same decoder family") {
    const auto dir = temp_dir("grid_enc");
    GridOptions g;
    g.base = tiny_base();
    g.levels = {4};
    g.modes = {"do"};
    g.encoders = {"fresnel", "cassi"};
    g.eval_synthetic_scenes = 2;
    g.out = dir.string();
    const auto cells = run_grid(runtime(), g);
    REQUIRE(cells.size() == 3);  // full reference, fresnel_L4, cassi
    CHECK(cells[1].mode == "fresnel");
    CHECK(cells[2].mode == "cassi");
    CHECK(cells[2].levels == -1);
    for (const auto& c : cells) {  // plausible reconstruction PSNRs (scenes in [0, 1])
      CHECK(c.mean.psnr > 10);
      CHECK(c.mean.psnr < 60);
    }
    std::ifstream t1(dir / "table1.md");
    std::string text((std::istreambuf_iterator<char>(t1)), std::istreambuf_iterator<char>());
    CHECK(text.find("| n/a | cassi |") != std::string::npos);
    CHECK(text.find("| 4 | fresnel |") != std::string::npos);
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("experiment grid: finished runs and cells are reused only for the same options and input bytes") {
    namespace fs = std::filesystem;
    const auto dir = temp_dir("grid_inputs");
    GridOptions g;
    g.base = tiny_base();
    g.levels = {2};
    g.modes = {"do", "qdo"};
    g.eval_synthetic_scenes = 2;
    g.out = (dir / "sweep").string();
    // Test scenes from a file (sensor-sized cubes).
    const std::size_t s = g.base.cfg.sensor_size_px();
    const std::string test = (dir / "test.h5").string();
    write_cube(test, random_cube(g.base.cfg.bands, s, s, 1), g.base.cfg.wavelengths_nm());
    g.test_data = {test};
    const auto first = run_grid(runtime(), g);
    REQUIRE(first.size() == 3);
    for (const auto& c : first) CHECK(c.inputs.rfind("fnv1a64:", 0) == 0);
    const CsvTable t1 = read_csv((fs::path(g.out) / "table1.csv").string());
    CHECK(t1.raw.back()[0] == first[0].inputs);  // the hash is in the table
    const auto stamp = fs::last_write_time(fs::path(g.out) / "cells" / "qdo_L2" / "metrics.json");
    // Other epochs or another learning rate: the finished runs do not match; refused, each difference named.
    GridOptions e = g;
    e.base.epochs = 4;
    CHECK_THROWS_WITH_AS(run_grid(runtime(), e), doctest::Contains("design.epochs: stored 3, given 4"), InputError);
    GridOptions lr = g;
    lr.base.design.lr_optics = 0.02;
    CHECK_THROWS_WITH_AS(run_grid(runtime(), lr), doctest::Contains("design.lr_optics: stored 0.01, given 0.02"), InputError);
    CHECK(fs::last_write_time(fs::path(g.out) / "cells" / "qdo_L2" / "metrics.json") == stamp);
    // The same test file path with other bytes (same size): every cell is evaluated again.
    write_cube(test, random_cube(g.base.cfg.bands, s, s, 2), g.base.cfg.wavelengths_nm());
    const auto second = run_grid(runtime(), g);
    REQUIRE(second.size() == first.size());
    for (std::size_t i = 0; i < first.size(); ++i) {
      CHECK(second[i].inputs != first[i].inputs);
      CHECK(second[i].mean.psnr != first[i].mean.psnr);
    }
    // The same inputs again: reused as they are.
    const auto third = run_grid(runtime(), g);
    CHECK(third.back().inputs == second.back().inputs);
    CHECK(third.back().mean.psnr == doctest::Approx(second.back().mean.psnr).epsilon(1e-6));
    // Training scenes changed under the same path: the runs are refused.
    const std::string train = (dir / "train.h5").string();
    GridOptions t = g;
    t.out = (dir / "sweep_t").string();
    t.modes = {"do"};
    write_cube(train, random_cube(g.base.cfg.bands, s, s, 3), g.base.cfg.wavelengths_nm());
    t.base.data = {train};
    run_grid(runtime(), t);
    write_cube(train, random_cube(g.base.cfg.bands, s, s, 4), g.base.cfg.wavelengths_nm());
    CHECK_THROWS_WITH_AS(run_grid(runtime(), t), doctest::Contains("training scenes changed"), InputError);
    fs::remove_all(dir);
  }
}
