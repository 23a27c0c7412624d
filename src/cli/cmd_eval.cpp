// qdo eval RUN: a run's design and decoder on the test scenes (eval.hpp) -> OUT/metrics.csv,
// metrics.json, reconstructions.h5 and figures. The options are read and the report written by
// the library (eval_options_from_options, eval_report); this file claims --out and prints.
#include <cstdio>

#include "cli.hpp"
#include "qdo/evaluate/eval.hpp"
#include "qdo/runtime/runtime.hpp"

namespace qdo::cli {

static int cmd_eval(const Args& a) {
  const EvalOptions e = eval_options_from_options(a.positional, a);  // every option checked
  claim_out(a, e.out);
  Runtime rt(a.get("device"));
  std::fputs(eval_report(evaluate_run(rt, e), e.out).c_str(), stdout);
  return 0;
}

// qdo eval: its entry in the command table (help order 120).
const RegisterCommand registered_eval(120, [] {
  using namespace opts;
  return CommandSpec{"eval", "evaluate a run's design: metrics, reconstructions and figures", "RUN", "run folder written by qdo design",
                   {data("test scenes (default: synthetic scenes)"), data_root(),
                    opt("levels", "re-quantize the full-precision design to L levels, an integer in [2, 65536] (default: the run's)"),
                    placement(), opt("decoder", "decoder: matched (refit to the evaluated design) or mismatch (fit to the full-precision design)", "matched"),
                    opt("decoder-kind", "the decoder that reconstructs: wiener, cg[:tolerance=T,max_iterations=N] (conjugate-gradient MAP) or "
                                        "another registered one (default: the run's own, its Wiener decoder or its trained network)"),
                    opt("psf", "PSF stack file through which the scenes are measured in place of the design's PSF: psf.h5 as qdo psf "
                               "writes it (a measured stack in that layout), for the run's bands and sensor grid (checked); not with --levels"),
                    opt("design", "a fitted as-built design .h5 (N x N at the run's pitch) whose simulated PSF measures the scenes in place "
                                  "of the run's design (a matched Wiener decoder is refit for it); not with --psf or --levels"),
                    opt("noise-sigma", "sensor noise std, in units of full scale, in [0, 10] (default: the run's)"),
                    opt("pixels", "pixels whose spectra are plotted: y:x pairs, comma-separated"),
                    opt("renders", "number of reconstructions rendered as PNG, an integer in [0, 1000]", "4"), synthetic_scenes("6"),
                    precision(), device(), out_dir_opt()},
                   cmd_eval};
});

}  // namespace qdo::cli
