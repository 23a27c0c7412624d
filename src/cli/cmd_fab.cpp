// qdo export (lithography mask sets), qdo tolerance (Monte Carlo over fabrication errors) and qdo
// fabricate (one camera as built). The work is fab.hpp's and fab_outputs.hpp's: this file turns
// the options into their inputs and prints.
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <cstdint>

#include "cli.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/fab/fab.hpp"
#include "qdo/fab/fab_outputs.hpp"
#include "qdo/runtime/runtime.hpp"

namespace fs = std::filesystem;
using namespace qdo;
using namespace qdo::cli;

namespace qdo::cli {
namespace {

// RUN (the positional): a run folder, whose config.json leaves no room for --preset or --config,
// or a design .h5 file read with the configuration they give (fab_outputs.hpp: read_design_source).
fab::DesignSource fab_source(const Args& a, bool check_grid) {
  const std::string& src = a.positional;
  if (fs::is_directory(src) && (a.has("preset") || a.has("config")))
    reject("--preset", "(given)", "omitted with a run folder (its config.json is used)");
  return fab::read_design_source(src, [&a] { return load_config(a); }, check_grid);
}

}  // namespace

int cmd_export(const Args& a) {
  fab::ExportOptions o;
  o.scheme = fab::scheme_from_string(a.get("scheme"));
  o.out = a.get("out");
  claim_out(a, o.out);
  o.constraints.min_feature_um = parse_double("--min-feature-um", a.get("min-feature-um"), 0, 1e4, "um", true);
  o.constraints.max_levels = parse_int("--max-levels", a.get("max-levels"), 0, 65536);
  o.constraints.max_height_nm = parse_double("--max-height-nm", a.get("max-height-nm"), 0, 1e6, "nm");
  o.constraints.level_tolerance_nm = parse_double("--tolerance-nm", a.get("tolerance-nm"), 0, 1e3, "nm");
  o.dose_curve_csv = a.get("dose-curve");
  const fab::DesignSource s = fab_source(a, true);
  o.provenance = s.provenance;
  const fab::ExportResult r = fab::export_design(s.design, s.cfg, o);
  for (const std::string& line : fab::export_summary_lines(r)) std::printf("%s\n", line.c_str());
  std::printf("wrote %s/ (", o.out.c_str());
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
  for (const std::string& line : fab::tolerance_summary_lines(r)) std::printf("%s\n", line.c_str());
  std::printf("%.1f s; wrote %s/ (tolerance.csv tolerance.json tolerance.md psnr_by_scenario.png worst_height_error.png worst_psf.png)\n",
              seconds_since(t0), t.out.c_str());
  return 0;
}

// qdo fabricate: one camera as built (fab.hpp: fabricate) -> DIR/design.h5 (the fabricated
// relief), config.json (the as-built geometry), truth.json (every error drawn and the realised
// level heights, in qdo fit's parameter names), heights.png and height_error.png.
int cmd_fabricate(const Args& a) {
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
  const fab::DesignSource s = fab_source(a, false);
  const fab::AsBuiltCamera cam = fab::fabricate(s.design, s.cfg, o);  // every check before any file is written
  const std::string dir = a.get("out");
  claim_out(a, dir);
  fab::write_as_built_outputs(dir, cam, s.design, s.cfg, o, s.design_path);
  for (const std::string& line : fab::as_built_summary_lines(cam, s.cfg, o, s.design_path)) std::printf("%s\n", line.c_str());
  std::printf("wrote %s/ (design.h5 config.json truth.json heights.png height_error.png)\n", dir.c_str());
  return 0;
}

}  // namespace qdo::cli
