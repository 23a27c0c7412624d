// qdo export: a design's lithography mask set (fab.hpp, fab_outputs.hpp): this file turns the
// options into their inputs and prints.
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <cstdint>

#include "cli.hpp"
#include "options.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/fab/fab.hpp"
#include "qdo/fab/fab_outputs.hpp"
#include "qdo/runtime/runtime.hpp"

namespace fs = std::filesystem;
using namespace qdo;
using namespace qdo::cli;

namespace qdo::cli {

static int cmd_export(const Args& a) {
  fab::ExportOptions o;
  o.scheme = fab::scheme_from_string(a.get("scheme"));
  o.out = a.get("out");
  claim_out(a, o.out);
  o.constraints.min_feature_um = parse_double("--min-feature-um", a.get("min-feature-um"), 0, 1e4, "um", true);
  o.constraints.max_levels = parse_int("--max-levels", a.get("max-levels"), 0, 65536);
  o.constraints.max_height_nm = parse_double("--max-height-nm", a.get("max-height-nm"), 0, 1e6, "nm");
  o.constraints.level_tolerance_nm = parse_double("--tolerance-nm", a.get("tolerance-nm"), 0, 1e3, "nm");
  o.dose_curve_csv = a.get("dose-curve");
  const fab::DesignSource s = fab_source(a, true);
  o.provenance = s.provenance;
  const fab::ExportResult r = fab::export_design(s.design, s.cfg, o);
  for (const std::string& line : fab::export_summary_lines(r)) std::printf("%s\n", line.c_str());
  std::printf("wrote %s/ (", o.out.c_str());
  for (std::size_t k = 0; k < r.files.size(); ++k) std::printf("%s%s", k ? " " : "", r.files[k].c_str());
  std::printf(")\n");
  return 0;
}

namespace {
// qdo export: its entry in the command table (help order 150).
const RegisterCommand registered_export(150, [] {
  using namespace opts;
  CommandSpec c{"export", "lithography mask set of a design (GDSII and figures)", "RUN|DESIGN.h5",
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
  return c;
});
}  // namespace

}  // namespace qdo::cli
