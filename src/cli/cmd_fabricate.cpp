// qdo fabricate: one camera as built, for simulating it (fab.hpp: fabricate) -> DIR/design.h5 (the
// fabricated relief), config.json (the as-built geometry), truth.json (every error drawn and the
// realised level heights, in qdo fit's parameter names), heights.png and height_error.png. The
// options are read and the report written by fab_text.hpp; this file claims --out and prints.
#include <cstdio>

#include "cli.hpp"
#include "qdo/fab/fab_text.hpp"

namespace qdo::cli {

static int cmd_fabricate(const Args& a) {
  fab::AsBuiltOptions o = fab::as_built_options_from_options(a);
  const fab::DesignSource s = fab::design_source_from_options(a.positional, a, false);
  fab::as_built_padding_from_options(o, s.cfg, a);
  const fab::AsBuiltCamera cam = fab::fabricate(s.design, s.cfg, o);  // every check before any file is written
  const std::string dir = a.get("out");
  claim_out(a, dir);
  fab::write_as_built_outputs(dir, cam, s.design, s.cfg, o, s.design_path);
  std::fputs(fab::as_built_report(cam, s.cfg, o, s.design_path, dir).c_str(), stdout);
  return 0;
}

// qdo fabricate: its entry in the command table (help order 170).
const RegisterCommand registered_fabricate(170, [] {
  using namespace opts;
  return CommandSpec{"fabricate",
                   "one camera as built, for simulating it: the design's masks made with one draw of qdo tolerance's errors, the relief "
                   "offset against the aperture, the DOE-sensor distance changed -> DIR/design.h5, config.json, truth.json (the true "
                   "values in qdo fit's names), heights.png, height_error.png",
                   "RUN|DESIGN.h5", "run folder written by qdo design, or a design .h5 file",
                   {opt("preset", "system preset for a DESIGN.h5: paper or small (omit with a run folder)", "small"),
                    opt("config", "system configuration JSON file for a DESIGN.h5 (omit with a run folder)"),
                    opt("scheme", "mask scheme: auto (binary when possible, else nested), binary, nested or greyscale", "auto"),
                    opt("etch-depth-error-nm", "etch depth error bound per mask, uniform in [-S, S], nm, in [0, 10000]", "20"),
                    opt("overlay-um", "overlay error bound per mask after the first and per axis, uniform in [-S, S], um, in [0, 1000]", "0.5"),
                    opt("edge-blur-um", "edge blur (Gaussian sigma) of every mask, um, in [0, 1000]", "0"),
                    seed(), opt("trial", "which draw of the seed's sequence (qdo tolerance's trial index), an integer in [0, 100000]", "0"),
                    opt("oversample", "mask oversampling, an integer in [1, 16]", "4"),
                    opt("offset-um", "DX,DY: the whole relief moved against the aperture after the masks, um (x along columns)", "0,0"),
                    opt("sensor-distance-error-um", "added to the DOE-sensor distance (assembly), um, in [-1e6, 1e6]; z must stay > 0", "0"),
                    model_padding(), out_dir_opt()},
                   cmd_fabricate};
});

}  // namespace qdo::cli
