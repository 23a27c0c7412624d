// What the fab commands (qdo export, tolerance, fabricate) read and report, beside fab.hpp's work:
// the design they take (a run folder of qdo design or a design .h5 file), the files of one camera
// as built (fabricate), and the text summaries of each result. The commands are these calls and
// fab.hpp's; other callers (Python, scripts) reuse them.
#pragma once
#include <functional>
#include <map>
#include <string>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/data/io.hpp"
#include "qdo/fab/fab.hpp"

namespace qdo::fab {

// --- The design a fab command takes ----------------------------------------------------------

struct DesignSource {
  SystemConfig cfg;             // the run's configuration, or the caller's for a design file
  Design design;                // N x N metres (read_design: checked)
  std::string design_path;      // RUN/design.h5, or the file
  bool from_run = false;        // a run folder (else a design file)
  // An export manifest's provenance: source, run, mode, levels, placement, objective, seed for a
  // run; source, levels (the level table's size) for a file.
  std::map<std::string, std::string> provenance;
};
// src a folder: a run folder of qdo design, its configuration (read_run_config: RUN/config.json,
// a run of one object point) and RUN/design.h5. Otherwise a design .h5 file, which must exist,
// read with the configuration file_config() returns (called only for a file, after that check, so
// the caller's own refusals about its configuration come after it); with check_grid the file
// must hold N x N samples at the configuration's pitch ("DESIGN" named with the file). Every
// refusal is an InputError naming `argument` and src otherwise.
DesignSource read_design_source(const std::string& src, const std::function<SystemConfig()>& file_config, bool check_grid,
                                const std::string& argument = "RUN");

// --- One camera as built (fabricate) -----------------------------------------------------------

// truth.json's text (2-space indent, final newline): the source, the scheme, the seed, trial and
// error bounds of o, per mask its etch depth, depth error and overlay shift, per level its design
// and realised heights and pixels, the true values in qdo fit's names and units (fit_parameters:
// levelL (L >= 1) = realised level L - realised level 0 + design level 0, dx, dy = o's offset, z =
// the as-built DOE-sensor distance, metres) and the design's and as-built sensor distances.
// design_cfg: the configuration the design was made for; source: the design file's path.
std::string as_built_truth_json_text(const AsBuiltCamera& cam, const SystemConfig& design_cfg, const AsBuiltOptions& o,
                                     const std::string& source);
// The camera's files in the folder dir (which must exist), each written atomically: design.h5
// (the as-built relief), config.json (the as-built geometry), truth.json (as_built_truth_json_text),
// heights.png (the as-built heights) and height_error.png (as built minus designed; design: the
// design fabricated, N x N metres as cam.design).
void write_as_built_outputs(const std::string& dir, const AsBuiltCamera& cam, const Design& design, const SystemConfig& design_cfg,
                            const AsBuiltOptions& o, const std::string& source);
// The summary, one line each (no newlines): the source, scheme and mask count; per mask its etch
// depth, depth error and overlay (nm, um); per level its design and realised height (nm); the
// relief offset (um) and the DOE-sensor distance design -> as built (m).
std::vector<std::string> as_built_summary_lines(const AsBuiltCamera& cam, const SystemConfig& design_cfg, const AsBuiltOptions& o,
                                                const std::string& source);

// --- Summaries of export and tolerance ----------------------------------------------------------

// An export: the scheme, method, mask layers, blank top (nm), polygons and vertices; per mask its
// layer, name, etch depth (nm) and, greyscale, its dose; the read-back check. One line each.
std::vector<std::string> export_summary_lines(const ExportResult& r);
// A tolerance study: the scheme, mask count and the nominal PSNR and SSIM, then a table of the
// scenarios (trials, PSNR mean, std, worst, SSIM mean with the calibrated decoder; PSNR mean and
// worst with the nominal one) under its header. One line each.
std::vector<std::string> tolerance_summary_lines(const ToleranceResult& r);

}  // namespace qdo::fab
