// qdo fit's overlay (suite `fit-overlay`, include/qdo/asbuilt/fit.hpp: parameter "overlay"): each
// lithography mask's own misplacement. The bilinear shift's derivative matches its differences;
// the relief the fit models for an overlay is the one qdo fabricate makes (fab.hpp: fabricate, rendered on a finer grid and area-averaged; an
// independent code path), for nested and binary masks, shifts below and beyond one DOE pixel; the
// overlay's adjoint gradient matches central differences; from a fabricated camera's noise-free
// PSF stack the fit with the overlay recovers the levels, z, the offset and every mask's overlay,
// where the fit without it bends the levels; overlays on and across whole pixels (the loss's
// kinks) are reached, and a trained DOE's camera needs the tries of each overlay's other cell; the
// offset's differences stay beside a half-pixel switch; refusals name the parameter.
#include <doctest/doctest.h>

#include <random>

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "common.hpp"
#include "fit_common.hpp"
#include "qdo/asbuilt/fit.hpp"
#include "qdo/data/config.hpp"
#include "qdo/fab/fab.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/runtime/error.hpp"

using namespace qdo;
using namespace qdo::test;

namespace {

// The fit's parameter vector (in model's layout) of a fabricated camera: levels (relative to level
// 0 at its design height) or mask depths, z, dx, dy, and each mask's overlay after the first.
std::vector<double> true_theta(const AsBuiltModel& model, const fab::AsBuiltCamera& cam, const Design& d, const SystemConfig& cfg,
                               double dx_m, double dy_m) {
  std::vector<double> th;
  for (const std::string& name : model.parameter_names()) {
    if (name.rfind("level", 0) == 0) {
      const std::size_t l = std::stoul(name.substr(5));
      th.push_back(cam.level_height_m[l] - cam.level_height_m[0] + d.levels_m[0]);
    } else if (name.rfind("mask", 0) == 0) {
      const std::size_t j = std::stoul(name.substr(4));
      th.push_back(cam.plan.masks[j].etch_depth_m + cam.depth_error_m[j]);
    } else if (name == "z") {
      th.push_back(cam.cfg.sensor_distance_m);
    } else if (name == "dx" || name == "dy") {
      th.push_back(name == "dx" ? dx_m : dy_m);
    } else if (name.size() > 2 && name[0] == 'o') {  // oxM, oyM: fab's "mask M" (index M - 1)
      const std::size_t m = std::stoul(name.substr(2)) - 1;
      th.push_back(name[1] == 'x' ? cam.shift_x_m[m] : cam.shift_y_m[m]);
    } else {
      FAIL("unexpected parameter " << name);
    }
  }
  (void)cfg;
  return th;
}

fab::AsBuiltCamera make_camera(const Design& d, const SystemConfig& cfg, const std::string& scheme, double overlay_px, std::uint64_t seed,
                               double dx_px = 0, double dy_px = 0, double dz_rel = 0) {
  fab::AsBuiltOptions o;
  o.scheme = scheme;
  o.etch_depth_error_m = 20e-9;
  o.overlay_m = overlay_px * cfg.pitch_m;
  o.seed = seed;
  o.offset_x_m = dx_px * cfg.pitch_m;
  o.offset_y_m = dy_px * cfg.pitch_m;
  o.sensor_distance_error_m = dz_rel * cfg.sensor_distance_m;
  return fab::fabricate(d, cfg, o);
}

// The as-built camera's sensor PSF stack (bands x S x S), noise-free.
RealStack camera_stack(const fab::AsBuiltCamera& cam) {
  Simulator sim(runtime(), cam.cfg, Precision::F64);
  sim.set_heights(cam.design.height_m);
  sim.compute_psf();
  return sim.psf_sensor();
}

// The fit of levels, z, offset and overlay (40 iterations at most) to a camera's stack, and the
// camera's truth in the fit's layout.
struct OverlayFit {
  FitOptions opt;
  FitResult r;
  std::vector<double> truth;
};
OverlayFit fit_camera(const SystemConfig& cfg, const Design& d, const fab::AsBuiltCamera& cam, const RealStack& meas, double dx_m,
                      double dy_m) {
  OverlayFit f;
  f.opt.parameters = {"levels", "z", "offset", "overlay"};
  f.opt.max_iterations = 40;
  f.r = fit_as_built(runtime(), cfg, Precision::F64, d, meas, f.opt);
  AsBuiltModel names(runtime(), cfg, Precision::F64, d, f.opt.parameters);
  f.truth = true_theta(names, cam, d, cfg, dx_m, dy_m);
  return f;
}

double spread(const std::vector<double>& a, const std::vector<double>& b) {
  double lo = 1e300, hi = -1e300;
  for (std::size_t i = 0; i < a.size(); ++i) {
    lo = std::min(lo, a[i] - b[i]);
    hi = std::max(hi, a[i] - b[i]);
  }
  return hi - lo;
}

}  // namespace

TEST_SUITE("fit-overlay") {
  TEST_CASE("shift_bilinear_derivative: the differences of shift_bilinear inside a pixel cell, the right one at a whole pixel") {
    const std::size_t rows = 7, cols = 9;
    std::vector<double> in(rows * cols);
    for (std::size_t i = 0; i < in.size(); ++i) in[i] = std::sin(0.7 * double(i)) + 0.1 * double(i % 5);
    // The shift is bilinear: linear in sx at fixed sy inside a cell, so a difference inside it is
    // exact to rounding; at a whole pixel only the right difference is.
    for (const auto& [sx, sy] : {std::pair<double, double>{0.3, -1.7}, {-2.45, 0.62}, {1.0, -0.25}, {0.4, 2.0}}) {
      CAPTURE(sx);
      CAPTURE(sy);
      for (int axis : {1, 0}) {
        CAPTURE(axis);
        const double h = 1e-3, s = axis == 1 ? sx : sy;
        const bool whole = s == std::floor(s);
        const auto at = [&](double d) {
          return shift_bilinear(in, 1, rows, cols, axis == 1 ? sx + d : sx, axis == 0 ? sy + d : sy);
        };
        const std::vector<double> g = shift_bilinear_derivative(in, 1, rows, cols, sx, sy, axis);
        const std::vector<double> a = at(h), b = whole ? at(0) : at(-h);
        double worst = 0, size = 0;
        for (std::size_t i = 0; i < g.size(); ++i) {
          worst = std::max(worst, std::fabs(g[i] - (a[i] - b[i]) / (whole ? h : 2 * h)));
          size = std::max(size, std::fabs(g[i]));
        }
        CHECK(size > 0.1);
        CHECK(worst < 1e-10);
      }
    }
    CHECK_THROWS_AS(shift_bilinear_derivative(in, 1, rows, cols, 0, 0, 2), Error);
  }

  TEST_CASE("the overlay's relief is qdo fabricate's: nested and binary masks, shifts below and beyond a DOE pixel") {
    const SystemConfig cfg = fit_config();
    const Design d = quantized_lens(cfg);
    struct Case {
      std::string scheme;
      std::vector<std::string> params;
      double overlay_px;
    };
    bool any_beyond_pixel = false;
    for (const Case& c : {Case{"nested", {"levels", "overlay"}, 0.45}, Case{"nested", {"levels", "overlay"}, 2.5},
                          Case{"binary", {"masks", "overlay"}, 0.45}, Case{"binary", {"masks", "overlay"}, 2.5}}) {
      CAPTURE(c.scheme);
      CAPTURE(c.overlay_px);
      const fab::AsBuiltCamera cam = make_camera(d, cfg, c.scheme, c.overlay_px, 17);
      AsBuiltModel model(runtime(), cfg, Precision::F64, d, c.params);
      // Two masks or more after the first for the nested lens (3 masks), one for the binary set (2 masks).
      const std::size_t masks = cam.plan.masks.size();
      REQUIRE(model.parameter_names().size() == (c.params[0] == "levels" ? 3u : 2u) + 2 * (masks - 1));
      const std::vector<double> th = true_theta(model, cam, d, cfg, 0, 0);
      bool beyond_pixel = false, fractional = false;
      for (std::size_t m = 1; m < masks; ++m)
        for (double s : {cam.shift_x_m[m], cam.shift_y_m[m]}) {
          beyond_pixel = beyond_pixel || std::fabs(s) > cfg.pitch_m;
          fractional = fractional || std::fabs(s / cfg.pitch_m - std::round(s / cfg.pitch_m)) > 0.05;
        }
      CHECK(fractional);
      any_beyond_pixel = any_beyond_pixel || beyond_pixel;
      // The fabricated relief and the fit's differ by one constant (a piston: the fab lifts its
      // lowest height to 0, the fit holds level 0): the same map to rounding.
      const Map2D h = model.heights(th);
      const double s = spread(cam.design.height_m.data, h.data);
      INFO("spread of fabricated - fitted relief " << s << " m");
      CHECK(s < 1e-15);
      // And the overlay matters: at zero overlay the map differs at the masks' edges by up to an etch depth.
      std::vector<double> th0 = th;
      for (std::size_t k = 0; k < th0.size(); ++k)
        if (model.parameter_names()[k][0] == 'o') th0[k] = 0;
      CHECK(spread(cam.design.height_m.data, model.heights(th0).data) > 100e-9);
    }
    CHECK(any_beyond_pixel);
  }

  TEST_CASE("the overlay's adjoint gradient matches central differences (levels and masks, below and beyond a pixel)") {
    const SystemConfig cfg = fit_config();
    const Design d = quantized_lens(cfg);
    const fab::AsBuiltCamera cam = make_camera(d, cfg, "nested", 0.45, 3);
    const RealStack meas = camera_stack(cam);
    struct Case {
      std::vector<std::string> params;
      std::vector<double> overlay_px;  // ox2, oy2, ... in DOE px (kept away from whole pixels, the kinks)
    };
    for (const Case& c : {Case{{"levels", "offset", "overlay"}, {0.21, -0.34, -1.37, 0.62}}, Case{{"masks", "overlay"}, {0.18, 2.41}}}) {
      CAPTURE(c.params.front());
      AsBuiltModel m(runtime(), cfg, Precision::F64, d, c.params);
      std::vector<double> th = m.design_values();
      std::size_t o = 0;
      for (std::size_t k = 0; k < th.size(); ++k) {
        const std::string& name = m.parameter_names()[k];
        if (name[0] == 'o') th[k] = c.overlay_px.at(o++) * cfg.pitch_m;
        if (name == "dx") th[k] = 0.27 * cfg.pitch_m;
        if (name == "dy") th[k] = -0.13 * cfg.pitch_m;
        if (name.rfind("level", 0) == 0 || name.rfind("mask", 0) == 0) th[k] += 5e-9 * double(k + 1);
      }
      REQUIRE(o == c.overlay_px.size());
      check_fit_gradient(m, th, meas,
                         [&](const std::string& name, double) { return name[0] == 'o' || name[0] == 'd' ? 1e-4 * cfg.pitch_m : 2e-11; });
      for (std::size_t k = 0; k < th.size(); ++k)
        if (m.parameter_names()[k][0] == 'o') CHECK(m.adjoint_parameter(k));
    }
  }

  TEST_CASE("from a fabricated camera's noise-free stack the fit with the overlay recovers every parameter; without it the levels bend") {
    const SystemConfig cfg = fit_config();
    const Design d = quantized_lens(cfg);
    const double dx_px = 0.3, dy_px = -0.2;
    const fab::AsBuiltCamera cam = make_camera(d, cfg, "nested", 0.4, 11, dx_px, dy_px, 0.016);
    const RealStack meas = camera_stack(cam);
    const OverlayFit f = fit_camera(cfg, d, cam, meas, dx_px * cfg.pitch_m, dy_px * cfg.pitch_m);
    const FitResult& r = f.r;
    const std::vector<double>& t = f.truth;
    REQUIRE(r.values.size() == t.size());
    CHECK(r.loss_final < 1e-8 * r.loss_design);
    double worst_level_with = 0;
    for (std::size_t k = 0; k < t.size(); ++k) {
      const FitValue& v = r.values[k];
      CAPTURE(v.name);
      INFO("fitted " << v.value << ", true " << t[k] << " (design " << v.design << ")");
      if (v.name == "z")
        CHECK(std::fabs(v.value - t[k]) < 1e-5 * t[k]);
      else if (v.name[0] == 'd' || v.name[0] == 'o')
        CHECK(std::fabs(v.value - t[k]) < 1e-3 * cfg.pitch_m);
      else {
        CHECK(std::fabs(v.value - t[k]) < 0.1e-9);
        worst_level_with = std::max(worst_level_with, std::fabs(v.value - t[k]));
      }
    }
    // The same stack without the overlay in the model: the fit leaves a residual and the levels
    // take the misfit.
    FitOptions without = f.opt;
    without.parameters = {"levels", "z", "offset"};
    const FitResult r0 = fit_as_built(runtime(), cfg, Precision::F64, d, meas, without);
    double worst_level_without = 0;
    for (std::size_t k = 0; k < 3; ++k) worst_level_without = std::max(worst_level_without, std::fabs(r0.values[k].value - t[k]));
    INFO("worst level error with the overlay " << worst_level_with * 1e9 << " nm, without " << worst_level_without * 1e9 << " nm");
    CHECK(r0.loss_final > 1e3 * r.loss_final);
    // It says its sigma is unreliable, and names the overlay as what to add.
    INFO(r0.sigma_unreliable_because);
    CHECK_FALSE(r0.sigma_reliable);
    CHECK(r0.sigma_unreliable_because.find("add overlay to --fit") != std::string::npos);
    CHECK(r.sigma_unreliable_because.find("add overlay") == std::string::npos);
    CHECK(worst_level_without > 1e-9);
    CHECK(worst_level_without > 20 * worst_level_with);
  }

  TEST_CASE("overlays on and across whole DOE pixels: none (the minimum on a kink), either side of one, past -1 px from a start") {
    const SystemConfig cfg = fit_config();
    const Design d = quantized_lens(cfg);
    const std::vector<std::string> params = {"levels", "z", "offset", "overlay"};
    AsBuiltModel model(runtime(), cfg, Precision::F64, d, params);
    REQUIRE(model.parameter_names().size() == 10);
    struct Case {
      double overlay_px[4];  // ox2, oy2, ox3, oy3
      std::vector<std::pair<std::string, double>> start;
    };
    // From the design's start (0, itself a kink): ox2 none, oy2 into the cell left of 0, ox3 right,
    // oy3 a hair left. Then oy2 at -1.3 px from a start at -0.8 px: the step stops at -1 and goes on.
    for (const Case& c : {Case{{0.0, -0.35, 0.3, -0.02}, {}}, Case{{0.05, -1.3, 0.2, 0.0}, {{"oy2", -0.8 * cfg.pitch_m}}}}) {
      CAPTURE(c.overlay_px[1]);
      std::vector<double> t = model.design_values();
      t[0] += 12e-9, t[1] -= 9e-9, t[2] += 15e-9, t[3] *= 1.01, t[4] = 0.3 * cfg.pitch_m, t[5] = -0.2 * cfg.pitch_m;
      for (std::size_t q = 0; q < 4; ++q) t[6 + q] = c.overlay_px[q] * cfg.pitch_m;
      const RealStack meas = model.evaluate(t);
      FitOptions opt;
      opt.parameters = params;
      opt.max_iterations = 40;
      opt.start = c.start;
      const FitResult r = fit_as_built(runtime(), cfg, Precision::F64, d, meas, opt);
      REQUIRE(r.values.size() == t.size());
      CHECK(r.converged);
      CHECK(r.loss_final < 1e-10 * r.loss_design);
      check_recovered(r, t, cfg.pitch_m, 1e-5, 1e-3, 0.1e-9);
    }
  }

  TEST_CASE("a camera without overlay, under noise: the loss's minimum sits on the kinks, and the fit from the design reaches it") {
    // Gaussian noise of 0.3 % of the peak on a stack with every overlay 0: the minimum in an
    // overlay is then often on its kink (both sides rise). The fit from the design's start must end
    // as low as a fit started at the truth (a step on a kink takes the side it goes to, or none).
    const SystemConfig cfg = fit_config();
    const Design d = quantized_lens(cfg);
    const std::vector<std::string> params = {"levels", "z", "offset", "overlay"};
    AsBuiltModel model(runtime(), cfg, Precision::F64, d, params);
    std::vector<double> t = model.design_values();
    t[0] += 12e-9, t[1] -= 9e-9, t[2] += 15e-9, t[3] *= 1.01, t[4] = 0.3 * cfg.pitch_m, t[5] = -0.2 * cfg.pitch_m;
    for (unsigned seed : {1u, 2u, 3u}) {
      CAPTURE(seed);
      RealStack meas = model.evaluate(t);
      std::mt19937_64 rng(seed);
      std::normal_distribution<double> nd(0.0, 1.0);
      const double peak = *std::max_element(meas.data.begin(), meas.data.end());
      for (double& v : meas.data) v += 3e-3 * peak * nd(rng);
      FitOptions opt;
      opt.parameters = params;
      opt.max_iterations = 60;
      const FitResult r = fit_as_built(runtime(), cfg, Precision::F64, d, meas, opt);
      FitOptions from_truth = opt;
      for (std::size_t k = 0; k < t.size(); ++k) from_truth.start.push_back({model.parameter_names()[k], t[k]});
      from_truth.lateral_starts = 1;
      const FitResult rt = fit_as_built(runtime(), cfg, Precision::F64, d, meas, from_truth);
      INFO("loss from the design " << r.loss_final << " (" << r.iterations << " iterations), from the truth " << rt.loss_final);
      CHECK(r.converged);
      CHECK(r.loss_final <= rt.loss_final * (1 + 1e-4));
      for (std::size_t k = 6; k < 10; ++k) CHECK(std::fabs(r.values[k].value) < 0.05 * cfg.pitch_m);
    }
  }

  TEST_CASE("the offset's Jacobian column beside a half-pixel switch is its branch's slope, not the step across the switch") {
    // A truth on a switch (the offset exactly -0.5 DOE px) leaves the fit a hair beside it; a
    // central difference across the switch would measure the step of the sensor window's edge
    // column instead of the slope, and a sigma orders of magnitude too small.
    const SystemConfig cfg = fit_config();
    const Design d = quantized_lens(cfg);
    AsBuiltModel m(runtime(), cfg, Precision::F64, d, {"levels", "offset"});
    std::vector<double> th = m.design_values();
    th[4] = 0.2 * cfg.pitch_m;
    const auto column_norm = [&](double dx_px, bool one_sided) {
      th[3] = dx_px * cfg.pitch_m;
      const RealStack at = m.evaluate(th);
      const Eigen::MatrixXd j = one_sided ? m.jacobian(th, &at) : m.jacobian(th);
      return j.col(3).norm();
    };
    for (bool one_sided : {false, true}) {
      CAPTURE(one_sided);
      const double smooth = column_norm(-0.45, one_sided);  // well inside the branch of 0
      for (double beside : {-0.5002, -0.4998, 0.4998, 0.5002, -0.5}) {
        CAPTURE(beside);
        const double c = column_norm(beside, one_sided);
        INFO("column norm " << c << ", inside the branch " << smooth);
        CHECK(c < 3 * smooth);
        CHECK(c > smooth / 3);
      }
    }
  }

  TEST_CASE("a trained DOE's camera with overlay: the fit tries each overlay's other cell and reaches the truth") {
    // The Section 7 design (speckled PSF) on the small preset with 8 bands, made by qdo fabricate
    // with overlay13's draw of scripts/experiments_fit_raw_sigma.sh (seed 13: etch errors, each
    // mask's overlay within 0.5 um, the relief moved by (0.7, 2.4) um, z 0.5 % long); a noise-free
    // stack. From the start (every overlay 0, a kink) the first steps put two overlays a few
    // hundredths of a pixel on the wrong side, where the loss has another minimum (levels 49 nm off
    // without the tries across); with them the fit ends on the truth.
    SystemConfig cfg = preset_config("small");
    cfg.bands = 8;
    cfg.wavelength_step_nm = 40;
    const Design d = trained_design(cfg);
    const double dx_m = 0.7e-6, dy_m = 2.4e-6;
    const fab::AsBuiltCamera cam = make_camera(d, cfg, "nested", 0.5e-6 / cfg.pitch_m, 13, dx_m / cfg.pitch_m, dy_m / cfg.pitch_m, 0.005);
    const OverlayFit f = fit_camera(cfg, d, cam, camera_stack(cam), dx_m, dy_m);
    const FitResult& r = f.r;
    const std::vector<double>& t = f.truth;
    REQUIRE(r.values.size() == t.size());
    CHECK(r.loss_final < 1e-12 * r.loss_design);
    check_recovered(r, t, cfg.pitch_m, 1e-6, 1e-4, 0.01e-9);
  }

  TEST_CASE("refusals: overlay needs a quantized design with two masks or more; start names and bounds") {
    const SystemConfig cfg = fit_config();
    Design flat = quantized_lens(cfg);
    flat.levels_m.clear();
    CHECK_THROWS_WITH_AS(check_fit_parameters(cfg, flat, {"scale", "overlay"}), doctest::Contains("overlay only for a quantized design"),
                         InputError);
    // Two used levels: one nested mask, nothing to misplace against it.
    Design two = quantized_lens(cfg);
    for (double& h : two.height_m.data) h = h < two.levels_m[2] ? two.levels_m[0] : two.levels_m[3];
    CHECK_THROWS_WITH_AS(check_fit_parameters(cfg, two, {"levels", "overlay"}), doctest::Contains("2 masks or more"), InputError);
    const Design d = quantized_lens(cfg);
    CHECK(overlay_parameter_names(d, {"levels", "overlay"}) == std::vector<std::string>{"ox2", "oy2", "ox3", "oy3"});
    CHECK(overlay_parameter_names(d, {"masks", "overlay"}) == std::vector<std::string>{"ox2", "oy2"});
    CHECK(overlay_parameter_names(d, {"levels"}).empty());
    for (const char* name : {"ox2", "oy3", "ox12"}) CHECK(is_overlay_parameter(name));
    for (const char* name : {"overlay", "oy", "dx", "ox2b", "offset", "level1"}) CHECK_FALSE(is_overlay_parameter(name));
  }
}
