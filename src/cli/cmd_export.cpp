// qdo export: a design's lithography mask set (fab.hpp, fab_outputs.hpp): the options are read by
// fab_text.hpp; this file claims --out and prints.
#include <cstdio>

#include "cli.hpp"
#include "qdo/fab/fab_text.hpp"

namespace qdo::cli {

static int cmd_export(const Args& a) {
  fab::ExportOptions o = fab::export_options_from_options(a);  // every option checked
  claim_out(a, o.out);
  const fab::DesignSource s = fab::design_source_from_options(a.positional, a, true);
  o.provenance = s.provenance;
  const fab::ExportResult r = fab::export_design(s.design, s.cfg, o);
  std::fputs(fab::export_report(r, o.out).c_str(), stdout);
  return 0;
}

// qdo export: its entry in the command table (help order 150).
const RegisterCommand registered_export(150, [] {
  using namespace opts;
  return CommandSpec{"export", "lithography mask set of a design (GDSII and figures)", "RUN|DESIGN.h5",
                   "run folder written by qdo design, or a design .h5 file",
                   {opt("scheme", "mask scheme: binary, nested or greyscale", "binary"), out_dir_opt(),
                    opt("preset", "system preset for a DESIGN.h5: paper or small (omit with a run folder)", "small"),
                    opt("config", "system configuration JSON file for a DESIGN.h5 (omit with a run folder)"),
                    opt("min-feature-um", "minimum feature size in um, in (0, 10000]", "1"),
                    opt("max-levels", "maximum number of height levels, an integer in [0, 65536] (0: no limit)", "0"),
                    opt("max-height-nm", "maximum etch depth in nm, in [0, 1e6] (0: no limit)", "0"),
                    opt("dose-curve", "greyscale dose curve CSV file (default: linear)"),
                    opt("tolerance-nm", "tolerance when matching heights to levels, in nm, in [0, 1000]", "0.001")},
                   cmd_export};
});

}  // namespace qdo::cli
