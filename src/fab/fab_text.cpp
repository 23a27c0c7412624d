// The fabrication commands' options read from text, and their reports (fab_text.hpp).
#include "qdo/fab/fab_text.hpp"

#include <filesystem>

#include "qdo/design/option_inputs.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/strprintf.hpp"
#include "qdo/runtime/util.hpp"

namespace qdo::fab {

DesignSource design_source_from_options(const std::string& src, const TextOptions& a, bool check_grid) {
  if (std::filesystem::is_directory(src) && (a.has("preset") || a.has("config")))
    reject("--preset", "(given)", "omitted with a run folder (its config.json is used)");
  return read_design_source(
      src, [&a] { return config_from_options(a); }, check_grid);
}

ExportOptions export_options_from_options(const TextOptions& a) {
  ExportOptions o;
  o.scheme = scheme_from_string(a.get("scheme", "binary"));
  o.out = a.get("out");
  o.constraints.min_feature_um = parse_double("--min-feature-um", a.get("min-feature-um", "1"), 0, 1e4, "um", true);
  o.constraints.max_levels = parse_int("--max-levels", a.get("max-levels", "0"), 0, 65536);
  o.constraints.max_height_nm = parse_double("--max-height-nm", a.get("max-height-nm", "0"), 0, 1e6, "nm");
  o.constraints.level_tolerance_nm = parse_double("--tolerance-nm", a.get("tolerance-nm", "0.001"), 0, 1e3, "nm");
  o.dose_curve_csv = a.get("dose-curve");
  return o;
}

AsBuiltOptions as_built_options_from_options(const TextOptions& a) {
  AsBuiltOptions o;
  o.scheme = a.get("scheme", "auto");
  if (o.scheme != "auto") (void)scheme_from_string(o.scheme);
  o.etch_depth_error_m = parse_double("--etch-depth-error-nm", a.get("etch-depth-error-nm", "20"), 0, 1e4, "nm") * 1e-9;
  o.overlay_m = parse_double("--overlay-um", a.get("overlay-um", "0.5"), 0, 1e3, "um") * 1e-6;
  o.edge_blur_m = parse_double("--edge-blur-um", a.get("edge-blur-um", "0"), 0, 1e3, "um") * 1e-6;
  o.seed = std::uint64_t(parse_int("--seed", a.get("seed", "0"), 0, 2147483647));
  o.trial = std::size_t(parse_int("--trial", a.get("trial", "0"), 0, 100000));
  o.oversample = std::size_t(parse_int("--oversample", a.get("oversample", "4"), 1, 16));
  {  // DX,DY
    const std::string off = a.get("offset-um", "0,0");
    const auto comma = off.find(',');
    if (comma == std::string::npos) reject("--offset-um", off, "DX,DY in micrometres (x along columns, y along rows)");
    o.offset_x_m = parse_double("--offset-um", off.substr(0, comma), -1e4, 1e4, "um") * 1e-6;
    o.offset_y_m = parse_double("--offset-um", off.substr(comma + 1), -1e4, 1e4, "um") * 1e-6;
  }
  o.sensor_distance_error_m =
      parse_double("--sensor-distance-error-um", a.get("sensor-distance-error-um", "0"), -1e6, 1e6, "um") * 1e-6;
  return o;
}

void as_built_padding_from_options(AsBuiltOptions& o, const SystemConfig& design_cfg, const TextOptions& a) {
  SystemConfig c = design_cfg;
  if (!apply_model_padding(c, a, design_cfg.sensor_distance_m).empty()) o.padding_px = c.padding_px;
}

ToleranceOptions tolerance_options_from_options(const std::string& run, const TextOptions& a) {
  ToleranceOptions t;
  t.run = run;
  t.etch_depth_error_m = parse_double("--etch-depth-error-nm", a.get("etch-depth-error-nm", "20"), 0, 1e4, "nm") * 1e-9;
  t.overlay_m = parse_double("--overlay-um", a.get("overlay-um", "0.5"), 0, 1e3, "um") * 1e-6;
  t.edge_blur_m = parse_double("--edge-blur-um", a.get("edge-blur-um", "0"), 0, 1e3, "um") * 1e-6;
  t.height_noise_m = parse_double("--height-noise-nm", a.get("height-noise-nm", "0"), 0, 1e4, "nm") * 1e-9;
  t.trials = std::size_t(parse_int("--trials", a.get("trials", "16"), 1, 100000));
  t.seed = std::uint64_t(parse_int("--seed", a.get("seed", "0"), 0, 2147483647));
  t.scheme = a.get("scheme", "auto");
  if (t.scheme != "auto") (void)scheme_from_string(t.scheme);
  t.oversample = std::size_t(parse_int("--oversample", a.get("oversample", "4"), 1, 16));
  t.per_source = !a.has("no-per-source");
  t.save_psfs = a.has("save-psfs");
  t.data = scene_paths_from_options(a, "data");
  t.synthetic_scenes = std::size_t(parse_int("--synthetic-scenes", a.get("synthetic-scenes", "6"), 1, 100000));
  t.noise_sigma =
      a.has("noise-sigma") ? parse_double("--noise-sigma", a.get("noise-sigma"), 0, 10, "(units of full scale)") : -1;
  t.precision = precision_from_string(a.get("precision", "f32"));
  t.out = a.get("out");
  return t;
}

std::string export_report(const ExportResult& r, const std::string& out) {
  std::string s;
  for (const std::string& line : export_summary_lines(r)) s += line + "\n";
  s += "wrote " + out + "/ (";
  for (std::size_t k = 0; k < r.files.size(); ++k) s += (k ? " " : "") + r.files[k];
  return s + ")\n";
}

std::string as_built_report(const AsBuiltCamera& cam, const SystemConfig& design_cfg, const AsBuiltOptions& o,
                            const std::string& design_path, const std::string& out) {
  std::string s;
  for (const std::string& line : as_built_summary_lines(cam, design_cfg, o, design_path)) s += line + "\n";
  return s + "wrote " + out + "/ (design.h5 config.json truth.json heights.png height_error.png)\n";
}

std::string tolerance_report(const ToleranceResult& r, double seconds, const std::string& out) {
  std::string s;
  for (const std::string& line : tolerance_summary_lines(r)) s += line + "\n";
  return s +
         strprintf(
             "%.1f s; wrote %s/ (tolerance.csv tolerance.json tolerance.md psnr_by_scenario.png worst_height_error.png "
             "worst_psf.png)\n",
             seconds, out.c_str());
}

}  // namespace qdo::fab
