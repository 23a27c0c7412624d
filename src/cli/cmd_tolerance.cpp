// qdo tolerance: Monte Carlo over fabrication errors of a run's design (fab.hpp, fab_outputs.hpp):
// this file turns the options into their inputs and prints.
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

static int cmd_tolerance(const Args& a) {
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

namespace {
// qdo tolerance: its entry in the command table (help order 160).
const RegisterCommand registered_tolerance(160, [] {
  using namespace opts;
  CommandSpec c{"tolerance", "Monte Carlo over fabrication errors of a run's design", "RUN", "run folder written by qdo design",
                   {opt("etch-depth-error-nm", "etch depth error std in nm, in [0, 10000]", "20"), opt("overlay-um", "mask overlay error std in um, in [0, 1000]", "0.5"),
                    opt("edge-blur-um", "edge blur in um, in [0, 1000]", "0"), opt("height-noise-nm", "height noise std in nm, in [0, 10000]", "0"),
                    opt("trials", "trials per scenario, an integer in [1, 100000]", "16"), seed(),
                    opt("scheme", "mask scheme: auto, binary, nested or greyscale", "auto"),
                    opt("oversample", "mask oversampling, an integer in [1, 16]", "4"), data("test scenes (default: synthetic scenes)"), data_root(),
                    synthetic_scenes("6"), noise_sigma("sensor noise std, in units of full scale, in [0, 10] (default: the run's)", ""),
                    flag("no-per-source", "skip the scenarios of one error source at a time"),
                    flag("save-psfs", "write every trial's PSF stack to psfs.h5"), precision(), device(), out_dir_opt()},
                   cmd_tolerance};
  return c;
});
}  // namespace

}  // namespace qdo::cli
