// The fabrication commands' options (qdo export, qdo fabricate, qdo tolerance), read from options as
// a user typed them (TextOptions, qdo/runtime/parse.hpp), and their reports. Each value is checked:
// refusals are InputErrors naming the option as typed ("--overlay-um"), the value and what is
// allowed. Defaults are the commands' where the caller declares none.
#pragma once
#include <string>

#include "qdo/fab/fab.hpp"
#include "qdo/fab/fab_outputs.hpp"
#include "qdo/runtime/parse.hpp"

namespace qdo::fab {

// RUN|DESIGN.h5: a run folder (its config.json: no --preset or --config then) or a design .h5 file
// read with the configuration of --preset / --config (read_design_source).
DesignSource design_source_from_options(const std::string& src, const TextOptions& a, bool check_grid);
// qdo export: scheme, out, min-feature-um, max-levels, max-height-nm, tolerance-nm, dose-curve.
ExportOptions export_options_from_options(const TextOptions& a);
// qdo fabricate: scheme (auto or a mask scheme), etch-depth-error-nm, overlay-um, edge-blur-um,
// seed, trial, oversample, offset-um (DX,DY), sensor-distance-error-um.
AsBuiltOptions as_built_options_from_options(const TextOptions& a);
// qdo fabricate's --model-padding (option_inputs.hpp apply_model_padding) for the design's
// configuration: o.padding_px set when it changes the design's padding_px.
void as_built_padding_from_options(AsBuiltOptions& o, const SystemConfig& design_cfg, const TextOptions& a);
// qdo tolerance RUN: etch-depth-error-nm, overlay-um, edge-blur-um, height-noise-nm, trials, seed,
// scheme, oversample, no-per-source, save-psfs, data, synthetic-scenes, noise-sigma, precision, out.
ToleranceOptions tolerance_options_from_options(const std::string& run, const TextOptions& a);

// The commands' reports (lines end with "\n"): the summary lines (export_summary_lines,
// as_built_summary_lines, tolerance_summary_lines), then the files written into `out` (and for
// tolerance the seconds it took).
std::string export_report(const ExportResult& r, const std::string& out);
std::string as_built_report(const AsBuiltCamera& cam, const SystemConfig& design_cfg, const AsBuiltOptions& o,
                            const std::string& design_path, const std::string& out);
std::string tolerance_report(const ToleranceResult& r, double seconds, const std::string& out);

}  // namespace qdo::fab
