// qdo export (lithography mask sets) and qdo tolerance (Monte Carlo over fabrication errors).
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <cstdint>

#include <nlohmann/json.hpp>

#include "cli.hpp"
#include "qdo/data/figure.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/design/design_run.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/fab/fab.hpp"
#include "qdo/data/io.hpp"
#include "qdo/runtime/runtime.hpp"

namespace fs = std::filesystem;
using namespace qdo;
using namespace qdo::cli;

namespace qdo::cli {
namespace {

DesignRunOptions read_run(const std::string& run) {
  return read_run_config(run, "RUN", "a run folder written by qdo design (config.json missing) or a design .h5 file");
}

}  // namespace

int cmd_export(const Args& a) {
  const std::string src = a.positional;
  fab::ExportOptions o;
  o.scheme = fab::scheme_from_string(a.get("scheme"));
  o.out = a.get("out");
  claim_out(a, o.out);
  o.constraints.min_feature_um = parse_double("--min-feature-um", a.get("min-feature-um"), 0, 1e4, "um", true);
  o.constraints.max_levels = parse_int("--max-levels", a.get("max-levels"), 0, 65536);
  o.constraints.max_height_nm = parse_double("--max-height-nm", a.get("max-height-nm"), 0, 1e6, "nm");
  o.constraints.level_tolerance_nm = parse_double("--tolerance-nm", a.get("tolerance-nm"), 0, 1e3, "nm");
  o.dose_curve_csv = a.get("dose-curve");
  SystemConfig cfg;
  Design d;
  if (fs::is_directory(src)) {
    if (a.has("preset") || a.has("config")) reject("--preset", "(given)", "omitted with a run folder (its config.json is used)");
    const DesignRunOptions r = read_run(src);
    cfg = r.cfg;
    d = RunFolder(src).design();
    o.provenance = {{"source", src + "/design.h5"}, {"run", src}, {"mode", to_string(r.design.mode)},
                    {"levels", std::to_string(r.design.quantizer.levels)}, {"placement", to_string(r.design.quantizer.placement)},
                    {"objective", to_string(r.objective)}, {"seed", std::to_string(r.design.seed)}};
  } else {
    if (!fs::exists(src)) reject("RUN", src, "an existing run folder or design .h5 file");
    cfg = load_config(a);
    d = read_design(src);
    if (d.height_m.rows != cfg.n)
      reject("DESIGN", src, "a height map of N x N = " + std::to_string(cfg.n) + " samples as configured (the file has " +
                                std::to_string(d.height_m.rows) + "; pass --preset or --config)");
    if (std::fabs(d.pitch_m - cfg.pitch_m) > 1e-6 * cfg.pitch_m)
      reject("DESIGN", src, "pitch_m = " + to_str(cfg.pitch_m) + " as configured (the file has " + to_str(d.pitch_m) + ")");
    o.provenance = {{"source", src}, {"levels", std::to_string(d.levels_m.size())}};
  }
  const fab::ExportResult r = fab::export_design(d, cfg, o);
  std::printf("%s scheme (%s): %zu mask layer(s), blank top %.3f nm, %zu polygons (%zu vertices)\n", fab::to_string(r.plan.scheme).c_str(),
              r.plan.method.c_str(), r.plan.masks.size(), r.plan.top_m * 1e9, r.polygons, r.vertices);
  for (const auto& m : r.plan.masks)
    std::printf("  layer %3d  %-16s etch %9.3f nm%s\n", m.layer, m.name.c_str(), m.etch_depth_m * 1e9,
                r.plan.scheme == fab::Scheme::Greyscale ? (" dose " + to_str(m.relative_dose)).c_str() : "");
  std::printf("read back: level map identical, max height error %.3g nm\nwrote %s/ (", r.max_height_error_nm, o.out.c_str());
  for (std::size_t k = 0; k < r.files.size(); ++k) std::printf("%s%s", k ? " " : "", r.files[k].c_str());
  std::printf(")\n");
  return 0;
}

int cmd_tolerance(const Args& a) {
  fab::ToleranceOptions t;
  t.run = a.positional;
  t.etch_depth_error_m = parse_double("--etch-depth-error-nm", a.get("etch-depth-error-nm"), 0, 1e4, "nm") * 1e-9;
  t.overlay_m = parse_double("--overlay-um", a.get("overlay-um"), 0, 1e3, "um") * 1e-6;
  t.edge_blur_m = parse_double("--edge-blur-um", a.get("edge-blur-um"), 0, 1e3, "um") * 1e-6;
  t.height_noise_m = parse_double("--height-noise-nm", a.get("height-noise-nm"), 0, 1e4, "nm") * 1e-9;
  t.trials = std::size_t(parse_int("--trials", a.get("trials"), 1, 100000));
  t.seed = std::uint64_t(parse_int("--seed", a.get("seed"), 0, 2147483647));
  t.scheme = a.get("scheme");
  if (t.scheme != "auto") fab::scheme_from_string(t.scheme);
  t.oversample = std::size_t(parse_int("--oversample", a.get("oversample"), 1, 16));
  t.per_source = !a.has("no-per-source");
  t.save_psfs = a.has("save-psfs");
  t.data = scene_paths(a, "data");
  t.synthetic_scenes = std::size_t(parse_int("--synthetic-scenes", a.get("synthetic-scenes"), 1, 100000));
  t.noise_sigma = a.has("noise-sigma") ? parse_double("--noise-sigma", a.get("noise-sigma"), 0, 10, "(units of full scale)") : -1;
  t.precision = precision_from_string(a.get("precision"));
  t.out = a.get("out");
  claim_out(a, t.out);
  t.quiet = false;
  Runtime rt(a.get("device"));
  const auto t0 = std::chrono::steady_clock::now();
  const fab::ToleranceResult r = fab::tolerance_analysis(rt, t);
  std::printf("scheme %s, %zu mask layer(s); nominal PSNR %.3f dB, SSIM %.4f\n", fab::to_string(r.plan.scheme).c_str(),
              r.plan.masks.size(), r.nominal.psnr, r.nominal.ssim);
  std::printf("%-13s %6s %10s %8s %10s %10s | %10s %10s  (nominal decoder)\n", "scenario", "trials", "PSNR mean", "std", "worst",
              "SSIM mean", "PSNR mean", "worst");
  for (const auto& s : r.summary) {
    const auto& p = s.calibrated.at("psnr_db");
    const auto& q = s.calibrated.at("ssim");
    const auto& pn = s.nominal_decoder.at("psnr_db");
    std::printf("%-13s %6zu %10.3f %8.3f %10.3f %10.4f | %10.3f %10.3f\n", s.scenario.c_str(), s.trials, p.mean, p.std, p.min, q.mean,
                pn.mean, pn.min);
  }
  std::printf("%.1f s; wrote %s/ (tolerance.csv tolerance.json tolerance.md psnr_by_scenario.png worst_height_error.png worst_psf.png)\n",
              seconds_since(t0), t.out.c_str());
  return 0;
}

}  // namespace qdo::cli

namespace qdo::cli {

// qdo fabricate: one camera as built (fab.hpp: fabricate) -> DIR/design.h5 (the fabricated
// relief), config.json (the as-built geometry), truth.json (every error drawn and the realised
// level heights, in qdo fit's parameter names), heights.png and height_error.png.
int cmd_fabricate(const Args& a) {
  const std::string src = a.positional;
  fab::AsBuiltOptions o;
  o.scheme = a.get("scheme");
  if (o.scheme != "auto") (void)fab::scheme_from_string(o.scheme);
  o.etch_depth_error_m = parse_double("--etch-depth-error-nm", a.get("etch-depth-error-nm"), 0, 1e4, "nm") * 1e-9;
  o.overlay_m = parse_double("--overlay-um", a.get("overlay-um"), 0, 1e3, "um") * 1e-6;
  o.edge_blur_m = parse_double("--edge-blur-um", a.get("edge-blur-um"), 0, 1e3, "um") * 1e-6;
  o.seed = std::uint64_t(parse_int("--seed", a.get("seed"), 0, 2147483647));
  o.trial = std::size_t(parse_int("--trial", a.get("trial"), 0, 100000));
  o.oversample = std::size_t(parse_int("--oversample", a.get("oversample"), 1, 16));
  {
    const std::string off = a.get("offset-um");
    const auto comma = off.find(',');
    if (comma == std::string::npos) reject("--offset-um", off, "DX,DY in micrometres (x along columns, y along rows)");
    o.offset_x_m = parse_double("--offset-um", off.substr(0, comma), -1e4, 1e4, "um") * 1e-6;
    o.offset_y_m = parse_double("--offset-um", off.substr(comma + 1), -1e4, 1e4, "um") * 1e-6;
  }
  o.sensor_distance_error_m = parse_double("--sensor-distance-error-um", a.get("sensor-distance-error-um"), -1e6, 1e6, "um") * 1e-6;
  SystemConfig cfg;
  Design d;
  std::string source = src;
  if (fs::is_directory(src)) {
    if (a.has("preset") || a.has("config")) reject("--preset", "(given)", "omitted with a run folder (its config.json is used)");
    cfg = read_run(src).cfg;
    d = RunFolder(src).design();
    source = src + "/design.h5";
  } else {
    if (!fs::exists(src)) reject("RUN", src, "an existing run folder or design .h5 file");
    cfg = load_config(a);
    d = read_design(src);
  }
  const fab::AsBuiltCamera cam = fab::fabricate(d, cfg, o);  // every check before any file is written
  const std::string dir = a.get("out");
  claim_out(a, dir);

  nlohmann::json t;
  t["source"] = source;
  t["scheme"] = cam.scheme_note;
  t["seed"] = o.seed;
  t["trial"] = o.trial;
  t["etch_depth_error_nm_bound"] = o.etch_depth_error_m * 1e9;
  t["overlay_um_bound"] = o.overlay_m * 1e6;
  t["edge_blur_um"] = o.edge_blur_m * 1e6;
  for (std::size_t m = 0; m < cam.plan.masks.size(); ++m)
    t["masks"].push_back({{"name", cam.plan.masks[m].name},
                          {"etch_depth_nm", cam.plan.masks[m].etch_depth_m * 1e9},
                          {"depth_error_nm", cam.depth_error_m[m] * 1e9},
                          {"shift_x_um", cam.shift_x_m[m] * 1e6},
                          {"shift_y_um", cam.shift_y_m[m] * 1e6}});
  // In qdo fit's names: level l (l >= 1) relative to level 0 placed at its design height (a piston
  // is invisible), the relief's offset, z.
  nlohmann::json fit_names;
  const double l0_design = cam.plan.levels.empty() ? 0.0 : cam.plan.levels[0].height_m;
  for (std::size_t l = 0; l < cam.plan.levels.size(); ++l) {
    t["levels"].push_back({{"index", cam.plan.levels[l].index},
                           {"design_nm", cam.plan.levels[l].height_m * 1e9},
                           {"realised_nm", cam.level_height_m[l] * 1e9},
                           {"pixels", cam.plan.levels[l].pixels}});
    if (l > 0) fit_names["level" + std::to_string(l)] = cam.level_height_m[l] - cam.level_height_m[0] + l0_design;
  }
  fit_names["z"] = cam.cfg.sensor_distance_m;
  fit_names["dx"] = o.offset_x_m;
  fit_names["dy"] = o.offset_y_m;
  t["fit_parameters"] = fit_names;
  t["fit_parameters_note"] =
      "the true values in qdo fit's names and units (m): levelL = realised level L - realised level 0 + design level 0; dx, dy = the "
      "relief's offset applied after the masks (the per-mask overlay shifts come on top and are not in qdo fit's model); z = the "
      "as-built DOE-sensor distance";
  t["sensor_distance_m"] = {{"design", cfg.sensor_distance_m}, {"as_built", cam.cfg.sensor_distance_m}};

  write_design(dir + "/design.h5", cam.design, {{"source", source}, {"made_by", "qdo fabricate"}, {"scheme", cam.scheme_note}});
  write_text_atomic(dir + "/config.json", config_to_json_text(cam.cfg) + "\n");
  write_text_atomic(dir + "/truth.json", t.dump(2) + "\n");
  write_height_figure(dir + "/heights.png", "As-built DOE heights (simulated fabrication)", cam.design.height_m, cam.cfg.pitch_m);
  Map2D err = cam.design.height_m;
  for (std::size_t i = 0; i < err.data.size(); ++i) err.data[i] -= d.height_m.data[i];
  write_height_figure(dir + "/height_error.png", "As-built minus designed heights", err, cam.cfg.pitch_m, "height error (nm)");

  std::printf("fabricated %s (%s): %zu mask(s)\n", source.c_str(), cam.scheme_note.c_str(), cam.plan.masks.size());
  for (std::size_t m = 0; m < cam.plan.masks.size(); ++m)
    std::printf("  %-16s etch %9.3f nm  error %+7.3f nm  overlay (%+.3f, %+.3f) um\n", cam.plan.masks[m].name.c_str(),
                cam.plan.masks[m].etch_depth_m * 1e9, cam.depth_error_m[m] * 1e9, cam.shift_x_m[m] * 1e6, cam.shift_y_m[m] * 1e6);
  for (std::size_t l = 0; l < cam.plan.levels.size(); ++l)
    std::printf("  level %zu: design %9.3f nm, realised %9.3f nm\n", l, cam.plan.levels[l].height_m * 1e9, cam.level_height_m[l] * 1e9);
  std::printf("relief offset (%+.3f, %+.3f) um, DOE-sensor distance %.6f -> %.6f m\nwrote %s/ (design.h5 config.json truth.json heights.png "
              "height_error.png)\n",
              o.offset_x_m * 1e6, o.offset_y_m * 1e6, cfg.sensor_distance_m, cam.cfg.sensor_distance_m, dir.c_str());
  return 0;
}

}  // namespace qdo::cli
