// qdo tolerance: Monte Carlo over fabrication errors of a run's design (fab.hpp, fab_outputs.hpp):
// the options are read by fab_text.hpp; this file claims --out, opens the device and prints.
#include <chrono>
#include <cstdio>

#include "cli.hpp"
#include "qdo/fab/fab_text.hpp"
#include "qdo/runtime/runtime.hpp"

namespace qdo::cli {

static int cmd_tolerance(const Args& a) {
  fab::ToleranceOptions t = fab::tolerance_options_from_options(a.positional, a);  // every option checked
  claim_out(a, t.out);
  t.quiet = false;
  Runtime rt(a.get("device"));
  const auto t0 = std::chrono::steady_clock::now();
  const fab::ToleranceResult r = fab::tolerance_analysis(rt, t);
  std::fputs(fab::tolerance_report(r, seconds_since(t0), t.out).c_str(), stdout);
  return 0;
}

// qdo tolerance: its entry in the command table (help order 160).
const RegisterCommand registered_tolerance(160, [] {
  using namespace opts;
  return CommandSpec{"tolerance", "Monte Carlo over fabrication errors of a run's design", "RUN", "run folder written by qdo design",
                   {opt("etch-depth-error-nm", "etch depth error std in nm, in [0, 10000]", "20"), opt("overlay-um", "mask overlay error std in um, in [0, 1000]", "0.5"),
                    opt("edge-blur-um", "edge blur in um, in [0, 1000]", "0"), opt("height-noise-nm", "height noise std in nm, in [0, 10000]", "0"),
                    opt("trials", "trials per scenario, an integer in [1, 100000]", "16"), seed(),
                    opt("scheme", "mask scheme: auto, binary, nested or greyscale", "auto"),
                    opt("oversample", "mask oversampling, an integer in [1, 16]", "4"), data("test scenes (default: synthetic scenes)"), data_root(),
                    synthetic_scenes("6"), opt("noise-sigma", "sensor noise std, in units of full scale, in [0, 10] (default: the run's)"),
                    flag("no-per-source", "skip the scenarios of one error source at a time"),
                    flag("save-psfs", "write every trial's PSF stack to psfs.h5"), precision(), device(), out_dir_opt()},
                   cmd_tolerance};
});

}  // namespace qdo::cli
