// From design to fab, the fabrication model: QDO+M designs (subset-sum levels, exact gradients,
// resumable, exported with binary masks), fabricated heights under shifts, depth errors and
// blur, and the tolerance analysis.
#include <cstdlib>
#include <fstream>
#include <set>
#include <sstream>

#include <nlohmann/json.hpp>

#include "common.hpp"
#include "fab_common.hpp"
#include "qdo/design/design_run.hpp"
#include "qdo/evaluate/eval.hpp"
#include "qdo/design/gradcheck.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/fab/fab.hpp"
#include "qdo/data/io.hpp"
#include "qdo/design/run.hpp"

using namespace qdo;
using namespace qdo::test;
using namespace qdo::test::fab_suite;

namespace {

DesignRunOptions tiny_run(const std::string& out, DesignMode mode, int levels) {
  DesignRunOptions o;
  o.cfg = tiny_config(32, 3);
  o.design.mode = mode;
  o.design.quantizer.levels = levels;
  o.design.steps_per_epoch = 2;
  o.design.t0_epochs = 1;
  o.design.t1_epochs = 4;
  o.design.seed = 3;
  o.design.lr_offsets = 0.05;
  o.epochs = 5;
  o.synthetic_scenes = 3;
  o.checkpoint_every = 3;
  o.precision = runtime().has_fp64() ? Precision::F64 : Precision::F32;
  o.out = out;
  o.quiet = true;
  return o;
}

}  // namespace

TEST_SUITE("fab") {
  TEST_CASE("QDO+M: subset-sum levels, exact gradients, resumable, exported exactly with binary masks") {
    const auto dir = temp_dir("fab_qdom");
    const std::string a = (dir / "a").string(), b = (dir / "b").string();
    const DesignRunResult ra = run_design(runtime(), tiny_run(a, DesignMode::QDOM, 4), false);
    DesignRunOptions first = tiny_run(b, DesignMode::QDOM, 4);
    first.max_steps = 4;
    run_design(runtime(), first, false);
    run_design(runtime(), tiny_run(b, DesignMode::QDOM, 4), true);
    const DesignState sa = load_checkpoint(a + "/checkpoint.h5", 16, 2, true), sb = load_checkpoint(b + "/checkpoint.h5", 16, 2, true);
    CHECK(sa.offsets == sb.offsets);  // two mask depths, resumed bit-identically
    CHECK(sa.w == sb.w);
    // The levels are subset sums of the two trained depths, and the depths moved.
    const Design d = read_design(a + "/design.h5");
    REQUIRE(d.levels_m.size() == 4);
    CHECK(ra.levels_m == d.levels_m);
    const double hm = tiny_config(32, 3).h_max_m();
    CHECK(d.levels_m[0] == 0.0);
    CHECK(d.levels_m[3] == doctest::Approx(d.levels_m[1] + d.levels_m[2]).epsilon(1e-14));
    CHECK(sa.offsets[0] * hm == doctest::Approx(d.levels_m[1]).epsilon(1e-14));
    CHECK(sa.offsets[1] * hm == doctest::Approx(d.levels_m[2]).epsilon(1e-14));
    CHECK(std::fabs(sa.offsets[0] - 1.0 / 3.0) + std::fabs(sa.offsets[1] - 2.0 / 3.0) > 1e-4);
    CHECK(sa.offsets[0] + sa.offsets[1] <= 1.0 + 1e-15);
    const std::set<double> distinct(d.height_m.data.begin(), d.height_m.data.end());
    for (double v : distinct) CHECK(std::find(d.levels_m.begin(), d.levels_m.end(), v) != d.levels_m.end());
    // Binary export: index-coded, the masks' depths are the trained depths, round trip exact.
    fab::ExportOptions o;
    o.out = (dir / "export").string();
    const auto r = fab::export_design(d, tiny_config(32, 3), o);
    CHECK(r.plan.method == "index-coded");
    REQUIRE(r.plan.masks.size() == 2);
    CHECK(r.plan.masks[0].etch_depth_m == doctest::Approx(sa.offsets[0] * hm).epsilon(1e-12));
    CHECK(r.plan.masks[1].etch_depth_m == doctest::Approx(sa.offsets[1] * hm).epsilon(1e-12));
    CHECK(fab::reconstruct_export(o.out).level_of_pixel == r.plan.level_of_pixel);
    // Gradients of the mask depths against central differences; and the level count rule.
    DesignRunOptions g = tiny_run("(unused)", DesignMode::QDOM, 8);
    const auto rows = gradcheck(runtime(), g, 5);
    bool saw_depths = false;
    for (const auto& row : rows) {
      CAPTURE(row.group);
      CAPTURE(row.max_rel_error);
      CHECK(row.ok());
      saw_depths = saw_depths || row.group.find("mask depths") != std::string::npos;
    }
    CHECK(saw_depths);
    CHECK_THROWS_WITH_AS(run_design(runtime(), tiny_run((dir / "c").string(), DesignMode::QDOM, 6), false),
                         doctest::Contains("power of two"), InputError);
    CHECK(design_mode_from_string("qdo+m") == DesignMode::QDOM);
    CHECK(to_string(DesignMode::QDOM) == "qdo+m");
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("fabricated heights: no error is the design bit for bit; shifts, depths and blur act as modelled") {
    const SystemConfig cfg = tiny_config(32, 3);
    const Design d = level_design(cfg, 4, 11);
    const fab::MaskPlan plan = fab::plan_masks(d, cfg, fab::Scheme::Binary, {});
    CHECK(fab::perturbed_heights(plan, d.height_m, {}).data == d.height_m.data);
    fab::Perturbation z;
    z.depth_error_m.assign(plan.masks.size(), 0.0);
    z.shift_x_m.assign(plan.masks.size(), 0.0);
    z.shift_y_m.assign(plan.masks.size(), 0.0);
    CHECK(fab::perturbed_heights(plan, d.height_m, z, 4).data == d.height_m.data);
    // A depth error of mask 2 lowers exactly its open pixels.
    fab::Perturbation e = z;
    e.depth_error_m[1] = 10e-9;
    const Map2D he = fab::perturbed_heights(plan, d.height_m, e);
    const double lift = 10e-9;  // level 0 (etched by every mask) would go below 0: all heights are raised by 10 nm
    for (std::size_t i = 0; i < he.data.size(); ++i)
      CHECK(he.data[i] == doctest::Approx(d.height_m.data[i] - (plan.masks[1].drawn[i] ? 10e-9 : 0.0) + lift).epsilon(1e-12));
    // A shift by one whole pixel moves the mask's etch by one pixel; a sub-pixel shift keeps the
    // etched volume of a mask away from the border and leaves partially etched (sliver) pixels.
    fab::Perturbation s = z;
    s.shift_x_m[0] = cfg.pitch_m;
    const Map2D hs = fab::perturbed_heights(plan, d.height_m, s);
    const double D0 = plan.masks[0].etch_depth_m;
    for (std::size_t i = 0; i < cfg.n; ++i)
      for (std::size_t j = 1; j < cfg.n; ++j) {
        const double want = d.height_m(i, j) + D0 * (plan.masks[0].drawn[i * cfg.n + j] ? 1.0 : 0.0) -
                            D0 * (plan.masks[0].drawn[i * cfg.n + j - 1] ? 1.0 : 0.0);
        CHECK(hs(i, j) == doctest::Approx(want).epsilon(1e-9));
      }
    Design box = d;
    for (std::size_t i = 0; i < cfg.n; ++i)
      for (std::size_t j = 0; j < cfg.n; ++j) box.height_m(i, j) = (i >= 8 && i < 20 && j >= 8 && j < 22) ? d.levels_m[0] : d.levels_m[3];
    const fab::MaskPlan bp = fab::plan_masks(box, cfg, fab::Scheme::Nested, {});
    fab::Perturbation sub;
    REQUIRE(bp.masks.size() == 1);
    sub.shift_x_m = {0.37 * cfg.pitch_m};
    sub.shift_y_m = {-0.21 * cfg.pitch_m};
    const Map2D hb = fab::perturbed_heights(bp, box.height_m, sub, 4);
    double vol0 = 0, vol1 = 0;
    std::size_t slivers = 0;
    for (std::size_t i = 0; i < hb.data.size(); ++i) {
      vol0 += box.height_m.data[i];
      vol1 += hb.data[i];
      const double f = (box.levels_m[3] - hb.data[i]) / (box.levels_m[3] - box.levels_m[0]);
      slivers += f > 0.01 && f < 0.99;
    }
    CHECK(vol1 == doctest::Approx(vol0).epsilon(1e-12));
    CHECK(slivers > 10);
    // Edge blur keeps the volume too and softens the edges.
    fab::Perturbation bl;
    bl.edge_blur_m = 1e-6;
    const Map2D hbl = fab::perturbed_heights(bp, box.height_m, bl, 4);
    double vol2 = 0;
    for (double v : hbl.data) vol2 += v;
    CHECK(vol2 == doctest::Approx(vol0).epsilon(1e-9));
    CHECK(hbl(8, 14) > box.height_m(8, 14));
  }

  TEST_CASE("tolerance: zero error reproduces qdo eval exactly; errors degrade the metrics monotonically on average") {
    const auto dir = temp_dir("fab_tol");
    const std::string run = (dir / "run").string();
    DesignRunOptions ro = tiny_run(run, DesignMode::QDOM, 4);
    ro.precision = Precision::F32;
    run_design(runtime(), ro, false);
    EvalOptions e;
    e.run = run;
    e.synthetic_scenes = 3;
    e.renders = 0;
    e.out = (dir / "eval").string();
    const EvalResult ev = evaluate_run(runtime(), e);

    fab::ToleranceOptions t;
    t.run = run;
    t.synthetic_scenes = 3;
    t.etch_depth_error_m = 0;
    t.overlay_m = 0;
    t.trials = 1;
    t.out = (dir / "zero").string();
    t.save_psfs = true;
    const fab::ToleranceResult z = fab::tolerance_analysis(runtime(), t);
    CHECK(h5_read(t.out + "/psfs.h5", "/psf_all_0").data == h5_read(t.out + "/psfs.h5", "/psf_nominal").data);
    t.save_psfs = false;
    CHECK(z.plan.scheme == fab::Scheme::Binary);
    CHECK(z.nominal.psnr == ev.mean.psnr);
    CHECK(z.nominal.ssim == ev.mean.ssim);
    CHECK(z.nominal.rmse == ev.mean.rmse);
    CHECK(z.nominal.ergas == ev.mean.ergas);
    CHECK(z.nominal.sam_rad == ev.mean.sam_rad);
    CHECK(z.nominal.psnr_hyper == ev.mean.psnr_hyper);
    REQUIRE(z.trials.size() == 1);
    CHECK(z.trials[0].calibrated.psnr == ev.mean.psnr);
    CHECK(z.trials[0].nominal_decoder.psnr == ev.mean.psnr);
    CHECK(z.trials[0].calibrated.ssim == ev.mean.ssim);
    CHECK(z.trials[0].psf_rel_change == 0.0);
    CHECK(z.trials[0].height_rms_change_m == 0.0);
    for (const char* f : {"tolerance.csv", "tolerance.json", "tolerance.md", "psnr_by_scenario.png", "worst_height_error.png"})
      CHECK(std::filesystem::exists(std::filesystem::path(t.out) / f));

    // Increasing etch-depth errors and overlay: mean PSNR falls at every step (fixed seed, the
    // same draws scaled, several trials each; steps wide enough to beat the trial spread).
    t.out.clear();
    t.trials = 4;
    t.seed = 7;
    t.per_source = false;
    std::vector<double> psnr_nd, psnr_cal;
    for (double s : {0.0, 40e-9, 120e-9, 300e-9}) {
      t.etch_depth_error_m = s;
      t.overlay_m = s * 20;  // 0, 0.8, 2.4, 6 um
      const fab::ToleranceResult r = fab::tolerance_analysis(runtime(), t);
      psnr_nd.push_back(r.summary[0].nominal_decoder.at("psnr_db").mean);
      psnr_cal.push_back(r.summary[0].calibrated.at("psnr_db").mean);
    }
    CAPTURE(psnr_nd[0]);
    CAPTURE(psnr_nd[1]);
    CAPTURE(psnr_nd[2]);
    CAPTURE(psnr_nd[3]);
    CHECK(psnr_nd[0] == ev.mean.psnr);
    for (std::size_t k = 1; k < psnr_nd.size(); ++k) CHECK(psnr_nd[k] < psnr_nd[k - 1]);
    CHECK(psnr_cal.back() < psnr_cal.front());
    // Each source alone is reported, and reuses the combined trial's draws.
    t.trials = 2;
    t.etch_depth_error_m = 20e-9;
    t.overlay_m = 0.5e-6;
    t.height_noise_m = 10e-9;
    t.edge_blur_m = 0.3e-6;
    t.per_source = true;
    const fab::ToleranceResult all = fab::tolerance_analysis(runtime(), t);
    REQUIRE(all.summary.size() == 5);
    CHECK(all.summary[1].scenario == "etch depth");
    CHECK(all.trials[1].depth_error_m == all.trials[0].depth_error_m);
    CHECK(all.trials[2].shift_x_m == all.trials[0].shift_x_m);
    CHECK(all.trials[0].shift_x_m[0] == 0.0);  // mask 1 is the reference
    CHECK(all.trials[0].shift_x_m[1] != 0.0);
    std::filesystem::remove_all(dir);
  }
}
