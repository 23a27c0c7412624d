// The as-built fit (fit.hpp) as a job: its inputs read and checked from files and text, and its
// result reported (fit.json, fit.h5, the as-built design.h5 and config.json, fit.png,
// residual.png, the text summary). `qdo fit` is these calls; other callers (Python, scripts)
// reuse them. Every check runs before any device work.
#pragma once
#include <string>
#include <utility>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/data/io.hpp"
#include "qdo/asbuilt/fit.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

// --- Inputs ---------------------------------------------------------------------------------

// The design that was built, by spec: a design .h5 file (its level table kept), a run folder (its
// design.h5), lens:NM or flat (no level table). Heights N x N metres, checked against cfg's grid
// and height range (design_heights_from_spec); pitch_m = cfg's. An InputError naming `argument`
// (the spec, or "(missing)" when empty) otherwise.
Design read_fit_design(const SystemConfig& cfg, const std::string& spec, const std::string& argument = "--design");

// What fit_as_built takes besides the options: the design, the measured stack and the fitted set.
struct FitProblem {
  Design design;                        // N x N metres (read_fit_design)
  RealStack measured;                   // bands x S x S, row-major (read_psf_stack_for)
  std::vector<std::string> parameters;  // fit.hpp's names; the design's default set when none were asked for
};
// The design (read_fit_design, naming design_argument), the parameters (empty: default_fit_parameters),
// the measured PSF stack (read_psf_stack_for, naming psf_argument: cfg.bands x S x S), then
// check_fit_parameters: all without a device, in that order.
FitProblem load_fit_problem(const SystemConfig& cfg, const std::string& design_spec, const std::string& psf_path,
                            const std::vector<std::string>& parameters, const std::string& design_argument = "--design",
                            const std::string& psf_argument = "--psf");

// The names a start value may be given for, for a fitted set on this design: level1 .. level(L-1)
// for levels, mask0 .. for masks, dx, dy for offset, sx, sy for shift, and scale, z, d by their
// own names (aperture has none: it is scanned).
std::vector<std::string> fit_start_names(const Design& design, const std::vector<std::string>& parameters);

// FitOptions::start from text "NAME=VALUE,...": NAME one of fit_start_names, each once; VALUE in
// the parameter's own unit, checked against what a built camera can be: lengths in metres unless
// suffixed (nm, um, µm, mm, m: `dx=1.5um`); sx, sy in sensor px (an optional px suffix); scale
// plain. Bounds: dx, dy within the aperture's half width (N pitch / 2), sx, sy within half the
// sensor window, z and d within a factor 10 of the configuration's, level and mask depths within
// [0, 2 x the design's deepest + 1 um], scale in (0, 10]. An InputError naming `argument`, the
// item, the value read and what is allowed, for the first item that is not.
std::vector<std::pair<std::string, double>> parse_fit_starts(const SystemConfig& cfg, const Design& design,
                                                             const std::vector<std::string>& parameters, const std::string& text,
                                                             const std::string& argument = "--start");

// --- The report -----------------------------------------------------------------------------

// Where the inputs came from, as the caller gave them (recorded in fit.json, fit.h5, design.h5).
struct FitSources {
  std::string design;  // the design spec
  std::string psf;     // the measured PSF file
  // The fitted model's sampling report (SamplingReport::summary() of the as-built design and
  // configuration, the paragraph `qdo psf` prints); fit.json's "model_sampling" when not empty.
  std::string model_sampling = {};
  // Raw frames: the frame pixel of the windows' centre ("ROW,COL") and the rule that chose it
  // (CalibrationResult::centre_rule); fit.json's "window_centre_row_col" and "window_centre_rule"
  // and psf.h5's "centre_row_col" and "centre_rule" when not empty.
  std::string centre_row_col = {};
  std::string centre_rule = {};
};

// Whether the fit ended above the design's own loss (or at NaN): then it is no result and no
// as-built design is written.
bool fit_worse_than_design(const FitResult& r);

// fit.json's text (2-space indent, final newline): the sources, every parameter (name, unit,
// design, value, sigma, sigma_jackknife (null when not computed), gradient), the correlation
// (p x p rows), the degenerate pairs, condition, losses, residuals per band, iterations, the
// loss history, the as-built levels, the times (total_s: the whole fit, seconds), counts, notes.
std::string fit_json_text(const SystemConfig& cfg, const FitResult& r, const FitSources& sources, double total_s);

// The fit's files in the folder dir (which must exist), each written atomically: fit.json
// (fit_json_text), fit.h5 (/value, /sigma, /sigma_jackknife, /design_value: one per parameter,
// -1 for a sigma not determined; /correlation p x p; per band /wavelengths_nm, /residual_rel_design,
// /residual_rel_fit; /loss_history; /psf_fit, /psf_measured, /psf_design: bands x S x S, row-major;
// the configuration and the as-built one as root attributes), unless fit_worse_than_design the
// as-built design.h5 and config.json and psf.h5 (r.model_psf as qdo psf writes a stack: the fitted
// model in the measurement's window, the registration included), then fit.png (for up to 6 bands, evenly spaced: measured,
// fitted, design and |fitted - measured|, each divided by its own maximum) and residual.png (the
// relative residual per band of the design and of the fit). measured: bands x S x S, row-major,
// the stack fitted. Returns whether the as-built design.h5 and config.json were written. A stack
// (measured, r.model_psf, r.design_psf) not bands x S x S or a residual not one per band of cfg
// is an InputError naming it, before any file is written.
bool write_fit_outputs(const std::string& dir, const SystemConfig& cfg, const RealStack& measured, const FitResult& r,
                       const FitSources& sources, double total_s);

// The summary, one line each (no newlines): the fitted count, iterations, time (fit_s, seconds)
// and losses; each parameter with its sigma and design value in a reader's unit (nm for heights, mm
// for z and d, um for offsets and the aperture, px for shifts); the note when the curvature sigma
// is unreliable; the pairs not separable; the mean relative residual per band; the times
// (writing_s: the writing of the files, seconds) and counts. The shapes are checked as by
// write_fit_outputs.
std::vector<std::string> fit_summary_lines(const SystemConfig& cfg, const FitResult& r, double fit_s, double writing_s);

}  // namespace qdo
