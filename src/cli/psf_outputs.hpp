// What `qdo psf` and `qdo simulate` share (private to src/cli/): the --save option. The PSF
// outputs themselves (psf.h5, points.csv, the figures, the concurrent writing) are the library's
// (include/qdo/design/psf_outputs.hpp).
#pragma once
#include "cli.hpp"

namespace qdo::cli {

// --save: extra outputs of psf and simulate, comma-separated; today only "native" (the native-grid
// PSF stack /psf_native in psf.h5, bands x N x N: the largest output, off by default).
bool save_native(const Args& a);

}  // namespace qdo::cli
