// What the fab commands read and report (fab_outputs.hpp): the design they take, the files of one
// camera as built, and the text summaries of export, tolerance and fabricate.
#include "qdo/fab/fab_outputs.hpp"

#include <nlohmann/json.hpp>

#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <filesystem>

#include "qdo/data/figure.hpp"
#include "qdo/design/design_run.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/strprintf.hpp"

namespace qdo::fab {

DesignSource read_design_source(const std::string& src, const std::function<SystemConfig()>& file_config, bool check_grid,
                                const std::string& argument) {
  DesignSource s;
  if (std::filesystem::is_directory(src)) {
    const DesignRunOptions r =
        read_run_config(src, argument, "a run folder written by qdo design (config.json missing) or a design .h5 file");
    s.cfg = r.cfg;
    s.design = RunFolder(src).design();
    s.design_path = src + "/design.h5";
    s.from_run = true;
    s.provenance = {{"source", s.design_path},
                    {"run", src},
                    {"mode", to_string(r.design.mode)},
                    {"levels", std::to_string(r.design.quantizer.levels)},
                    {"placement", to_string(r.design.quantizer.placement)},
                    {"objective", to_string(r.objective)},
                    {"seed", std::to_string(r.design.seed)}};
    return s;
  }
  if (!std::filesystem::exists(src)) reject(argument, src, "an existing run folder or design .h5 file");
  s.cfg = file_config();
  s.design = read_design(src);
  s.design_path = src;
  if (check_grid) {
    const SystemConfig& cfg = s.cfg;
    const Design& d = s.design;
    if (d.height_m.rows != cfg.n)
      reject("DESIGN", src, "a height map of N x N = " + std::to_string(cfg.n) + " samples as configured (the file has " +
                                std::to_string(d.height_m.rows) + "; pass --preset or --config)");
    if (std::fabs(d.pitch_m - cfg.pitch_m) > 1e-6 * cfg.pitch_m)
      reject("DESIGN", src, "pitch_m = " + to_str(cfg.pitch_m) + " as configured (the file has " + to_str(d.pitch_m) + ")");
  }
  s.provenance = {{"source", src}, {"levels", std::to_string(s.design.levels_m.size())}};
  return s;
}

std::string as_built_truth_json_text(const AsBuiltCamera& cam, const SystemConfig& design_cfg, const AsBuiltOptions& o,
                                     const std::string& source) {
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
  // Each mask's overlay after the first, as qdo fit's overlay names it (oxM, oyM for "mask M";
  // its masks are these when the plan is nested, or binary index-coded for a qdo+m design).
  if (cam.plan.scheme != Scheme::Greyscale)
    for (std::size_t m = 1; m < cam.plan.masks.size(); ++m) {
      fit_names["ox" + std::to_string(m + 1)] = cam.shift_x_m[m];
      fit_names["oy" + std::to_string(m + 1)] = cam.shift_y_m[m];
    }
  fit_names["z"] = cam.cfg.sensor_distance_m;
  fit_names["dx"] = o.offset_x_m;
  fit_names["dy"] = o.offset_y_m;
  t["fit_parameters"] = fit_names;
  t["fit_parameters_note"] =
      "the true values in qdo fit's names and units (m): levelL = realised level L - realised level 0 + design level 0; dx, dy = the "
      "relief's offset applied after the masks; oxM, oyM = mask M's own overlay on top of it (qdo fit --fit ...,overlay; the first "
      "mask defines the alignment); z = the as-built DOE-sensor distance";
  t["sensor_distance_m"] = {{"design", design_cfg.sensor_distance_m}, {"as_built", cam.cfg.sensor_distance_m}};
  return t.dump(2) + "\n";
}

void write_as_built_outputs(const std::string& dir, const AsBuiltCamera& cam, const Design& design, const SystemConfig& design_cfg,
                            const AsBuiltOptions& o, const std::string& source) {
  if (design.height_m.data.size() != cam.design.height_m.data.size())
    reject("design", to_str(design.height_m.rows) + " x " + to_str(design.height_m.cols),
           "the design fabricated, " + to_str(cam.design.height_m.rows) + " x " + to_str(cam.design.height_m.cols) + " as built");
  const std::string truth = as_built_truth_json_text(cam, design_cfg, o, source);
  write_design(dir + "/design.h5", cam.design, {{"source", source}, {"made_by", "qdo fabricate"}, {"scheme", cam.scheme_note}});
  write_text_atomic(dir + "/config.json", config_to_json_text(cam.cfg) + "\n");
  write_text_atomic(dir + "/truth.json", truth);
  write_height_figure(dir + "/heights.png", "As-built DOE heights (simulated fabrication)", cam.design.height_m, cam.cfg.pitch_m);
  Map2D err = cam.design.height_m;
  for (std::size_t i = 0; i < err.data.size(); ++i) err.data[i] -= design.height_m.data[i];
  write_height_figure(dir + "/height_error.png", "As-built minus designed heights", err, cam.cfg.pitch_m, "height error (nm)");
}

std::vector<std::string> as_built_summary_lines(const AsBuiltCamera& cam, const SystemConfig& design_cfg, const AsBuiltOptions& o,
                                                const std::string& source) {
  std::vector<std::string> out;
  out.push_back(strprintf("fabricated %s (%s): %zu mask(s)", source.c_str(), cam.scheme_note.c_str(), cam.plan.masks.size()));
  for (std::size_t m = 0; m < cam.plan.masks.size(); ++m)
    out.push_back(strprintf("  %-16s etch %9.3f nm  error %+7.3f nm  overlay (%+.3f, %+.3f) um", cam.plan.masks[m].name.c_str(),
                            cam.plan.masks[m].etch_depth_m * 1e9, cam.depth_error_m[m] * 1e9, cam.shift_x_m[m] * 1e6,
                            cam.shift_y_m[m] * 1e6));
  for (std::size_t l = 0; l < cam.plan.levels.size(); ++l)
    out.push_back(strprintf("  level %zu: design %9.3f nm, realised %9.3f nm", l, cam.plan.levels[l].height_m * 1e9,
                            cam.level_height_m[l] * 1e9));
  out.push_back(strprintf("relief offset (%+.3f, %+.3f) um, DOE-sensor distance %.6f -> %.6f m", o.offset_x_m * 1e6, o.offset_y_m * 1e6,
                          design_cfg.sensor_distance_m, cam.cfg.sensor_distance_m));
  if (cam.cfg.padding_px != design_cfg.padding_px)
    out.push_back(strprintf("model window: padding_px %zu (the design's %zu), so that config.json samples the transfer function "
                            "(--model-padding)", cam.cfg.padding_px, design_cfg.padding_px));
  return out;
}

std::vector<std::string> export_summary_lines(const ExportResult& r) {
  std::vector<std::string> out;
  out.push_back(strprintf("%s scheme (%s): %zu mask layer(s), blank top %.3f nm, %zu polygons (%zu vertices)",
                          to_string(r.plan.scheme).c_str(), r.plan.method.c_str(), r.plan.masks.size(), r.plan.top_m * 1e9, r.polygons,
                          r.vertices));
  for (const auto& m : r.plan.masks)
    out.push_back(strprintf("  layer %3d  %-16s etch %9.3f nm%s", m.layer, m.name.c_str(), m.etch_depth_m * 1e9,
                            r.plan.scheme == Scheme::Greyscale ? (" dose " + to_str(m.relative_dose)).c_str() : ""));
  out.push_back(strprintf("read back: level map identical, max height error %.3g nm", r.max_height_error_nm));
  return out;
}

std::vector<std::string> tolerance_summary_lines(const ToleranceResult& r) {
  std::vector<std::string> out;
  out.push_back(strprintf("scheme %s, %zu mask layer(s); nominal PSNR %.3f dB, SSIM %.4f", to_string(r.plan.scheme).c_str(),
                          r.plan.masks.size(), r.nominal.psnr, r.nominal.ssim));
  out.push_back(strprintf("%-13s %6s %10s %8s %10s %10s | %10s %10s  (nominal decoder)", "scenario", "trials", "PSNR mean", "std", "worst",
                          "SSIM mean", "PSNR mean", "worst"));
  for (const auto& s : r.summary) {
    const auto& p = s.calibrated.at("psnr_db");
    const auto& q = s.calibrated.at("ssim");
    const auto& pn = s.nominal_decoder.at("psnr_db");
    out.push_back(strprintf("%-13s %6zu %10.3f %8.3f %10.3f %10.4f | %10.3f %10.3f", s.scenario.c_str(), s.trials, p.mean, p.std, p.min,
                            q.mean, pn.mean, pn.min));
  }
  return out;
}

}  // namespace qdo::fab
