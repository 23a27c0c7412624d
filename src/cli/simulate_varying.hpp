// qdo simulate with a depth map (--depth) or a field-dependent PSF (--field-grid) on the command
// line: the options turned into the library's capture (include/qdo/asbuilt/varying_capture.hpp).
#pragma once
#include "cli.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo::cli {

// True when the command line asks for a varying image (--depth or --field-grid).
bool varying_requested(const Args& a);
// Refuses the varying options (--depth-layers, --depth-scale, --psf-placement, --field-edge-deg,
// --field-rank) when neither --depth nor --field-grid is given (they would be ignored).
void check_no_orphan_varying_options(const Args& a);
// The whole command for a varying image: every input checked before any device work, then the
// PSFs at the used depth layers / field points only, the image, the outputs.
int simulate_varying(const Args& a, const SystemConfig& cfg, Precision p);

}  // namespace qdo::cli
