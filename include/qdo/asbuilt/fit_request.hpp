// qdo fit as a library call: the as-built DOE (fit.hpp) from the design that was built and a
// measured PSF stack, or from the raw point-source frames themselves (fit_raw.hpp). The options are
// read as a user typed them (TextOptions: preset, config, design, psf, frames, darks, white,
// centre, fit, iterations, lateral-starts, refine-starts, start, tolerance, precision, model-padding:
// option_inputs.hpp's apply_model_padding, which sets cfg.padding_px, the model's window) and every
// input is read and checked before any device work: refusals are InputErrors naming the option as
// typed ("--psf"), the value and what is allowed. The design and the measured stack are PSF specs
// (psf_spec.hpp): --design the design that was built (read_fit_design: its level table kept), --psf
// a PSF stack file read as every command reads one (read_psf_input).
#pragma once
#include <functional>
#include <string>
#include <vector>

#include "qdo/asbuilt/fit.hpp"
#include "qdo/asbuilt/fit_raw.hpp"
#include "qdo/asbuilt/fit_report.hpp"
#include "qdo/design/psf_spec.hpp"
#include "qdo/physics/calibrate.hpp"
#include "qdo/runtime/parse.hpp"
#include "qdo/runtime/runtime.hpp"

namespace qdo {

struct FitRequest {
  SystemConfig cfg;
  Precision precision = Precision::F64;
  PsfSpec design;                    // Kind::Design: the design that was built
  PsfSpec measured;                  // Kind::File: the measured stack; Kind::Run (empty) with raw frames
  std::string frames, darks, white;  // the raw frames' folders (frames empty: the --psf stack is the data)
  CalibrationOptions calibration;    // the raw frames' reduction (white, centre)
  FitOptions options;                // without progress
  FitProblem problem;     // the design, the fitted set, the measured stack (bands x S x S; empty with raw frames)
  RawPsfWindows windows;  // raw frames: each band's window
  std::vector<std::string> notes;  // what reading the raw frames found, one line each (no newline)
};
FitRequest fit_request_from_options(const TextOptions& a);

struct FitReport {
  std::string text;      // fit_summary_lines, one per line, and the files written
  std::string warning;   // "NOT CONVERGED: ..." when the iteration limit ended the fit, else empty
  bool written = false;  // the as-built design.h5 and config.json were written (write_fit_outputs)
  std::string refusal;   // when not written: why the fit is no result (the caller fails, exit 3)
};
// The fit (on the device) and its files in `dir` (which must exist, claimed by the caller);
// progress (when set) gets a line per iteration.
FitReport run_fit_request(Runtime& rt, const FitRequest& q, const std::string& dir,
                          const std::function<void(const std::string&)>& progress = {});

}  // namespace qdo
