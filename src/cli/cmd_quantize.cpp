// qdo quantize: a design's heights quantized post hoc to --levels uniform levels (doe.hpp) -> a
// design .h5 file (--out); the work is quantize_design_file (qdo/design/quantize_design.hpp).
#include <cstdio>

#include "cli.hpp"
#include "qdo/design/quantize_design.hpp"

namespace qdo::cli {

static int cmd_quantize(const Args& a) {
  std::fputs(quantize_design_file(a).c_str(), stdout);
  return 0;
}

// qdo quantize: its entry in the command table (help order 70).
const RegisterCommand registered_quantize(70, [] {
  using namespace opts;
  return CommandSpec{"quantize", "quantize a design to L levels (post-hoc, uniform) into a design .h5 file", "", "",
                   {preset(), config(), design_spec(), opt("levels", "number of height levels L, an integer in [2, 65536] (required)"),
                    placement(), opt("out", "output design .h5 file")},
                   cmd_quantize};
});

}  // namespace qdo::cli
