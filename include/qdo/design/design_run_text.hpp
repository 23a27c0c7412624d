// A design run (qdo design, and the runs of qdo sweep and qdo gradcheck) read from options as a
// user typed them (TextOptions, qdo/runtime/parse.hpp), and its report as text. Every refusal is
// an InputError naming the option as typed ("--lr"), the value and what is allowed, before any
// device work. The training recipe (recipe.hpp) gives every default it names; an option given
// explicitly wins over it.
#pragma once
#include <string>
#include <vector>

#include "qdo/design/design_run.hpp"
#include "qdo/design/design_run_options.hpp"
#include "qdo/design/gradcheck.hpp"
#include "qdo/runtime/parse.hpp"

namespace qdo {

// The options of `qdo design` (also read by gradcheck, sweep): --mode and --out as given. The
// defaults written here apply only to options without a default in `a.defaults`. With `range`
// (qdo design): a configuration of several object points is taken, and --object-distances,
// --field-angles and --points-per-step build and sample them (object_points_from_options).
DesignRunOptions design_run_options_from_options(const TextOptions& a, bool range = false);
// qdo design --mode do-finetune --from RUN: the options of the do run RUN with this run's levels
// and placement, frozen optics, --finetune-steps network steps in one epoch at the do run's last
// network learning rate (or --lr-decoder), constant; --psf or --design: the camera as built whose
// PSF is frozen (checked against the do run's configuration). Any other option is refused.
DesignRunOptions finetune_options_from_options(const TextOptions& a);
// An option given explicitly that does nothing in the run's mode, objective or decoder is refused,
// naming where it acts (--beta without qdo+a or qdo+m, --target without psf-target, ...).
void check_options_act(const TextOptions& a, const DesignRunOptions& o);
// With --resume: every option given explicitly that differs from RUN/config.json is an InputError
// listing "--option: stored X, given Y" (--max-steps, --device, --out, --check-gradients may differ).
void check_resume_options(const TextOptions& a, const DesignRunOptions& given);

// qdo design's options, whatever the mode: --mode do-finetune (finetune_options_from_options) or a
// run over the configuration's points (design_run_options_from_options with range); a new run
// validated and checked by check_options_act, a resumed one (--resume; do-finetune's own options
// then ignored: its stored ones) by check_resume_options.
DesignRunOptions design_command_options(const TextOptions& a);
// The run's report: steps, final loss, seconds and levels (nm); for a design over a range of
// object points a table of each point's loss and the range's mean and worst; the files written
// into `out`. Lines end with "\n".
std::string design_run_report(const DesignRunResult& r, double seconds, const std::string& out);
// qdo gradcheck's options: a design run's (design_run_options_from_options) on the qdo recipe with
// 10 epochs (a generic state: random heights, the checked step inside the alpha window), validated.
DesignRunOptions gradcheck_options_from_options(const TextOptions& a);
// The gradient check's table: parameter group, max relative error, tolerance, ok or FAIL, one
// line each after a header (lines end with "\n"); ok when every group passes.
struct GradcheckReport {
  std::string text;
  bool ok = true;
};
GradcheckReport gradcheck_report(const std::vector<GradcheckRow>& rows);
// qdo design --check-gradients: gradcheck on the run's configuration (a design over several object
// points at point 0, whose chain is the one-point chain), its table after a line saying so.
GradcheckReport design_gradient_check(Runtime& rt, const DesignRunOptions& o);

}  // namespace qdo
