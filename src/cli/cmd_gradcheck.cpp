// qdo gradcheck: the analytic gradients against finite differences (gradcheck.hpp), its table
// printed (gradcheck_report, design_run_text.hpp; also qdo design --check-gradients); exit 5 on a failure.
#include <cstdio>

#include "cli.hpp"
#include "qdo/design/design_run_text.hpp"
#include "qdo/runtime/runtime.hpp"

namespace qdo::cli {

static int cmd_gradcheck(const Args& a) {
  const DesignRunOptions o = gradcheck_options_from_options(a);  // every option checked
  Runtime rt(a.get("device"));
  const GradcheckReport g = gradcheck_report(gradcheck(rt, o, o.design.seed));
  std::fputs(g.text.c_str(), stdout);
  return g.ok ? 0 : 5;
}

// qdo gradcheck: its entry in the command table (help order 110).
const RegisterCommand registered_gradcheck(110, [] {
  using namespace opts;
  return CommandSpec{"gradcheck", "check the analytic gradients against finite differences (exit 5 on failure)", "", "",
                   {preset(), config(), opt("mode", "design mode: full, do, qdo, ste, qdo+a or qdo+m", "qdo+a"),
                    opt("levels", "height levels L, an integer in [2, 65536]", "4"), placement(), parameterization(), objective(),
                    target(), seed(), device(),
                    opt("psf-path", "PSF engine of the optimisation: auto (radial for radial designs), 2d or radial (radial designs "
                                    "only)", "auto"),
                    opt("wiener-on", "where the wiener objective's device row is checked: device (default) or cpu (no such row)", "device")},
                   cmd_gradcheck};
});

}  // namespace qdo::cli
