// qdo psf: a design's spectral PSF stack (psf.h5, psf.png, design.png): the work is the library's
// (psf_outputs_from_options, qdo/design/psf_outputs.hpp); this file claims --out and prints.
#include <cstdio>

#include "cli.hpp"
#include "qdo/design/psf_outputs.hpp"

namespace qdo::cli {

static int cmd_psf(const Args& a) {
  std::fputs(psf_outputs_from_options(a, [&a] { return out_dir(a); }).c_str(), stdout);
  return 0;
}

// qdo psf: its entry in the command table (help order 40).
const RegisterCommand registered_psf(40, [] {
  using namespace opts;
  return CommandSpec{"psf", "compute a design's PSF stack: DIR/psf.h5 (the sensor-grid stack; points x bands x S x S with several "
                          "object points, and points.csv), psf.png, design.png", "", "",
                   {preset(), config(), design_spec(), levels_post(), placement(),
                    object_distances("several object points", "all computed in one batched pass"), field_angles("several object points"),
                    precision(), device(), save_opt(), compress(), out_dir_opt()},
                   cmd_psf};
});

}  // namespace qdo::cli
