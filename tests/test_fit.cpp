// qdo fit (suite `fit`, include/qdo/asbuilt/fit.hpp): the as-built DOE. A known perturbation of a 4-level
// lens (level depths off by +15, -20, +20 nm, the DOE-sensor distance z off by 1.6 %, the relief
// offset by (0.3, -0.2) DOE pixels) is applied through the fit's own model (the same forward
// model: these tests check the inverse, not the physics, which the psf suite checks), PSFs are
// simulated through it, and the fit recovers it: tightly without noise; with Gaussian noise of a
// stated level within 4 reported sigmas, the sigmas below stated bounds. The adjoint gradient is
// checked against central differences; the degenerate pairs are reported; every refusal names
// what is wrong; `qdo fit` runs end to end on files the test writes and refuses bad input (exit 2).
#include <doctest/doctest.h>

#include <nlohmann/json.hpp>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <vector>

#include "adjoint_ladder.hpp"
#include "common.hpp"
#include "fit_common.hpp"
#include "qdo/data/config.hpp"
#include "qdo/design/design.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/asbuilt/fit.hpp"
#include "qdo/design/option_inputs.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/data/io.hpp"
#include "qdo/physics/simulator.hpp"

using namespace qdo;
using namespace qdo::test;
namespace fs = std::filesystem;

namespace {

// The truth: theta of levels,z,offset = (level1..3, z, dx, dy).
std::vector<double> truth(const SystemConfig& cfg, const Design& d) {
  return {d.levels_m[1] + 15e-9, d.levels_m[2] - 20e-9, d.levels_m[3] + 20e-9, cfg.sensor_distance_m * 1.016, 0.3 * cfg.pitch_m,
          -0.2 * cfg.pitch_m};
}

// Additive Gaussian noise of sigma = rel x the band's peak, per pixel (seeded).
RealStack noisy(const RealStack& p, double rel, unsigned seed) {
  RealStack out = p;
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> n(0.0, 1.0);
  const std::size_t plane = p.rows * p.cols;
  for (std::size_t b = 0; b < p.planes; ++b) {
    double peak = 0;
    for (std::size_t i = 0; i < plane; ++i) peak = std::max(peak, p.data[b * plane + i]);
    for (std::size_t i = 0; i < plane; ++i) out.data[b * plane + i] += rel * peak * n(rng);
  }
  return out;
}

const FitValue& value(const FitResult& r, const std::string& name) {
  for (const auto& v : r.values)
    if (v.name == name) return v;
  FAIL("no fitted value " << name);
  return r.values.front();
}

double scale_of(const std::string& name, const SystemConfig& cfg) { return name == "dx" || name == "dy" ? cfg.pitch_m : 1.0; }

}  // namespace

TEST_SUITE("fit") {
  TEST_CASE("the adjoint gradient of the fit's loss matches central differences (levels, scale, offset, shift; z, d)") {
    const SystemConfig cfg = fit_config();
    const Design d = quantized_lens(cfg);
    const RealStack meas = [&] {
      AsBuiltModel m(runtime(), cfg, Precision::F64, d, {"levels", "z", "offset"});
      return noisy(m.evaluate(truth(cfg, d)), 0.01, 5);
    }();
    struct Case {
      std::vector<std::string> params;
      std::vector<double> at;  // offsets from the design values, in each parameter's unit (pixels for dx, dy)
    };
    // Away from integer shifts (the bilinear shift's kinks).
    const std::vector<Case> cases = {{{"levels", "z", "d", "offset", "shift"}, {7e-9, -4e-9, 3e-9, 2e-5, 0.01, 0.37, -0.21, 0.23, -0.31}},
                                     {{"masks", "offset"}, {0, 0, 0.41, 0.13}},
                                     {{"scale", "shift"}, {0.01, -0.27, 0.45}}};
    for (const auto& c : cases) {
      CAPTURE(c.params.front());
      Design dd = d;
      if (c.params.front() == "scale") dd.levels_m.clear();
      AsBuiltModel m(runtime(), cfg, Precision::F64, dd, c.params);
      std::vector<double> th = m.design_values();
      REQUIRE(th.size() == c.at.size());
      for (std::size_t k = 0; k < th.size(); ++k) th[k] += c.at[k] * scale_of(m.parameter_names()[k], cfg);
      check_fit_gradient(m, th, meas, [&](const std::string& name, double v) {
        return name == "z" || name == "d"       ? 1e-4 * v
               : name == "scale"                ? 1e-5
               : name == "sx" || name == "sy"   ? 1e-4
               : name == "dx" || name == "dy"   ? 1e-4 * cfg.pitch_m
                                                : 2e-11;
      });
    }
  }

  TEST_CASE("without noise the fit recovers levels, z and offset tightly") {
    const SystemConfig cfg = fit_config();
    const Design d = quantized_lens(cfg);
    const auto t = truth(cfg, d);
    AsBuiltModel m(runtime(), cfg, Precision::F64, d, {"levels", "z", "offset"});
    const RealStack meas = m.evaluate(t);
    FitOptions opt;
    opt.parameters = {"levels", "z", "offset"};
    opt.max_iterations = 40;
    const FitResult r = fit_as_built(runtime(), cfg, Precision::F64, d, meas, opt);
    REQUIRE(r.values.size() == t.size());
    CHECK(r.loss_final < 1e-6 * r.loss_design);
    for (std::size_t k = 0; k < t.size(); ++k) {
      const FitValue& v = r.values[k];
      CAPTURE(v.name);
      INFO("fitted " << v.value << ", true " << v.value << " (design " << v.design << ")");
      if (v.name == "z")
        CHECK(std::fabs(v.value - t[k]) < 1e-4 * t[k]);
      else if (v.name == "dx" || v.name == "dy")
        CHECK(std::fabs(v.value - t[k]) < 1e-3 * cfg.pitch_m);
      else
        CHECK(std::fabs(v.value - t[k]) < 0.1e-9);
    }
    // The as-built outputs: the fitted level table and geometry.
    REQUIRE(r.as_built.levels_m.size() == 4);
    CHECK(std::fabs(r.as_built.levels_m[2] - t[1]) < 0.1e-9);
    CHECK(r.as_built.levels_m[0] == d.levels_m[0]);  // held: a piston
    CHECK(std::fabs(r.as_built_config.sensor_distance_m - t[3]) < 1e-4 * t[3]);
    CHECK(r.as_built_config.scene_distance_m == cfg.scene_distance_m);
    CHECK(r.residual_rel_fit.size() == cfg.bands);
    // The start and one entry per accepted step (a last iteration that finds no lower loss adds none), never rising.
    CHECK(r.loss_history.size() >= std::size_t(r.iterations));
    CHECK(r.loss_history.size() <= std::size_t(r.iterations) + 1);
    for (std::size_t k = 1; k < r.loss_history.size(); ++k) CHECK(r.loss_history[k] < r.loss_history[k - 1]);
  }

  TEST_CASE("lateral starts: from the offset's mirror start the grid finds the true basin; start values are taken") {
    const SystemConfig cfg = fit_config();
    const Design d = quantized_lens(cfg);
    const auto t = truth(cfg, d);
    AsBuiltModel m(runtime(), cfg, Precision::F64, d, {"levels", "z", "offset"});
    const RealStack meas = m.evaluate(t);
    FitOptions opt;
    opt.parameters = {"levels", "z", "offset"};
    opt.max_iterations = 40;
    // The relief offset's blur is even in the offset: start at the mirror of the truth. (This lens's
    // compact PSF leads even that start home; the speckled PSF of a trained DOE does not, which is
    // what the grid is for: EXPERIMENTS.md "The built camera, in simulation". Here: the grid
    // search ends in the true basin and a given start is the fit's first point.)
    opt.start = {{"dx", -t[4]}, {"dy", -t[5]}};
    opt.lateral_starts = 1;  // the given start alone
    opt.max_iterations = 1;
    std::vector<std::string> lines;
    opt.progress = [&](const std::string& l) { lines.push_back(l); };
    const FitResult one = fit_as_built(runtime(), cfg, Precision::F64, d, meas, opt);
    std::vector<double> start = m.design_values();
    start[4] = -t[4];
    start[5] = -t[5];
    CHECK(one.loss_initial == doctest::Approx(m.loss(start, meas)).epsilon(1e-9));  // the start taken
    opt.max_iterations = 40;
    opt.progress = {};
    const FitResult mirror = fit_as_built(runtime(), cfg, Precision::F64, d, meas, opt);
    opt.lateral_starts = 7;
    const FitResult grid = fit_as_built(runtime(), cfg, Precision::F64, d, meas, opt);
    INFO("mirror start: dx " << value(mirror, "dx").value / cfg.pitch_m << " px, loss " << mirror.loss_final << "; grid: dx "
                             << value(grid, "dx").value / cfg.pitch_m << " px, loss " << grid.loss_final << " (true " << t[4] / cfg.pitch_m << ")");
    CHECK(grid.loss_final < 1e-6 * grid.loss_design);
    CHECK(std::fabs(value(grid, "dx").value - t[4]) < 1e-3 * cfg.pitch_m);
    CHECK(std::fabs(value(grid, "dy").value - t[5]) < 1e-3 * cfg.pitch_m);
    CHECK(grid.loss_final <= std::max(mirror.loss_final, 1e-12 * grid.loss_design));  // (both may end at rounding)
    // An unknown start name is refused naming it.
    opt.start = {{"dz", 0.0}};
    CHECK_THROWS_WITH_AS(fit_as_built(runtime(), cfg, Precision::F64, d, meas, opt), doctest::Contains("dz"), InputError);
  }

  TEST_CASE("a trained DOE's speckled PSF: the default starts and the centroid start alone both find the truth") {
    // The small preset's system with 8 bands over 400 .. 680 nm; the as-built truth: etch errors
    // of the tolerance study's size on the levels, z 1.6 % long, the relief moved by (3.1, -2.9) um
    // (0.78 and 0.73 DOE px: whole pixels in the map, the rest as the optical axis moved).
    SystemConfig cfg = preset_config("small");
    cfg.bands = 8;
    cfg.wavelength_step_nm = 40;
    cfg.validate();
    const Design d = trained_design(cfg);
    const std::vector<double> t = {d.levels_m[1] + 13.3e-9, d.levels_m[2] - 1.0e-9, d.levels_m[3] + 16.6e-9, cfg.sensor_distance_m * 1.016,
                                   3.1e-6, -2.9e-6};
    AsBuiltModel m(runtime(), cfg, Precision::F64, d, {"levels", "z", "offset"});
    const RealStack meas = m.evaluate(t);
    FitOptions opt;
    opt.parameters = {"levels", "z", "offset"};
    const FitResult r = fit_as_built(runtime(), cfg, Precision::F64, d, meas, opt);  // the defaults
    REQUIRE(r.values.size() == t.size());
    CHECK(r.converged);
    CHECK(r.loss_final < 1e-8 * r.loss_design);
    for (std::size_t k = 0; k < t.size(); ++k) {
      CAPTURE(r.values[k].name);
      INFO("fitted " << r.values[k].value << ", true " << t[k]);
      if (r.values[k].name == "z")
        CHECK(std::fabs(r.values[k].value - t[k]) < 1e-5 * t[k]);
      else if (r.values[k].name == "dx" || r.values[k].name == "dy")
        CHECK(std::fabs(r.values[k].value - t[k]) < 1e-9);
      else
        CHECK(std::fabs(r.values[k].value - t[k]) < 0.05e-9);
    }
    // A relief moved exactly has no blur that repeats with the offset's fraction of a pixel (the
    // bilinear blend of heights had: narrow minima, one per fraction, from which the centroid
    // start alone converged elsewhere): from the centroid start alone the fit finds the truth too.
    opt.lateral_starts = 1;
    const FitResult one = fit_as_built(runtime(), cfg, Precision::F64, d, meas, opt);
    INFO("centroid start alone: dx " << value(one, "dx").value << ", dy " << value(one, "dy").value << ", loss " << one.loss_final);
    CHECK(std::hypot(value(one, "dx").value - t[4], value(one, "dy").value - t[5]) < 1e-9);
    CHECK(one.loss_final < 1e-8 * one.loss_design);
  }

  TEST_CASE("with noise (sigma = 0.1 % of each band's peak per pixel) the recovery is within 4 reported sigmas, the sigmas bounded") {
    const SystemConfig cfg = fit_config();
    const Design d = quantized_lens(cfg);
    const auto t = truth(cfg, d);
    AsBuiltModel m(runtime(), cfg, Precision::F64, d, {"levels", "z", "offset"});
    const RealStack meas = noisy(m.evaluate(t), 1e-3, 11);
    FitOptions opt;
    opt.parameters = {"levels", "z", "offset"};
    const FitResult r = fit_as_built(runtime(), cfg, Precision::F64, d, meas, opt);
    // Bounds on the sigmas at this noise (measured on this system: 1.6 .. 2.8 nm on the levels,
    // 0.18 um on z, 2.6 and 5.0 nm on dx and dy): 4 nm on a level, 2e-4 z, 0.005 DOE pixels.
    for (std::size_t k = 0; k < t.size(); ++k) {
      const FitValue& v = r.values[k];
      CAPTURE(v.name);
      INFO("fitted " << v.value << " +- " << v.sigma << ", true " << t[k] << ", design " << v.design);
      CHECK(std::fabs(v.value - t[k]) < 4 * v.sigma);
      if (v.name == "z")
        CHECK(v.sigma < 2e-4 * t[k]);
      else if (v.name == "dx" || v.name == "dy")
        CHECK(v.sigma < 0.005 * cfg.pitch_m);
      else
        CHECK(v.sigma < 4e-9);
      CHECK(std::fabs(v.design - t[k]) > 4 * v.sigma);  // the perturbation is resolved, not within the noise
    }
    // The residual left is the noise: s close to its sigma (the mean of 0.01 x peak over bands).
    const std::size_t plane = meas.rows * meas.cols;
    double noise = 0;
    const RealStack clean = m.evaluate(t);
    for (std::size_t b = 0; b < cfg.bands; ++b) {
      double peak = 0;
      for (std::size_t i = 0; i < plane; ++i) peak = std::max(peak, clean.data[b * plane + i]);
      noise += 1e-6 * peak * peak / double(cfg.bands);
    }
    CHECK(r.residual_sigma == doctest::Approx(std::sqrt(noise)).epsilon(0.05));
    for (std::size_t b = 0; b < cfg.bands; ++b) CHECK(r.residual_rel_fit[b] < r.residual_rel_design[b]);
  }

  TEST_CASE("the jackknife sigma over band groups: about the curvature sigma under noise alone, far above it when the bands disagree") {
    const SystemConfig cfg = fit_config();
    const Design d = quantized_lens(cfg);
    const auto t = truth(cfg, d);
    AsBuiltModel m(runtime(), cfg, Precision::F64, d, {"levels", "z", "offset"});
    FitOptions opt;
    opt.parameters = {"levels", "z", "offset"};
    // Noise alone: both estimate the same spread (8 groups of one band: the jackknife's own
    // scatter is wide, hence the bounds).
    const FitResult noise = fit_as_built(runtime(), cfg, Precision::F64, d, noisy(m.evaluate(t), 1e-3, 11), opt);
    CHECK(noise.jackknife_groups == 8);
    CHECK(noise.sigma_reliable);
    for (const FitValue& v : noise.values) {
      CAPTURE(v.name);
      INFO("sigma " << v.sigma << ", jackknife " << v.sigma_jackknife);
      REQUIRE(std::isfinite(v.sigma_jackknife));
      CHECK(v.sigma_jackknife > 0.2 * v.sigma);
      CHECK(v.sigma_jackknife < 5 * v.sigma);
    }
    // A misfit the model does not have, different between wavelengths: the upper half of the bands
    // measured through levels 12 nm deeper than the lower half's. The fit lands between the two;
    // the curvature sigma (the noise-free residual's) does not cover that, the jackknife does.
    std::vector<double> t2 = t;
    for (std::size_t k = 0; k < 3; ++k) t2[k] += 12e-9;
    RealStack meas = m.evaluate(t);
    const RealStack upper = m.evaluate(t2);
    const std::size_t plane = meas.rows * meas.cols;
    for (std::size_t i = cfg.bands / 2 * plane; i < meas.data.size(); ++i) meas.data[i] = upper.data[i];
    const FitResult split = fit_as_built(runtime(), cfg, Precision::F64, d, meas, opt);
    CHECK_FALSE(split.sigma_reliable);
    INFO(split.sigma_unreliable_because);
    CHECK(split.sigma_unreliable_because.find("jackknife") != std::string::npos);
    CHECK(split.sigma_unreliable_because.find("level1") != std::string::npos);
    CHECK(split.sigma_unreliable_because.find("chi^2") == std::string::npos);  // a stack's residuals are not in noise units
    for (std::size_t k = 0; k < 3; ++k) {
      const FitValue& v = split.values[k];
      CAPTURE(v.name);
      INFO("fitted " << v.value << " +- " << v.sigma << " (jackknife " << v.sigma_jackknife << "), lower bands' " << t[k] << ", upper's " << t2[k]);
      CHECK(v.sigma_jackknife > 3 * v.sigma);
      // The fit is a compromise: within the two halves' levels, widened by 3 jackknife sigmas. Where
      // in that span it lands the misfit decides (z takes part of it: here the levels land nearer
      // the lower half's), so no sigma of one fit covers the disagreement itself.
      CHECK(v.value > std::min(t[k], t2[k]) - 3 * v.sigma_jackknife);
      CHECK(v.value < std::max(t[k], t2[k]) + 3 * v.sigma_jackknife);
    }
    // z absorbs part of the disagreement: it leaves its truth by far more than its curvature sigma.
    CHECK(std::fabs(split.values[3].value - t[3]) > 3 * split.values[3].sigma);
    // None with jackknife_groups < 2.
    opt.jackknife_groups = 1;
    const FitResult none = fit_as_built(runtime(), cfg, Precision::F64, d, meas, opt);
    CHECK(none.jackknife_groups == 0);
    CHECK(std::isnan(none.values[0].sigma_jackknife));
    CHECK_FALSE(none.sigma_reliable);
  }

  TEST_CASE("mask depths of a qdo+m design are recovered; z and d together are reported as not separable") {
    const SystemConfig cfg = fit_config();
    Design d = quantized_lens(cfg);
    d.levels_m = subset_sum_levels({cfg.h_max_m() / 4, cfg.h_max_m() / 2}, 4);  // the wrapped levels again, as subset sums
    REQUIRE(d.levels_m[3] == doctest::Approx(0.75 * cfg.h_max_m()).epsilon(1e-12));
    {
      AsBuiltModel m(runtime(), cfg, Precision::F64, d, {"masks"});
      const std::vector<double> t = {d.levels_m[1] - 12e-9, d.levels_m[2] + 18e-9};
      FitOptions opt;
      opt.parameters = {"masks"};
      const FitResult r = fit_as_built(runtime(), cfg, Precision::F64, d, m.evaluate(t), opt);
      CHECK(std::fabs(value(r, "mask0").value - t[0]) < 0.1e-9);
      CHECK(std::fabs(value(r, "mask1").value - t[1]) < 0.1e-9);
      CHECK(std::fabs(r.as_built.levels_m[3] - (t[0] + t[1])) < 0.2e-9);
    }
    {
      AsBuiltModel m(runtime(), cfg, Precision::F64, d, {"z"});
      FitOptions opt;
      opt.parameters = {"z", "d"};
      opt.max_iterations = 5;
      const FitResult r = fit_as_built(runtime(), cfg, Precision::F64, d, noisy(m.evaluate({cfg.sensor_distance_m * 1.01}), 0.01, 3), opt);
      REQUIRE(r.correlation.rows() == 2);
      INFO("correlation of z and d: " << r.correlation(0, 1));
      CHECK(std::fabs(r.correlation(0, 1)) > 0.95);
      REQUIRE(r.degenerate.size() == 1);
      CHECK(r.values[r.degenerate[0].first].name == "z");
      CHECK(r.values[r.degenerate[0].second].name == "d");
    }
  }

  TEST_CASE("a level no pixel takes is held; the aperture radius is found by its scan") {
    const SystemConfig cfg = fit_config();
    // The inclusive placement's top level (h_max) is taken by no pixel of a lens for 500 nm.
    Quantizer q;
    q.levels = 4;
    Design d;
    d.height_m = quantize_heights(lens_design(cfg, 500), cfg.h_max_m(), q);
    d.pitch_m = cfg.pitch_m;
    d.levels_m = q.level_heights_m(cfg.h_max_m());
    {
      AsBuiltModel m(runtime(), cfg, Precision::F64, d, {"levels"});
      REQUIRE(m.unused_levels() == std::vector<std::size_t>{3});
      CHECK(m.parameter_names() == std::vector<std::string>{"level1", "level2"});
    }
    // The truth: an aperture of 30 DOE pixels (the configuration's is N/2 - 1 = 31), z off by 1 %.
    AsBuiltModel truth_model(runtime(), cfg, Precision::F64, quantized_lens(cfg), {"z"});
    truth_model.set_aperture_radius(30 * cfg.pitch_m);
    const RealStack meas = truth_model.evaluate({cfg.sensor_distance_m * 1.01});
    FitOptions opt;
    opt.parameters = {"z", "aperture"};
    const FitResult r = fit_as_built(runtime(), cfg, Precision::F64, quantized_lens(cfg), meas, opt);
    const FitValue& a = value(r, "aperture");
    INFO("aperture " << a.value / cfg.pitch_m << " px +- " << a.sigma / cfg.pitch_m << " (design " << a.design / cfg.pitch_m << ")");
    CHECK(a.gradient == "scan");
    CHECK(a.design == doctest::Approx(31 * cfg.pitch_m));
    CHECK(std::fabs(a.value - 30 * cfg.pitch_m) < 0.5 * cfg.pitch_m);
    CHECK(r.as_built_config.aperture_radius_m == a.value);
    CHECK(r.loss_final < 1e-3 * r.loss_design);
    CHECK(r.correlation.rows() == 1);  // the aperture takes no part in it
  }

  TEST_CASE("refusals name the parameter and what is allowed, before any device work") {
    const SystemConfig cfg = fit_config();
    const Design d = quantized_lens(cfg);
    Design unq = d;
    unq.levels_m.clear();
    const auto msg = [&](const Design& dd, const std::vector<std::string>& p) {
      try {
        check_fit_parameters(cfg, dd, p);
      } catch (const InputError& e) {
        return std::string(e.what());
      }
      return std::string("(accepted)");
    };
    CHECK(msg(d, {"levels", "tilt"}).find("'--fit' = tilt") != std::string::npos);
    CHECK(msg(d, {"levels", "levels"}).find("each parameter once") != std::string::npos);
    CHECK(msg(unq, {"levels"}).find("quantized design") != std::string::npos);
    CHECK(msg(d, {"levels", "scale"}).find("degenerate") != std::string::npos);
    CHECK(msg(d, {"masks"}).find("QDO+M") == std::string::npos);  // uniform inclusive 4 levels: 0, h/3, 2h/3, h are subset sums
    Design odd = d;
    odd.levels_m[3] += 50e-9;
    CHECK(msg(odd, {"masks"}).find("QDO+M design") != std::string::npos);
    CHECK(msg(d, {"aperture"}).find("at least one") != std::string::npos);
    SystemConfig inf = cfg;
    inf.scene_at_infinity = true;
    try {
      check_fit_parameters(inf, d, {"z", "d"});
      FAIL("accepted d at infinity");
    } catch (const InputError& e) {
      CHECK(std::string(e.what()).find("infinity") != std::string::npos);
    }
    CHECK(msg(d, {"levels", "z", "offset", "shift", "aperture"}) == "(accepted)");
    // A measured stack of the wrong shape.
    try {
      fit_as_built(runtime(), cfg, Precision::F64, d, RealStack(cfg.bands - 1, 32, 32), {});
      FAIL("accepted a 7-band stack");
    } catch (const InputError& e) {
      CHECK(std::string(e.what()).find("7 x 32 x 32") != std::string::npos);
    }
  }

  TEST_CASE("qdo fit end to end: a perturbed design's PSF file is fitted back; bad input exits 2 naming it") {
    const SystemConfig cfg = fit_config();
    const Design d = quantized_lens(cfg);
    const fs::path dir = temp_dir("fit_cli");
    std::ofstream(dir / "cfg.json") << config_to_json_text(cfg) << "\n";
    write_design((dir / "design.h5").string(), d);
    const auto t = truth(cfg, d);
    // The camera made with a window that samples the transfer function (the configuration's keeps
    // the paper's ratio, which does not): qdo fit's model window by default (--model-padding auto).
    SystemConfig cam = cfg;
    cam.padding_px = sampled_padding_px(cfg, kModelPaddingZMargin * cfg.sensor_distance_m).padding_px;
    REQUIRE(cam.padding_px > cfg.padding_px);
    {
      AsBuiltModel m(runtime(), cam, Precision::F64, d, {"levels", "z", "offset"});
      write_psf((dir / "psf.h5").string(), m.evaluate(t), cfg.wavelengths_nm(), cfg.sensor_pitch_m);
    }
    const std::string base = "fit --config " + (dir / "cfg.json").string() + " --design " + (dir / "design.h5").string();
    const Run ok = qdo_run(base + " --psf " + (dir / "psf.h5").string() + " --out " + (dir / "out").string());
    INFO(ok.out);
    REQUIRE(ok.code == 0);
    // The default starts: scans of the offset, then short fits from starts in different basins.
    CHECK(ok.out.find("lateral starts of dx, dy by scans of each") != std::string::npos);
    CHECK(ok.out.find("fit: start 2 at dx=") != std::string::npos);
    CHECK(ok.out.find("fitted 6 parameters in ") != std::string::npos);
    CHECK(ok.out.find("SIGMA UNRELIABLE") == std::string::npos);  // an exact fit leaves nothing to disagree on
    for (const char* f : {"fit.h5", "fit.json", "design.h5", "config.json", "psf.h5", "fit.png", "residual.png"}) CHECK(fs::exists(dir / "out" / f));
    const auto j = nlohmann::json::parse(slurp(dir / "out" / "fit.json"));
    REQUIRE(j["parameters"].size() == 6);
    CHECK(j["parameters"][0]["name"] == "level1");
    CHECK(j["parameters"][0].contains("sigma_jackknife"));
    CHECK(j["jackknife_groups"] == 8);
    CHECK(j["sigma_reliable"] == true);
    CHECK(ok.out.find("padding_px raised from " + to_str(cfg.padding_px) + " to " + to_str(cam.padding_px)) != std::string::npos);
    CHECK(j["model_padding_px"] == cam.padding_px);
    // The fitted model's sampling: the report `qdo psf` gives for the as-built design and configuration.
    {
      Simulator sim(runtime(), config_from_json_file((dir / "out" / "config.json").string()), Precision::F64);
      sim.set_heights(read_design((dir / "out" / "design.h5").string()).height_m);
      sim.compute_psf();
      REQUIRE(j.contains("model_sampling"));
      CHECK(j["model_sampling"] == sim.sampling().summary());
      CHECK(ok.out.find("the fitted model's " + sim.sampling().summary()) != std::string::npos);
    }
    CHECK(std::fabs(j["parameters"][0]["value"].get<double>() - t[0]) < 0.5e-9);
    CHECK(std::fabs(j["parameters"][3]["value"].get<double>() - t[3]) < 1e-3 * t[3]);
    CHECK(h5_read((dir / "out" / "fit.h5").string(), "/correlation").shape == std::vector<std::size_t>{6, 6});
    CHECK(h5_read((dir / "out" / "fit.h5").string(), "/psf_fit").shape == std::vector<std::size_t>{cfg.bands, 32, 32});
    CHECK(h5_read((dir / "out" / "fit.h5").string(), "/residual_rel_fit").data.size() == cfg.bands);
    // psf.h5: the fitted model in the measurement's window, as qdo psf writes a stack (--psf takes it).
    CHECK(h5_read((dir / "out" / "psf.h5").string(), "/psf_sensor").data == h5_read((dir / "out" / "fit.h5").string(), "/psf_fit").data);
    CHECK(read_psf_stack_file((dir / "out" / "psf.h5").string()).psf_sensor.planes == cfg.bands);
    const Design built = read_design((dir / "out" / "design.h5").string());
    CHECK(std::fabs(built.levels_m[1] - t[0]) < 0.5e-9);
    const SystemConfig built_cfg = config_from_json_file((dir / "out" / "config.json").string());
    CHECK(std::fabs(built_cfg.sensor_distance_m - t[3]) < 1e-3 * t[3]);
    CHECK(built_cfg.padding_px == cam.padding_px);  // the as-built configuration is the fitted model's
    // The as-built design and configuration are taken by the other commands.
    const Run psf = qdo_run("psf --config " + (dir / "out" / "config.json").string() + " --design " + (dir / "out" / "design.h5").string() +
                            " --out " + (dir / "psf_built").string());
    INFO(psf.out);
    CHECK(psf.code == 0);
    // Refusals: exit 2, naming the argument and the value.
    const Run unknown = qdo_run(base + " --psf " + (dir / "psf.h5").string() + " --fit levels,tilt --out " + (dir / "o2").string());
    CHECK(unknown.code == 2);
    CHECK(unknown.out.find("tilt") != std::string::npos);
    CHECK(!fs::exists(dir / "o2"));
    SystemConfig other = cfg;
    other.bands = 5;
    other.wavelength_step_nm = 25;
    std::ofstream(dir / "other.json") << config_to_json_text(other) << "\n";
    const Run grid = qdo_run("fit --config " + (dir / "other.json").string() + " --design " + (dir / "design.h5").string() + " --psf " +
                             (dir / "psf.h5").string() + " --out " + (dir / "o3").string());
    CHECK(grid.code == 2);
    CHECK(grid.out.find("psf.h5") != std::string::npos);
    Design unq = d;
    unq.levels_m.clear();
    write_design((dir / "unq.h5").string(), unq);
    const Run levels = qdo_run("fit --config " + (dir / "cfg.json").string() + " --design " + (dir / "unq.h5").string() + " --psf " +
                               (dir / "psf.h5").string() + " --fit levels,z --out " + (dir / "o4").string());
    CHECK(levels.code == 2);
    CHECK(levels.out.find("quantized design") != std::string::npos);
    // --start in the parameter's own unit, bounded by what a built camera can be; refused before
    // any work, naming --start (not an internal argument), the item and the unit rule.
    const std::string with_psf = base + " --psf " + (dir / "psf.h5").string();
    auto refused = [&](const std::string& extra, const std::string& named, const std::string& out) {
      const Run r = qdo_run(with_psf + " " + extra + " --out " + (dir / out).string());
      CAPTURE(extra);
      CAPTURE(r.out);
      CHECK(r.code == 2);
      CHECK(r.out.find(named) != std::string::npos);
      CHECK(!fs::exists(dir / out / "design.h5"));
    };
    refused("--start dx=1.5,dy=-1.0", "lengths are metres unless suffixed", "s1");  // 1.5 m: beyond the aperture
    refused("--start sx=1e3 --fit levels,z,shift", "sx=1e3: a registration within half", "s2");
    refused("--start z=-0.01", "--start", "s3");
    refused("--start level1=1", "level1=1: a depth in", "s4");
    refused("--start dx=0.1um,dx=0.2um", "given twice", "s5");
    refused("--fit ''", "--fit", "s6");
    refused("--fit ' , '", "--fit", "s7");
    refused("--fit=", "--fit", "s7b");
    refused("--model-padding wide", "--model-padding", "s7c");
    refused("--model-padding 100000", "--model-padding", "s7d");
    // Suffixes are read: 0.1um is 1e-7 m (taken: a fit from there converges to the truth).
    const Run um = qdo_run(with_psf + " --start dx=0.1um,dy=-50nm,z=" + to_str(cfg.sensor_distance_m * 1e3) + "mm --out " + (dir / "s8").string());
    CAPTURE(um.out);
    CHECK(um.code == 0);
    // A fit that ends worse than the design writes no as-built design and fails (exit 3): one
    // iteration from a start far off in dx, taken alone (--lateral-starts 1: with a grid the start
    // is one candidate among others and the lowest wins).
    const double far_um = 0.35 * double(cfg.n) * cfg.pitch_m * 1e6;
    const Run worse = qdo_run(with_psf + " --iterations 1 --lateral-starts 1 --start dx=" + to_str(far_um) + "um,dy=" + to_str(far_um) + "um --out " +
                              (dir / "s9").string());
    CAPTURE(worse.out);
    CHECK(worse.code == 3);
    CHECK(worse.out.find("above the design's own") != std::string::npos);
    CHECK(worse.out.find("NOT CONVERGED") != std::string::npos);
    CHECK(!fs::exists(dir / "s9" / "design.h5"));
    CHECK(!fs::exists(dir / "s9" / "config.json"));
    fs::remove_all(dir);
  }
}
