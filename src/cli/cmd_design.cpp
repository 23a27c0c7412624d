// qdo design: a design optimised end to end into a run folder (design_run.hpp), resumable; with
// --mode do-finetune, a do run's network fine-tuned for quantized or as-built optics.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <set>
#include <string>

#include "cli.hpp"
#include "options.hpp"
#include "qdo/data/config.hpp"
#include "qdo/design/design.hpp"
#include "qdo/design/design_run.hpp"
#include "qdo/design/design_run_options.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/design/gradcheck.hpp"
#include "qdo/runtime/mpi.hpp"
#include "qdo/physics/psf_source.hpp"
#include "qdo/design/psf_spec.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/runtime/util.hpp"

namespace qdo::cli {

namespace {
// qdo design --mode do-finetune --from RUN: the options of the do run RUN with this run's levels
// and placement, frozen optics, finetune-steps network steps in one epoch at the do run's last
// network learning rate (or --lr-decoder), constant. Options that would be dropped are refused.
DesignRunOptions finetune_options(const Args& a) {
  static const std::set<std::string> allowed = {"mode",      "from",      "levels", "placement", "finetune-steps", "lr-decoder",
                                                "checkpoint-every", "max-steps", "device", "out", "precision", "psf", "design"};
  for (const auto& [k, v] : a.opt)
    if (!allowed.count(k))
      reject("--" + k, v, "not with --mode do-finetune (it takes the do run's options; allowed: --from --levels --placement --psf --design "
                          "--finetune-steps --lr-decoder --checkpoint-every --max-steps --precision --device --out)");
  if (!a.has("from")) reject("--from", "(missing)", "the network do run folder to fine-tune (--mode do-finetune)");
  const std::string from = a.get("from");
  DesignRunOptions o = read_run_config(from, "--from", "a run folder written by qdo design (config.json missing)");
  if (o.design.mode != DesignMode::DO || !o.decoder.network())
    reject("--from", from, "a do run with a network decoder (it is a " + to_string(o.design.mode) + " run, decoder " + o.decoder.to_string() +
                               "); with the Wiener decoder the refit is qdo eval --decoder matched");
  const double last_lr = o.lr_decoder * std::pow(o.design.lr_decay_per_epoch, double(o.epochs - 1));
  o.finetune_from = from;
  if (a.has("levels")) o.design.quantizer.levels = parse_int("--levels", a.get("levels"), 2, 65536);
  if (a.has("placement")) o.design.quantizer.placement = placement_from_string(a.get("placement"));
  o.design.steps_per_epoch = std::size_t(parse_int("--finetune-steps", a.get("finetune-steps", "200"), 1, 100000000));
  o.epochs = 1;
  o.design.t0_epochs = 0;
  o.design.t1_epochs = 1;
  o.design.lr_decay_per_epoch = 1;
  o.lr_decoder = a.has("lr-decoder") ? parse_double("--lr-decoder", a.get("lr-decoder"), 0, 1, "", true) : last_lr;
  o.checkpoint_every = std::size_t(parse_int("--checkpoint-every", a.get("checkpoint-every", "10"), 1, 100000000));
  o.max_steps = a.has("max-steps") ? parse_int("--max-steps", a.get("max-steps"), 0, 2147483647) : -1;
  if (a.has("precision")) o.precision = precision_from_string(a.get("precision"));
  // do-finetune for the camera as built: the frozen PSF is a measured stack or a fitted design's,
  // checked against the do run's configuration here, before any work.
  const PsfSpec asbuilt = psf_spec_from_options(a.get("psf"), a.get("design"), "--psf", "--design", "the frozen PSF comes from one of them");
  if (asbuilt.kind != PsfSpec::Kind::Run) {
    if (a.has("levels"))
      reject("--levels", a.get("levels"),
             asbuilt.kind == PsfSpec::Kind::File ? "no --levels with --psf (the measured stack is used as it is)"
                                                 : "no --levels with --design (the fitted design is used as it is)");
    (asbuilt.kind == PsfSpec::Kind::File ? o.finetune_psf : o.finetune_design) = asbuilt.value;
    (void)read_psf_input(asbuilt, o.cfg);
  }
  o.out = a.get("out");
  return o;
}
// An option given explicitly that does nothing in the run's mode, objective or decoder is
// refused, naming where it acts (it was ignored silently).
void check_options_act(const Args& a, const DesignRunOptions& o) {
  const DesignMode m = o.design.mode;
  const bool levels_trained = m == DesignMode::QDOA || m == DesignMode::QDOM;
  const bool network = o.objective == Objective::Network;
  const bool wiener = o.objective == Objective::Wiener || o.objective == Objective::WienerMse || o.objective == Objective::WienerMae;
  struct Rule {
    const char* option;
    bool acts;
    const char* where;
  };
  const Rule rules[] = {
      {"beta", levels_trained, "--mode qdo+a or qdo+m (the regulariser of the trained levels)"},
      {"lr-offsets", levels_trained, "--mode qdo+a or qdo+m (the trained level offsets or mask depths)"},
      {"lr-decoder", network, "a network --decoder"},
      {"gamma", network, "a network --decoder"},
      {"target", o.objective == Objective::PsfTarget, "--objective psf-target"},
      {"wiener-on", wiener, "the Wiener objectives (--objective wiener, wiener-mse or wiener-mae)"},
      {"from", false, "--mode do-finetune"},
      {"finetune-steps", false, "--mode do-finetune"},
      {"psf", false, "--mode do-finetune (the measured PSF the network is fine-tuned for)"},
      {"design", false, "--mode do-finetune (the fitted design whose PSF the network is fine-tuned for)"},
  };
  for (const Rule& r : rules)
    if (a.has(r.option) && !r.acts)
      reject(std::string("--") + r.option, a.get(r.option),
             std::string("an option of ") + r.where + "; this run (--mode " + to_string(m) + ", --objective " + to_string(o.objective) +
                 (network ? ", --decoder " + o.decoder.to_string() : std::string()) + ") would ignore it: leave it out");
}

}  // namespace

static int cmd_design(const Args& a) {
  const bool finetune = a.get("mode") == "do-finetune";
  if (finetune && a.has("resume")) {  // a do-finetune run resumes like any run: its stored options
    Args b = a;
    b.opt.erase("mode");
    b.opt.erase("from");
    b.opt.erase("psf");
    b.opt.erase("design");
    return cmd_design(b);
  }
  DesignRunOptions o = finetune ? finetune_options(a) : design_options(a, true);
  const bool resume = a.has("resume");
  if (!resume) o.validate();
  else check_resume_options(a, o);
  if (!resume && !finetune) check_options_act(a, o);
  // Under mpirun rank 0 owns the run folder (run_design); each rank opens its own device.
  const qdo::mpi::World* world = qdo::mpi::world();
  const bool writer = !world || world->rank() == 0;
  if (!resume && writer) claim_out(a, o.out);  // --resume: the run folder is checked by the resume itself
  Runtime rt(process_device(a.get("device")));
  if (a.has("check-gradients")) {
    // A design over several points: each point's chain is the one-point chain of point_config(cfg, p)
    // (the range objective is their mean); checked at the first point.
    DesignRunOptions g = o;
    if (o.cfg.point_count() > 1) {
      g.cfg = point_config(o.cfg, 0);
      g.design.points_per_step = 1;
    }
    std::printf("gradient check on this run's configuration (reduced to N <= 64)%s:\n",
                o.cfg.point_count() > 1 ? ", at object point 0" : "");
    if (const int rc = print_gradcheck(gradcheck(rt, g, g.design.seed)); rc != 0) return rc;
  }
  const auto t0 = std::chrono::steady_clock::now();
  const DesignRunResult r = run_design(rt, o, resume);
  if (!writer) return 0;
  std::printf("design: %ld steps, final loss %.6g, %.1f s; levels (nm):", r.steps_done, r.final_loss, seconds_since(t0));
  for (double l : r.levels_m) std::printf(" %.1f", l * 1e9);
  std::printf("\n");
  if (!r.point_losses.empty()) {  // a design over a range of object points: its spread over the range
    std::printf("%-6s %12s %12s %12s %14s\n", "point", "distance_m", "field_x_deg", "field_y_deg", "loss");
    double worst = r.point_losses[0], sum = 0;
    for (std::size_t p = 0; p < r.point_losses.size(); ++p) {
      const ObjectPoint& pt = r.points[p];
      std::printf("%-6zu %12s %12.4g %12.4g %14.6g\n", p, pt.at_infinity() ? "inf" : to_str(pt.distance_m).c_str(), pt.field_x_deg,
                  pt.field_y_deg, r.point_losses[p]);
      worst = std::max(worst, r.point_losses[p]);
      sum += r.point_losses[p];
    }
    std::printf("range: mean loss %.6g, worst %.6g over %zu points\n", sum / double(r.point_losses.size()), worst,
                r.point_losses.size());
  }
  std::printf("wrote %s/ (config.json checkpoint.h5 log.csv design.h5 psf.h5 design.png psf.png loss.png%s)\n", o.out.c_str(),
              r.point_losses.empty() ? "" : " range.csv range.png");
  return 0;
}

namespace {
// qdo design: its entry in the command table (help order 100).
const RegisterCommand registered_design(100, [] {
  using namespace opts;
  CommandSpec c{"design", "optimise a design end to end into a run folder (resumable)", "", "",
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
  return c;
});
}  // namespace

}  // namespace qdo::cli
