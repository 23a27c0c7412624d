// The as-built fit as a job (fit_report.hpp): its inputs read and checked, its result written
// and summarised.
#include "qdo/asbuilt/fit_report.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cctype>
#include <cstdarg>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>

#include "qdo/data/figure.hpp"
#include "qdo/data/psf_file.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/physics/psf_source.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/parse.hpp"
#include "qdo/runtime/strprintf.hpp"
#include "qdo/runtime/util.hpp"

namespace qdo {

namespace {

// A value and its sigma in the unit a reader wants: nm for heights, mm for distances, um for offsets.
std::string human(const FitValue& v, double x) {
  char b[64];
  if (v.name == "z" || v.name == "d")
    std::snprintf(b, sizeof b, "%.4f mm", x * 1e3);
  else if (v.name == "dx" || v.name == "dy" || v.name == "aperture" || is_overlay_parameter(v.name))
    std::snprintf(b, sizeof b, "%.3f um", x * 1e6);
  else if (v.unit == "m")
    std::snprintf(b, sizeof b, "%.2f nm", x * 1e9);
  else if (v.unit == "px")
    std::snprintf(b, sizeof b, "%.4f px", x);
  else
    std::snprintf(b, sizeof b, "%.6f", x);
  return b;
}

// One start item NAME=VALUE (name: its NAME), read and bounded as parse_fit_starts says.
double start_value(const SystemConfig& cfg, const Design& design, const std::string& name, const std::string& item,
                   const std::string& argument) {
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
  const double v = parse_double(argument, num) * factor;
  double lo = 0, hi = 0;
  std::string why;
  const double half_aperture = 0.5 * double(cfg.n) * cfg.pitch_m;
  double deepest = 0;
  for (double l : design.levels_m) deepest = std::max(deepest, std::fabs(l));
  for (double h : design.height_m.data) deepest = std::max(deepest, std::fabs(h));
  if (name == "dx" || name == "dy") {
    lo = -half_aperture, hi = half_aperture, why = "the relief's offset within the aperture's half width";
  } else if (is_overlay_parameter(name)) {
    hi = 4 * cfg.pitch_m, lo = -hi, why = "a mask's overlay within 4 DOE pixels";
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
    reject(argument, item,
           why + ", [" + to_str(lo) + ", " + to_str(hi) + "]" + unit + "; it reads as " + shown +
               (px || plain ? std::string() : " (lengths are metres unless suffixed: " + name + "=1.5um, " + name + "=550nm, " + name + "=20mm)"));
  }
  return v;
}

// The shapes the report reads: measured (when given), the fitted and design stacks bands x S x S,
// a residual per band; an InputError naming the array otherwise (a result of another configuration).
void check_report_shapes(const SystemConfig& cfg, const FitResult& r, const RealStack* measured) {
  const std::size_t s = cfg.sensor_size_px();
  const auto check_stack = [&](const char* name, const RealStack& st) {
    if (st.planes != cfg.bands || st.rows != s || st.cols != s)
      reject(name, to_str(st.planes) + " x " + to_str(st.rows) + " x " + to_str(st.cols),
             "the configuration's bands x S x S = " + to_str(cfg.bands) + " x " + to_str(s) + " x " + to_str(s));
  };
  if (measured) check_stack("measured", *measured);
  check_stack("model_psf", r.model_psf);
  check_stack("design_psf", r.design_psf);
  if (r.residual_rel_design.size() != cfg.bands || r.residual_rel_fit.size() != cfg.bands)
    reject("residual_rel_design, residual_rel_fit", to_str(r.residual_rel_design.size()) + ", " + to_str(r.residual_rel_fit.size()),
           "one value per band, " + to_str(cfg.bands) + " each");
}

// The fitted names, comma-separated (fit.h5's and design.h5's "names" / "fit").
std::string joined_names(const FitResult& r) {
  std::string names;
  for (const auto& v : r.values) names += (names.empty() ? "" : ",") + v.name;
  return names;
}

// The correlation p x p, row-major.
std::vector<double> correlation_rows(const FitResult& r) {
  const std::size_t np = r.correlation.rows();
  std::vector<double> corr(np * np);
  for (std::size_t x = 0; x < np; ++x)
    for (std::size_t y = 0; y < np; ++y) corr[x * np + y] = r.correlation(long(x), long(y));
  return corr;
}

void write_fit_h5(const std::string& path, const SystemConfig& cfg, const RealStack& measured, const FitResult& r,
                  const FitSources& sources) {
  const std::size_t np = r.correlation.rows(), nv = r.values.size(), s = cfg.sensor_size_px();
  std::vector<double> vals, sig, sig_jk, des;
  for (const auto& v : r.values) {
    vals.push_back(v.value);
    sig.push_back(std::isfinite(v.sigma) ? v.sigma : -1.0);
    sig_jk.push_back(std::isfinite(v.sigma_jackknife) ? v.sigma_jackknife : -1.0);
    des.push_back(v.design);
  }
  const std::string names = joined_names(r);
  std::vector<H5Dataset> ds;
  ds.push_back({"/value", {nv}, vals, {}, {{"names", names}, {"units", "m, px or 1 per parameter (fit.json)"}}});
  ds.push_back({"/sigma", {nv}, sig, {}, {{"names", names}, {"note", "-1: not determined"}}});
  ds.push_back({"/sigma_jackknife", {nv}, sig_jk, {}, {{"names", names}, {"note", "over band groups; -1: not computed"}}});
  ds.push_back({"/design_value", {nv}, des, {}, {{"names", names}}});
  if (np > 0) ds.push_back({"/correlation", {np, np}, correlation_rows(r), {}, {{"names", names}}});
  ds.push_back({"/wavelengths_nm", {cfg.bands}, cfg.wavelengths_nm(), {}, {{"units", "nm"}}});
  ds.push_back({"/residual_rel_design", {cfg.bands}, r.residual_rel_design, {}, {{"units", "|design - measured| / |measured| per band"}}});
  ds.push_back({"/residual_rel_fit", {cfg.bands}, r.residual_rel_fit, {}, {{"units", "|fit - measured| / |measured| per band"}}});
  ds.push_back({"/loss_history", {r.loss_history.size()}, r.loss_history, {}, {}});
  ds.push_back({"/psf_fit", {cfg.bands, s, s}, r.model_psf.data, {{"pitch_m", cfg.sensor_pitch_m}}, {{"units", "fraction of band energy per sensor pixel"}}});
  ds.push_back({"/psf_measured", {cfg.bands, s, s}, measured.data, {{"pitch_m", cfg.sensor_pitch_m}}, {}});
  ds.push_back({"/psf_design", {cfg.bands, s, s}, r.design_psf.data, {{"pitch_m", cfg.sensor_pitch_m}}, {}});
  if (!r.source_power.empty())
    ds.push_back({"/source_power",
                  {r.source_power.size()},
                  r.source_power,
                  {},
                  {{"units", "full scale per unit of the band's unit-sum PSF at its largest colour"}}});
  h5_write(path, ds,
           {{"config", config_to_json_text(cfg)},
            {"as_built_config", config_to_json_text(r.as_built_config)},
            {"design", sources.design},
            {"psf", sources.psf},
            {"source", "qdo fit"}});
}

// fit.png and residual.png in dir.
void write_fit_figures(const std::string& dir, const SystemConfig& cfg, const RealStack& measured, const FitResult& r) {
  const std::size_t s = cfg.sensor_size_px();
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

}  // namespace

Design read_fit_design(const SystemConfig& cfg, const std::string& spec_in, const std::string& argument) {
  std::string spec = spec_in;
  if (spec.empty()) reject(argument, "(missing)", "the design that was built: a design .h5 file, a run folder, lens:NM or flat");
  if (std::filesystem::is_directory(spec)) spec += "/design.h5";
  Design d;
  d.height_m = design_heights_from_spec(cfg, spec, argument);  // the grid and height checks, naming the file
  d.pitch_m = cfg.pitch_m;
  if (spec != "flat" && spec.rfind("lens:", 0) != 0) d.levels_m = read_design(spec).levels_m;
  return d;
}

FitProblem load_fit_problem(const SystemConfig& cfg, const std::string& design_spec, const std::string& psf_path,
                            const std::vector<std::string>& parameters, const std::string& design_argument,
                            const std::string& psf_argument) {
  FitProblem p;
  p.design = read_fit_design(cfg, design_spec, design_argument);
  p.parameters = parameters.empty() ? default_fit_parameters(p.design) : parameters;
  p.measured = read_psf_stack_for(cfg, psf_path, psf_argument);
  check_fit_parameters(cfg, p.design, p.parameters);  // names, levels without a table, degenerate pairs: before any work
  return p;
}

std::vector<std::string> fit_start_names(const Design& design, const std::vector<std::string>& parameters) {
  std::vector<std::string> allowed;
  for (const auto& pname : parameters) {
    if (pname == "levels")
      for (std::size_t l = 1; l < design.levels_m.size(); ++l) allowed.push_back("level" + std::to_string(l));
    else if (pname == "masks")
      for (int k = 0; (std::size_t(1) << k) < design.levels_m.size(); ++k) allowed.push_back("mask" + std::to_string(k));
    else if (pname == "offset")
      allowed.insert(allowed.end(), {"dx", "dy"});
    else if (pname == "shift")
      allowed.insert(allowed.end(), {"sx", "sy"});
    else if (pname == "overlay") {
      const auto o = overlay_parameter_names(design, parameters);
      allowed.insert(allowed.end(), o.begin(), o.end());
    }
    else if (pname != "aperture")
      allowed.push_back(pname);
  }
  return allowed;
}

std::vector<std::pair<std::string, double>> parse_fit_starts(const SystemConfig& cfg, const Design& design,
                                                             const std::vector<std::string>& parameters, const std::string& text,
                                                             const std::string& argument) {
  const std::vector<std::string> allowed = fit_start_names(design, parameters);
  std::vector<std::pair<std::string, double>> start;
  for (const auto& item : split_items(text)) {
    const auto eq = item.find('=');
    const std::string name = item.substr(0, eq);
    if (eq == std::string::npos || std::find(allowed.begin(), allowed.end(), name) == allowed.end()) {
      std::string all;
      for (const auto& n : allowed) all += (all.empty() ? "" : ", ") + n;
      reject(argument, item, "NAME=VALUE with NAME a fitted parameter (" + all + "), VALUE in metres or with a unit (550nm, 1.5um, 20mm), sensor px (sx, sy) or none (scale)");
    }
    for (const auto& [given, value] : start)
      if (given == name) reject(argument, item, "each name once (" + name + " is given twice)");
    start.push_back({name, start_value(cfg, design, name, item, argument)});
  }
  return start;
}

bool fit_worse_than_design(const FitResult& r) { return !(r.loss_final <= r.loss_design); }

std::string fit_json_text(const SystemConfig& cfg, const FitResult& r, const FitSources& sources, double total_s) {
  const std::size_t np = r.correlation.rows();
  nlohmann::json j;
  j["design"] = sources.design;
  j["psf"] = sources.psf;
  j["parameters"] = nlohmann::json::array();
  for (const auto& v : r.values)
    j["parameters"].push_back({{"name", v.name}, {"unit", v.unit}, {"design", v.design}, {"value", v.value}, {"sigma", v.sigma},
                               {"sigma_jackknife", std::isfinite(v.sigma_jackknife) ? nlohmann::json(v.sigma_jackknife) : nlohmann::json()},
                               {"gradient", v.gradient}});
  const std::vector<double> corr = correlation_rows(r);
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
  j["worse_than_design"] = fit_worse_than_design(r);
  j["loss_history"] = r.loss_history;
  j["levels_m"] = r.as_built.levels_m;
  j["seconds"] = {{"psf", r.times.psf_s}, {"vjp", r.times.vjp_s}, {"jacobian", r.times.jacobian_s}, {"solve", r.times.solve_s},
                  {"aperture_scan", r.times.scan_s}, {"total", total_s}};
  j["counts"] = {{"psf_evaluations", r.times.psf_evaluations}, {"vjps", r.times.vjps}, {"simulators_built", r.times.simulators_built}};
  j["jackknife_groups"] = r.jackknife_groups;
  // Whether the curvature sigma can be read as an error (FitResult::sigma_reliable), and why not.
  j["sigma_reliable"] = r.sigma_reliable;
  if (!r.sigma_unreliable_because.empty()) j["sigma_unreliable_because"] = r.sigma_unreliable_because;
  if (!sources.model_sampling.empty()) j["model_sampling"] = sources.model_sampling;
  j["model_padding_px"] = cfg.padding_px;  // the model's window (qdo fit --model-padding)
  if (!sources.centre_row_col.empty()) {
    j["window_centre_row_col"] = sources.centre_row_col;
    j["window_centre_rule"] = sources.centre_rule;
  }
  j["notes"] = "sigma: 1-sigma from the Gauss-Newton curvature, Cov = s^2 (J^T J)^-1 with s^2 = 2 loss / (m - p), equal weights; "
               "sigma_jackknife: the spread over fits each leaving out one of jackknife_groups groups of contiguous bands "
               "(linearised at the fit), which grows where the model misses what differs between wavelengths; "
               "levels: level 0 held at its design value (a common piston is invisible); oxM, oyM: mask M's own overlay (the "
               "first mask holds the alignment; the offset moves all); z and d by central differences; aperture by a half-pixel scan";
  if (!r.source_power.empty()) {  // the raw frames (fit_raw.hpp)
    j["data"] = "raw frames";
    j["source_power"] = r.source_power;
    j["chi2_reduced"] = r.residual_sigma * r.residual_sigma;
    j["chi2_reduced_passes"] = r.chi2_reduced_passes;
    j["notes"] =
        "data: the raw frames' windows, each usable pixel's residual (a_b G PSF - D) / sqrt(V) with V its "
        "Poisson-Gaussian variance and a_b the band's source power solved in closed form; loss = chi^2 / 2; "
        "sigma: Cov = chi2_reduced (J^T J)^-1 with J the Jacobian of those residuals (the curvature of chi^2 scaled "
        "by the reduced chi^2, 1 when the noise model and the model hold); chi2_reduced_passes: that of each weighting "
        "pass, the first with the shot noise of the signal each pixel's neighbours predict, then of the fitted model's; "
        "residual_rel_*: |weighted residual| / "
        "|weighted data| per band; psf_measured in fit.h5: each usable pixel's D / (a_b G); sigma_jackknife: as for "
        "a stack, over groups of contiguous bands; levels: level 0 held at its design value (a common piston is "
        "invisible); oxM, oyM: mask M's own overlay (the first mask holds the alignment; the offset moves all); z and d by "
        "central differences; aperture by a half-pixel scan";
  }
  return j.dump(2) + "\n";
}

bool write_fit_outputs(const std::string& dir, const SystemConfig& cfg, const RealStack& measured, const FitResult& r,
                       const FitSources& sources, double total_s) {
  check_report_shapes(cfg, r, &measured);
  write_text_atomic(dir + "/fit.json", fit_json_text(cfg, r, sources, total_s));
  write_fit_h5(dir + "/fit.h5", cfg, measured, r, sources);
  // An as-built design that explains the measurement worse than the design itself is no result.
  const bool written = !fit_worse_than_design(r);
  if (written) {
    write_design(dir + "/design.h5", r.as_built,
                 {{"source", "qdo fit"}, {"design", sources.design}, {"psf", sources.psf}, {"fit", joined_names(r)}});
    write_text_atomic(dir + "/config.json", config_to_json_text(r.as_built_config) + "\n");
    // The fitted model as the measurement's window sees it, the registration included (fit.h5's
    // /psf_fit): the PSF a decoder adapted to the camera takes (--psf), on the grid the measurement
    // was taken on, where qdo psf of design.h5 and config.json centres it on the optical axis.
    PsfFile f = psf_file_for(r.as_built_config, SensorStack(r.model_psf));
    f.root_attrs["source"] = "qdo fit: the fitted model in the measurement's window, registration included";
    f.root_attrs["design"] = sources.design;
    f.root_attrs["measured"] = sources.psf;
    if (!sources.centre_row_col.empty()) {  // the frame pixel the window's centre (S/2, S/2) is
      f.root_attrs["centre_row_col"] = sources.centre_row_col;
      f.root_attrs["centre_rule"] = sources.centre_rule;
    }
    write_psf_file(dir + "/psf.h5", std::move(f));
  }
  write_fit_figures(dir, cfg, measured, r);
  return written;
}

std::vector<std::string> fit_summary_lines(const SystemConfig& cfg, const FitResult& r, double fit_s, double writing_s) {
  check_report_shapes(cfg, r, nullptr);
  std::vector<std::string> out;
  const std::size_t np = r.correlation.rows();
  out.push_back(strprintf("fitted %zu parameters in %d iterations (%s) in %.2f s: loss %.4e -> %.4e, residual sigma %.3e per pixel", np,
                          r.iterations, r.converged ? "converged" : "iteration limit", fit_s, r.loss_design, r.loss_final,
                          r.residual_sigma));
  if (!r.source_power.empty())
    out.push_back(strprintf(
        "data: raw frames, each pixel weighted by its Poisson-Gaussian variance; reduced chi^2 %.4f (1 when the "
        "noise model and the model hold; the sigmas are scaled by it)",
        r.residual_sigma * r.residual_sigma));
  for (const auto& v : r.values) {
    const std::string jk = std::isfinite(v.sigma_jackknife) ? ", jackknife +- " + human(v, v.sigma_jackknife) : std::string();
    out.push_back(strprintf("  %-9s %s +- %s (design %s; %s%s)", v.name.c_str(), human(v, v.value).c_str(),
                            std::isfinite(v.sigma) ? human(v, v.sigma).c_str() : "undetermined", human(v, v.design).c_str(),
                            v.gradient.c_str(), jk.c_str()));
  }
  if (!r.sigma_reliable && !r.sigma_unreliable_because.empty())
    out.push_back("note: SIGMA UNRELIABLE: " + r.sigma_unreliable_because +
                  "; the curvature sigma does not bound the error, and the jackknife sigma is a lower bound on it "
                  "(fit.json sigma_reliable)");
  for (const auto& d : r.degenerate)
    out.push_back(strprintf("  not separable: %s and %s (correlation %+.4f)", r.values[d.first].name.c_str(),
                            r.values[d.second].name.c_str(), r.correlation(long(d.first), long(d.second))));
  double rd = 0, rf = 0;
  for (std::size_t b = 0; b < cfg.bands; ++b) {
    rd += r.residual_rel_design[b] / double(cfg.bands);
    rf += r.residual_rel_fit[b] / double(cfg.bands);
  }
  out.push_back(strprintf("mean relative residual per band: design %.4f, fit %.4f", rd, rf));
  out.push_back(strprintf("time: PSF %.2f s, adjoint %.2f s, Jacobian %.2f s, solve %.3f s, aperture scan %.2f s, writing %.2f s "
                          "(%ld PSF evaluations, %ld adjoints, %ld simulators)",
                          r.times.psf_s, r.times.vjp_s, r.times.jacobian_s, r.times.solve_s, r.times.scan_s, writing_s,
                          r.times.psf_evaluations, r.times.vjps, r.times.simulators_built));
  return out;
}

}  // namespace qdo
