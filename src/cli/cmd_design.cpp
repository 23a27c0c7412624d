// qdo design: a design optimised end to end into a run folder (design_run.hpp), resumable; with
// --mode do-finetune, a do run's network fine-tuned for quantized or as-built optics. The options
// are read and checked by the library (design_run_text.hpp); this file prints its report.
#include <chrono>
#include <cstdio>
#include <string>

#include "cli.hpp"
#include "qdo/design/design_run_text.hpp"
#include "qdo/runtime/mpi.hpp"
#include "qdo/runtime/runtime.hpp"

namespace qdo::cli {

static int cmd_design(const Args& a) {
  const DesignRunOptions o = design_command_options(a);  // read and checked, a resumed run's against its stored ones
  const bool resume = a.has("resume");
  // Under mpirun rank 0 owns the run folder (run_design); each rank opens its own device.
  const qdo::mpi::World* world = qdo::mpi::world();
  const bool writer = !world || world->rank() == 0;
  if (!resume && writer) claim_out(a, o.out);  // --resume: the run folder is checked by the resume itself
  Runtime rt(process_device(a.get("device")));
  if (a.has("check-gradients")) {
    const GradcheckReport g = design_gradient_check(rt, o);
    std::fputs(g.text.c_str(), stdout);
    if (!g.ok) return 5;
  }
  const auto t0 = std::chrono::steady_clock::now();
  const DesignRunResult r = run_design(rt, o, resume);
  if (writer) std::fputs(design_run_report(r, seconds_since(t0), o.out).c_str(), stdout);
  return 0;
}

// qdo design: its entry in the command table (help order 100).
const RegisterCommand registered_design(100, [] {
  using namespace opts;
  return CommandSpec{"design", "optimise a design end to end into a run folder (resumable)", "", "",
                   concat({preset(), config(),
                           opt("mode", "design mode: full, do, qdo, ste, qdo+a, qdo+m, or do-finetune (with --from: a network do run's "
                                       "network trained on with its DOE quantized to --levels and frozen)", "qdo+a"),
                           opt("levels", "height levels L, an integer in [2, 65536]", "4"), placement(),
                           parameterization(), objective(), target(), data("training scenes (default: synthetic scenes)"), data_root(),
                           opt("from", "do-finetune: the finished network do run folder to fine-tune"),
                           opt("finetune-steps", "do-finetune: network steps with the DOE frozen, an integer in [1, 100000000]", "200"),
                           opt("psf", "do-finetune for the camera as built: a measured PSF stack (qdo calibrate's psf.h5, for the run's "
                                      "bands and sensor grid; checked) frozen in place of the do run's quantized DOE; not with --levels"),
                           opt("design", "do-finetune for the camera as built: a fitted as-built design .h5 (N x N at the run's pitch), "
                                         "its simulated PSF frozen in place of the do run's quantized DOE; not with --levels or --psf"),
                           object_distances("design over a range", "the training conditions of the run"), field_angles("design over a range"),
                           opt("points-per-step", "object points each optimiser step trains on, drawn anew each step (seeded), an integer "
                                                  "in [1, P] for P object points (P: every point every step)", "1")},
                          concat(training_options(),
                                 {opt("checkpoint-every", "steps between checkpoints, an integer in [1, 100000000]", "10"),
                                  opt("max-steps", "stop after N steps in this session, resumable, an integer >= 0 (default: no limit)"),
                                  flag("resume", "continue the run in --out with its stored options"),
                                  flag("check-gradients", "run the gradient check on this configuration first"), precision(), device(),
                                  opt("out", "run folder (config.json checkpoint.h5 log.csv design.h5 psf.h5 *.png)")})),
                   cmd_design, true};
});

}  // namespace qdo::cli
