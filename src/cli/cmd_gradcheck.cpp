// qdo gradcheck: the analytic gradients against finite differences (gradcheck.hpp), and the table
// it prints (print_gradcheck, also qdo design --check-gradients).
#include <cstdio>
#include <vector>

#include "cli.hpp"
#include "options.hpp"
#include "qdo/design/design_run_options.hpp"
#include "qdo/design/gradcheck.hpp"
#include "qdo/runtime/runtime.hpp"

namespace qdo::cli {

int print_gradcheck(const std::vector<GradcheckRow>& rows) {
  bool ok = true;
  std::printf("%-78s %12s %10s  %s\n", "parameter group", "max rel err", "tolerance", "");
  for (const auto& r : rows) {
    std::printf("%-78s %12.3e %10.1e  %s\n", r.group.c_str(), r.max_rel_error, r.tolerance, r.ok() ? "ok" : "FAIL");
    ok = ok && r.ok();
  }
  return ok ? 0 : 5;
}

static int cmd_gradcheck(const Args& a) {
  Args b = a;
  b.opt["out"] = "(unused)";
  b.opt["epochs"] = "10";
  // A generic state whatever the training recipe: qdo's (random heights away from the quantizer's
  // thresholds, 10 steps an epoch so the checked step 6 lies inside the alpha window). The release
  // recipe's own terms (L_aq over the rings, the pinned top level) are checked by suite recipe.
  b.opt["recipe"] = "qdo";
  DesignRunOptions o = design_options(b);
  o.validate();  // every option checked before the device is opened
  Runtime rt(a.get("device"));
  return print_gradcheck(gradcheck(rt, o, o.design.seed));
}

namespace {
// qdo gradcheck: its entry in the command table (help order 110).
const RegisterCommand registered_gradcheck(110, [] {
  using namespace opts;
  CommandSpec c{"gradcheck", "check the analytic gradients against finite differences (exit 5 on failure)", "", "",
                   {preset(), config(), mode(), opt("levels", "height levels L, an integer in [2, 65536]", "4"), placement(),
                    parameterization(), objective(), target(), seed(), device(), psf_path(),
                    opt("wiener-on", "where the wiener objective's device row is checked: device (default) or cpu (no such row)", "device")},
                   cmd_gradcheck};
  return c;
});
}  // namespace

}  // namespace qdo::cli
