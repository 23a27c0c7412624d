// qdo fabricate: one camera as built, for simulating it (fab.hpp, fab_outputs.hpp): this file
// turns the options into their inputs and prints.
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <cstdint>

#include "cli.hpp"
#include "options.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/fab/fab.hpp"
#include "qdo/fab/fab_outputs.hpp"
#include "qdo/runtime/runtime.hpp"

namespace fs = std::filesystem;
using namespace qdo;
using namespace qdo::cli;

namespace qdo::cli {

// qdo fabricate: one camera as built (fab.hpp: fabricate) -> DIR/design.h5 (the fabricated
// relief), config.json (the as-built geometry), truth.json (every error drawn and the realised
// level heights, in qdo fit's parameter names), heights.png and height_error.png.
static int cmd_fabricate(const Args& a) {
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

namespace {
// qdo fabricate: its entry in the command table (help order 170).
const RegisterCommand registered_fabricate(170, [] {
  using namespace opts;
  CommandSpec c{"fabricate",
                   "one camera as built, for simulating it: the design's masks made with one draw of qdo tolerance's errors, the relief "
                   "offset against the aperture, the DOE-sensor distance changed -> DIR/design.h5, config.json, truth.json (the true "
                   "values in qdo fit's names), heights.png, height_error.png",
                   "RUN|DESIGN.h5", "run folder written by qdo design, or a design .h5 file",
                   {opt("preset", "system preset for a DESIGN.h5: paper or small (omit with a run folder)", "small"),
                    opt("config", "system configuration JSON file for a DESIGN.h5 (omit with a run folder)"),
                    opt("scheme", "mask scheme: auto (binary when possible, else nested), binary, nested or greyscale", "auto"),
                    opt("etch-depth-error-nm", "etch depth error bound per mask, uniform in [-S, S], nm, in [0, 10000]", "20"),
                    opt("overlay-um", "overlay error bound per mask after the first and per axis, uniform in [-S, S], um, in [0, 1000]", "0.5"),
                    opt("edge-blur-um", "edge blur (Gaussian sigma) of every mask, um, in [0, 1000]", "0"),
                    seed(), opt("trial", "which draw of the seed's sequence (qdo tolerance's trial index), an integer in [0, 100000]", "0"),
                    opt("oversample", "mask oversampling, an integer in [1, 16]", "4"),
                    opt("offset-um", "DX,DY: the whole relief moved against the aperture after the masks, um (x along columns)", "0,0"),
                    opt("sensor-distance-error-um", "added to the DOE-sensor distance (assembly), um, in [-1e6, 1e6]; z must stay > 0", "0"),
                    out_dir_opt()},
                   cmd_fabricate};
  return c;
});
}  // namespace

}  // namespace qdo::cli
