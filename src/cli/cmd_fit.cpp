// qdo fit: the as-built DOE (fit.hpp) from a design and a measured PSF stack -> DIR/fit.h5,
// fit.json, design.h5 (the as-built relief), config.json (the as-built geometry), fit.png
// (measured, fitted and design PSF per band) and residual.png (relative residual per band).
#include <nlohmann/json.hpp>

#include <chrono>
#include <cmath>
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>

#include "cli.hpp"
#include "qdo/data/figure.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/design/fit.hpp"
#include "qdo/data/io.hpp"
#include "qdo/physics/psf_source.hpp"
#include "qdo/design/run.hpp"
#include "qdo/runtime/runtime.hpp"

namespace qdo::cli {

namespace {

// --design: a design .h5 file (its level table kept), a run folder (its design.h5), lens:NM or
// flat (no level table). Checked against the configuration's grid and height range (load_design).
Design fit_design(const SystemConfig& cfg, const Args& a) {
  std::string spec = a.get("design");
  if (spec.empty()) reject("--design", "(missing)", "the design that was built: a design .h5 file, a run folder, lens:NM or flat");
  if (std::filesystem::is_directory(spec)) spec += "/design.h5";
  Design d;
  d.height_m = load_design(cfg, spec);  // the grid and height checks, naming the file
  d.pitch_m = cfg.pitch_m;
  if (spec != "flat" && spec.rfind("lens:", 0) != 0) d.levels_m = read_design(spec).levels_m;
  return d;
}

// A value and its sigma in the unit a reader wants: nm for heights, mm for distances, um for offsets.
std::string human(const FitValue& v, double x) {
  char b[64];
  if (v.name == "z" || v.name == "d")
    std::snprintf(b, sizeof b, "%.4f mm", x * 1e3);
  else if (v.name == "dx" || v.name == "dy" || v.name == "aperture")
    std::snprintf(b, sizeof b, "%.3f um", x * 1e6);
  else if (v.unit == "m")
    std::snprintf(b, sizeof b, "%.2f nm", x * 1e9);
  else if (v.unit == "px")
    std::snprintf(b, sizeof b, "%.4f px", x);
  else
    std::snprintf(b, sizeof b, "%.6f", x);
  return b;
}

// One --start item NAME=VALUE in the parameter's own unit, checked against what a built camera can
// be: lengths in metres unless suffixed (nm, um, mm, m: `dx=1.5um`, as fabricate --offset-um
// takes them); sx, sy in sensor px (an optional px suffix); scale plain. Bounds: offsets within
// the aperture's half width, shifts within half the sensor window, z and d within a factor 10 of
// the configuration's, level and mask depths within [0, 2 x the design's deepest + 1 um], scale in
// (0, 10]. An InputError names --start, the item, the value read and what is allowed.
double start_value(const SystemConfig& cfg, const Design& design, const std::string& name, const std::string& item) {
  const std::string text = item.substr(item.find('=') + 1);
  const bool px = name == "sx" || name == "sy", plain = name == "scale";
  struct Suffix {
    const char* s;
    double f;
  };
  const Suffix lengths[] = {{"nm", 1e-9}, {"um", 1e-6}, {"\u00b5m", 1e-6}, {"mm", 1e-3}, {"m", 1.0}};
  std::string num = text, unit;
  double factor = 1;
  if (px) {
    if (num.size() > 2 && num.compare(num.size() - 2, 2, "px") == 0) num.resize(num.size() - 2);
    unit = " px";
  } else if (!plain) {
    for (const auto& u : lengths) {
      const std::size_t n = std::strlen(u.s);
      if (num.size() > n && num.compare(num.size() - n, n, u.s) == 0 && (std::isdigit(static_cast<unsigned char>(num[num.size() - n - 1])) || num[num.size() - n - 1] == '.')) {
        num.resize(num.size() - n);
        factor = u.f;
        break;
      }
    }
    unit = " m";
  }
  const double v = parse_double("--start", num) * factor;
  double lo = 0, hi = 0;
  std::string why;
  const double half_aperture = 0.5 * double(cfg.n) * cfg.pitch_m;
  double deepest = 0;
  for (double l : design.levels_m) deepest = std::max(deepest, std::fabs(l));
  for (double h : design.height_m.data) deepest = std::max(deepest, std::fabs(h));
  if (name == "dx" || name == "dy") {
    lo = -half_aperture, hi = half_aperture, why = "the relief's offset within the aperture's half width";
  } else if (px) {
    hi = 0.5 * double(cfg.sensor_size_px()), lo = -hi, why = "a registration within half the " + to_str(cfg.sensor_size_px()) + " px window";
  } else if (name == "z") {
    lo = 0.1 * cfg.sensor_distance_m, hi = 10 * cfg.sensor_distance_m, why = "within a factor 10 of the configuration's sensor_distance_m";
  } else if (name == "d") {
    lo = 0.1 * cfg.scene_distance_m, hi = 10 * cfg.scene_distance_m, why = "within a factor 10 of the configuration's scene_distance_m";
  } else if (plain) {
    lo = 1e-6, hi = 10, why = "a factor on every height, in (0, 10]";
  } else {  // levelK, maskK
    lo = 0, hi = 2 * deepest + 1e-6, why = "a depth in [0, 2 x the design's deepest + 1 um]";
  }
  if (!(v >= lo && v <= hi)) {
    const std::string shown = to_str(v) + unit;
    reject("--start", item,
           why + ", [" + to_str(lo) + ", " + to_str(hi) + "]" + unit + "; it reads as " + shown +
               (px || plain ? std::string() : " (lengths are metres unless suffixed: " + name + "=1.5um, " + name + "=550nm, " + name + "=20mm)"));
  }
  return v;
}

}  // namespace

int cmd_fit(const Args& a) {
  const SystemConfig cfg = load_config(a);
  if (!a.has("psf")) reject("--psf", "(missing)", "the measured PSF stack: psf.h5 as qdo calibrate or qdo psf writes it");
  FitOptions opt;
  if (a.has("fit") && a.get("fit").find_first_not_of(" ,") == std::string::npos)
    reject("--fit", a.get("fit"), "one or more of levels, masks, scale, z, d, offset, shift, aperture (omit --fit for the default set)");
  opt.parameters = split_items(a.get("fit"));
  opt.max_iterations = parse_int("--iterations", a.get("iterations"), 1, 1000);
  opt.tolerance = parse_double("--tolerance", a.get("tolerance"), 0, 1, "", false);
  const Precision p = precision_from_string(a.get("precision"));
  const Design design = fit_design(cfg, a);
  if (opt.parameters.empty()) opt.parameters = default_fit_parameters(design);
  const RealStack measured = read_psf_stack_for(cfg, a.get("psf"), "--psf");
  check_fit_parameters(cfg, design, opt.parameters);  // names, levels without a table, degenerate pairs: before any work
  if (a.get("lateral-starts") == "auto") {
    opt.lateral_starts = 0;
  } else {
    char* end = nullptr;
    const std::string& v = a.get("lateral-starts");
    const long k = std::strtol(v.c_str(), &end, 10);
    if (v.empty() || *end || k < 1 || k > 15) reject("--lateral-starts", v, "auto or an integer in [1, 15]");
    opt.lateral_starts = int(k);
  }
  opt.refine_starts = parse_int("--refine-starts", a.get("refine-starts"), 1, 16);
  if (a.has("start")) {
    // NAME=VALUE,...: the names the fit prints, in metres (levels, masks, z, d, dx, dy) or sensor
    // px (sx, sy) or none (scale); checked against the fitted set before any work.
    std::vector<std::string> allowed;
    for (const auto& pname : opt.parameters) {
      if (pname == "levels")
        for (std::size_t l = 1; l < design.levels_m.size(); ++l) allowed.push_back("level" + std::to_string(l));
      else if (pname == "masks")
        for (int k = 0; (std::size_t(1) << k) < design.levels_m.size(); ++k) allowed.push_back("mask" + std::to_string(k));
      else if (pname == "offset")
        allowed.insert(allowed.end(), {"dx", "dy"});
      else if (pname == "shift")
        allowed.insert(allowed.end(), {"sx", "sy"});
      else if (pname != "aperture")
        allowed.push_back(pname);
    }
    for (const auto& item : split_items(a.get("start"))) {
      const auto eq = item.find('=');
      const std::string name = item.substr(0, eq);
      if (eq == std::string::npos || std::find(allowed.begin(), allowed.end(), name) == allowed.end()) {
        std::string all;
        for (const auto& n : allowed) all += (all.empty() ? "" : ", ") + n;
        reject("--start", item, "NAME=VALUE with NAME a fitted parameter (" + all + "), VALUE in metres or with a unit (550nm, 1.5um, 20mm), sensor px (sx, sy) or none (scale)");
      }
      for (const auto& [given, value] : opt.start)
        if (given == name) reject("--start", item, "each name once (" + name + " is given twice)");
      opt.start.push_back({name, start_value(cfg, design, name, item)});
    }
  }
  const std::string dir = out_dir(a);
  Runtime rt(a.get("device"));
  opt.progress = [](const std::string& l) {
    std::printf("%s\n", l.c_str());
    std::fflush(stdout);
  };
  const auto t0 = std::chrono::steady_clock::now();
  const FitResult r = fit_as_built(rt, cfg, p, design, measured, opt);
  const double fit_s = seconds_since(t0);
  const auto t1 = std::chrono::steady_clock::now();

  // fit.json and fit.h5: the same values.
  const std::size_t np = r.correlation.rows(), nv = r.values.size(), s = cfg.sensor_size_px();
  nlohmann::json j;
  j["design"] = a.get("design");
  j["psf"] = a.get("psf");
  j["parameters"] = nlohmann::json::array();
  std::vector<double> vals, sig, sig_jk, des;
  std::string names;
  for (const auto& v : r.values) {
    j["parameters"].push_back({{"name", v.name}, {"unit", v.unit}, {"design", v.design}, {"value", v.value}, {"sigma", v.sigma},
                               {"sigma_jackknife", std::isfinite(v.sigma_jackknife) ? nlohmann::json(v.sigma_jackknife) : nlohmann::json()},
                               {"gradient", v.gradient}});
    vals.push_back(v.value);
    sig.push_back(std::isfinite(v.sigma) ? v.sigma : -1.0);
    sig_jk.push_back(std::isfinite(v.sigma_jackknife) ? v.sigma_jackknife : -1.0);
    des.push_back(v.design);
    names += (names.empty() ? "" : ",") + v.name;
  }
  std::vector<double> corr(np * np);
  for (std::size_t x = 0; x < np; ++x)
    for (std::size_t y = 0; y < np; ++y) corr[x * np + y] = r.correlation(long(x), long(y));
  j["correlation"] = nlohmann::json::array();
  for (std::size_t x = 0; x < np; ++x)
    j["correlation"].push_back(std::vector<double>(corr.begin() + long(x * np), corr.begin() + long((x + 1) * np)));
  j["degenerate"] = nlohmann::json::array();
  for (const auto& d : r.degenerate)
    j["degenerate"].push_back({{"a", r.values[d.first].name}, {"b", r.values[d.second].name},
                               {"correlation", r.correlation(long(d.first), long(d.second))}});
  j["condition"] = r.condition;
  j["loss_design"] = r.loss_design;
  j["loss_final"] = r.loss_final;
  j["residual_sigma"] = r.residual_sigma;
  j["wavelengths_nm"] = cfg.wavelengths_nm();
  j["residual_rel_design"] = r.residual_rel_design;
  j["residual_rel_fit"] = r.residual_rel_fit;
  j["iterations"] = r.iterations;
  j["converged"] = r.converged;
  j["worse_than_design"] = !(r.loss_final <= r.loss_design);
  j["loss_history"] = r.loss_history;
  j["levels_m"] = r.as_built.levels_m;
  j["seconds"] = {{"psf", r.times.psf_s}, {"vjp", r.times.vjp_s}, {"jacobian", r.times.jacobian_s}, {"solve", r.times.solve_s},
                  {"aperture_scan", r.times.scan_s}, {"total", fit_s}};
  j["counts"] = {{"psf_evaluations", r.times.psf_evaluations}, {"vjps", r.times.vjps}, {"simulators_built", r.times.simulators_built}};
  j["jackknife_groups"] = r.jackknife_groups;
  // Whether the curvature sigma can be read as an error: not when the band groups disagree by more
  // than it allows (the jackknife sigma over 3 x the curvature sigma for some parameter).
  j["sigma_reliable"] = r.sigma_reliable;
  j["notes"] = "sigma: 1-sigma from the Gauss-Newton curvature, Cov = s^2 (J^T J)^-1 with s^2 = 2 loss / (m - p), equal weights; "
               "sigma_jackknife: the spread over fits each leaving out one of jackknife_groups groups of contiguous bands "
               "(linearised at the fit), which grows where the model misses what differs between wavelengths; "
               "levels: level 0 held at its design value (a common piston is invisible); z and d by central differences; "
               "aperture by a half-pixel scan";
  write_text_atomic(dir + "/fit.json", j.dump(2) + "\n");

  std::vector<H5Dataset> ds;
  ds.push_back({"/value", {nv}, vals, {}, {{"names", names}, {"units", "m, px or 1 per parameter (fit.json)"}}});
  ds.push_back({"/sigma", {nv}, sig, {}, {{"names", names}, {"note", "-1: not determined"}}});
  ds.push_back({"/sigma_jackknife", {nv}, sig_jk, {}, {{"names", names}, {"note", "over band groups; -1: not computed"}}});
  ds.push_back({"/design_value", {nv}, des, {}, {{"names", names}}});
  if (np > 0) ds.push_back({"/correlation", {np, np}, corr, {}, {{"names", names}}});
  ds.push_back({"/wavelengths_nm", {cfg.bands}, cfg.wavelengths_nm(), {}, {{"units", "nm"}}});
  ds.push_back({"/residual_rel_design", {cfg.bands}, r.residual_rel_design, {}, {{"units", "|design - measured| / |measured| per band"}}});
  ds.push_back({"/residual_rel_fit", {cfg.bands}, r.residual_rel_fit, {}, {{"units", "|fit - measured| / |measured| per band"}}});
  ds.push_back({"/loss_history", {r.loss_history.size()}, r.loss_history, {}, {}});
  ds.push_back({"/psf_fit", {cfg.bands, s, s}, r.model_psf.data, {{"pitch_m", cfg.sensor_pitch_m}}, {{"units", "fraction of band energy per sensor pixel"}}});
  ds.push_back({"/psf_measured", {cfg.bands, s, s}, measured.data, {{"pitch_m", cfg.sensor_pitch_m}}, {}});
  ds.push_back({"/psf_design", {cfg.bands, s, s}, r.design_psf.data, {{"pitch_m", cfg.sensor_pitch_m}}, {}});
  h5_write(dir + "/fit.h5", ds,
           {{"config", config_to_json_text(cfg)},
            {"as_built_config", config_to_json_text(r.as_built_config)},
            {"design", a.get("design")},
            {"psf", a.get("psf")},
            {"source", "qdo fit"}});
  // An as-built design that explains the measurement worse than the design itself is no result:
  // the command fails (exit 3) and, as on any failure, --out keeps nothing of it.
  const bool worse = !(r.loss_final <= r.loss_design);
  if (!worse) {
    write_design(dir + "/design.h5", r.as_built,
                 {{"source", "qdo fit"}, {"design", a.get("design")}, {"psf", a.get("psf")}, {"fit", names}});
    write_text_atomic(dir + "/config.json", config_to_json_text(r.as_built_config) + "\n");
  }
  // fit.png: for up to 6 bands, evenly spaced, four panels each: measured, fitted, design and
  // |fitted - measured|, each divided by its own maximum (residual.png holds the residuals' sizes).
  const auto w = cfg.wavelengths_nm();
  {
    const std::size_t shown = std::min<std::size_t>(6, cfg.bands);
    RealStack panels(4 * shown, s, s);
    std::vector<std::string> titles;
    const char* what[4] = {"measured", "fitted", "design", "|fit - meas.|"};
    for (std::size_t k = 0; k < shown; ++k) {
      const std::size_t b = shown > 1 ? k * (cfg.bands - 1) / (shown - 1) : 0;
      for (std::size_t i = 0; i < s * s; ++i) {
        const double meas = measured.plane(b)[i], fit = r.model_psf.plane(b)[i];
        panels.plane(4 * k)[i] = std::max(meas, 0.0);
        panels.plane(4 * k + 1)[i] = std::max(fit, 0.0);
        panels.plane(4 * k + 2)[i] = std::max(r.design_psf.plane(b)[i], 0.0);
        panels.plane(4 * k + 3)[i] = std::fabs(fit - meas);
      }
      for (const char* t : what) titles.push_back(std::string(t) + " " + to_str(w[b]) + " nm");
    }
    write_psf_panels(dir + "/fit.png", "Measured, fitted and designed PSFs, and |fitted - measured|", panels, titles,
                     cfg.sensor_pitch_m, std::min<std::size_t>(s, 48));
  }
  {
    LinePlot lp;
    lp.title = "Relative residual ||model - measured|| / ||measured|| per band";
    lp.x_label = "wavelength (nm)";
    lp.y_label = "relative residual";
    const bool per_band = r.residual_rel_design.size() == cfg.bands && r.residual_rel_fit.size() == cfg.bands;
    std::vector<double> x(r.residual_rel_fit.size());
    for (std::size_t i = 0; i < x.size(); ++i) x[i] = per_band ? w[i] : double(i);
    if (!per_band) lp.x_label = "band index";
    lp.series.push_back(PlotSeries{"the design", per_band ? w : std::vector<double>(x), r.residual_rel_design, {}, {}, false});
    lp.series.push_back(PlotSeries{"the fitted as-built design", x, r.residual_rel_fit, {}, {}, false});
    write_line_plot(dir + "/residual.png", lp);
  }
  const double out_s = seconds_since(t1);

  std::printf("fitted %zu parameters in %d iterations (%s) in %.2f s: loss %.4e -> %.4e, residual sigma %.3e per pixel\n", np,
              r.iterations, r.converged ? "converged" : "iteration limit", fit_s, r.loss_design, r.loss_final, r.residual_sigma);
  for (const auto& v : r.values) {
    const std::string jk = std::isfinite(v.sigma_jackknife) ? ", jackknife +- " + human(v, v.sigma_jackknife) : std::string();
    std::printf("  %-9s %s +- %s (design %s; %s%s)\n", v.name.c_str(), human(v, v.value).c_str(),
                std::isfinite(v.sigma) ? human(v, v.sigma).c_str() : "undetermined", human(v, v.design).c_str(), v.gradient.c_str(),
                jk.c_str());
  }
  if (!r.sigma_reliable && r.jackknife_groups >= 2)
    std::printf("note: SIGMA UNRELIABLE: for some parameters the jackknife sigma over %d band groups is more than 3 x the curvature "
                "sigma: the model misses something that differs between wavelengths, and the curvature sigma does not bound the "
                "error; the jackknife sigma is a lower bound on it (fit.json sigma_reliable)\n",
                r.jackknife_groups);
  for (const auto& d : r.degenerate)
    std::printf("  not separable: %s and %s (correlation %+.4f)\n", r.values[d.first].name.c_str(), r.values[d.second].name.c_str(),
                r.correlation(long(d.first), long(d.second)));
  double rd = 0, rf = 0;
  for (std::size_t b = 0; b < cfg.bands; ++b) {
    rd += r.residual_rel_design[b] / double(cfg.bands);
    rf += r.residual_rel_fit[b] / double(cfg.bands);
  }
  std::printf("mean relative residual per band: design %.4f, fit %.4f\n", rd, rf);
  std::printf("time: PSF %.2f s, adjoint %.2f s, Jacobian %.2f s, solve %.3f s, aperture scan %.2f s, writing %.2f s "
              "(%ld PSF evaluations, %ld adjoints, %ld simulators)\n",
              r.times.psf_s, r.times.vjp_s, r.times.jacobian_s, r.times.solve_s, r.times.scan_s, out_s, r.times.psf_evaluations,
              r.times.vjps, r.times.simulators_built);
  if (!r.converged)
    std::fprintf(stderr, "qdo fit: NOT CONVERGED: the iteration limit (--iterations %d) ended the fit; the values and sigmas above "
                         "are not a minimum: raise --iterations, or start elsewhere (--start, --lateral-starts)\n",
                 opt.max_iterations);
  if (worse)
    throw AccuracyError("the fit ended at loss " + to_str(r.loss_final) + ", above the design's own " + to_str(r.loss_design) +
                        ": no as-built design is written (nothing in --out " + a.get("out") + "); start nearer the truth (--start in "
                        "the parameter's unit, e.g. dx=1.5um), raise --iterations or try more starts (--lateral-starts)");
  std::printf("wrote %s/fit.h5, fit.json, design.h5, config.json, fit.png, residual.png\n", dir.c_str());
  return 0;
}

}  // namespace qdo::cli
