// `qdo design` and `qdo gradcheck` as library calls (the CLI is a thin wrapper; tests call these).
#pragma once
#include <string>
#include <vector>

#include "qdo/design.hpp"
#include "qdo/runtime.hpp"
#include "qdo/wiener.hpp"

namespace qdo {

struct DesignRunOptions {
  SystemConfig cfg;
  DesignOptions design;
  // wiener (closed-form expected MSE under the scene prior, REFERENCE §3b), wiener-mse,
  // wiener-mae (empirical, on batches of training scenes), psf-target (match `target`).
  std::string objective = "wiener";
  std::string target;                  // psf-target: lens:NM or a design .h5 whose PSF is the target
  std::vector<std::string> data;       // scene files/folders; empty: synthetic scenes
  std::string data_format = "auto";
  std::size_t synthetic_scenes = 12;   // when data is empty
  std::size_t batch = 4;               // scenes per step (wiener-mse, wiener-mae)
  std::size_t epochs = 50;
  double decoder_noise_sigma = 1e-3;   // σ of the Wiener filter (REFERENCE §1 training noise)
  std::size_t prior_bins = 16;
  std::string init = "random";         // random | flat | lens:NM
  std::size_t checkpoint_every = 10;
  long max_steps = -1;                 // stop after this many steps in total (-1: epochs * steps_per_epoch)
  Precision precision = Precision::F32;
  std::string out;                     // the run folder
  bool quiet = false;                  // no progress line
  void validate() const;               // InputError naming the option
};

std::string design_run_options_to_json(const DesignRunOptions& o);
DesignRunOptions design_run_options_from_json(const std::string& text, const std::string& origin);

// What `qdo design --resume` reads from a run folder, all of it checked before any work and
// without a device (run_design uses these; the fuzz target run_folder calls load_resume_state).
// Every refusal is an InputError naming the file (or, for a missing file, the folder).
//
// RUN/config.json: the stored options, parsed and validated; a stored value out of range is
// named as "file 'RUN/config.json': argument 'epochs' = 0: >= 1". out is left as a placeholder.
DesignRunOptions read_run_options(const std::string& config_path);
// The one reader of a finished run's RUN/config.json for the commands that consume it (eval,
// tolerance, export, sweep-psf --adaptive-from, sweep's reuse check, --resume's comparison):
// parsed strictly (design_run_options_from_json) but not validated against this machine, whose
// copy of the training data may have moved. A missing file is an InputError
// "argument '<argument>' = RUN: <allowed>". out is set to RUN.
DesignRunOptions read_run_config(const std::string& run, const std::string& argument = "run",
                                 const std::string& allowed = "a run folder written by qdo design (config.json missing)");
// RUN/log.csv after its header: every row must start "step,loss,"; the rows with step <
// before_step (and their losses) are appended, the others are redone by the resume.
void read_resume_log(const std::string& log_path, long before_step, std::vector<std::string>& rows,
                     std::vector<double>& losses);
struct ResumeState {
  DesignRunOptions options;       // from config.json, out = the folder
  DesignState state;              // checkpoint.h5, checked against the sizes the options imply
  std::vector<std::string> log_rows;  // log.csv rows before state.step (none without a log)
  std::vector<double> losses;
  std::string checkpoint;         // the file `state` came from: checkpoint.h5 or checkpoint.prev.h5
  std::string refused;            // when it is the previous one: why checkpoint.h5 was refused ("" if absent)
};
// config.json and a checkpoint must exist (else "argument 'out' = DIR: a run folder with ...");
// log.csv is optional. save_checkpoint keeps the checkpoint it replaces as checkpoint.prev.h5:
// when checkpoint.h5 is missing or refused (checksum, shape, values) and the previous one loads,
// the state comes from that one (rows of log.csv at or after its step are redone), and
// `refused` says why; if neither loads, the error about checkpoint.h5 is raised. No file is
// changed here.
ResumeState load_resume_state(const std::string& dir);

struct DesignRunResult {
  long steps_done = 0;
  double final_loss = 0;
  std::vector<double> levels_m;        // the fabricated design's level heights
};
// Runs (or, with resume, continues from RUN/checkpoint.h5 with RUN/config.json's options, of
// which only max_steps and quiet are taken from `o`) and writes the run folder (run.hpp). The
// folder is locked (RunLock) while this runs: a second writer gets an InputError naming the pid.
DesignRunResult run_design(Runtime& rt, const DesignRunOptions& o, bool resume);

// The run's scene prior (RUN/prior.h5: /cov bins x B x B with attributes rows, cols).
void save_prior(const std::string& path, const wiener::SpectralPrior& p);
wiener::SpectralPrior load_prior(const std::string& path);

// `qdo eval`: reconstruct test scenes through a run's design with the Wiener decoder.
struct EvalOptions {
  std::string run;                     // the run folder
  std::vector<std::string> data;       // test scenes; empty: held-out synthetic scenes
  std::string data_format = "auto";
  std::size_t synthetic_scenes = 6;
  int levels = 0;                      // > 0: re-quantize design_full.h5 uniformly to L levels (DO at L)
  bool full_precision = false;         // evaluate design_full.h5 itself (the unquantized reference)
  Placement placement = Placement::Inclusive;
  // matched: the decoder is built for the evaluated design; mismatch: for the full-precision
  // design (the paper's DO: a decoder trained for H_f, measurements through the quantized DOE).
  std::string decoder = "matched";
  double noise_sigma = -1;             // measurement noise; < 0: the run's decoder sigma
  std::vector<std::pair<std::size_t, std::size_t>> pixels;  // spectral curves at (y, x); empty: centre
  std::size_t renders = 4;             // scenes rendered as PNG and stored as HDF5
  std::string out;
  Precision precision = Precision::F32;
};
struct EvalRow {
  std::string scene;
  double psnr = 0, psnr_hyper = 0, ssim = 0, rmse = 0, ergas = 0, sam_rad = 0;
};
struct EvalResult {
  std::vector<EvalRow> rows;
  EvalRow mean;
  double deviation_nm = 0;             // mean |H_eval - H_f| (Table 2)
};
EvalResult evaluate_run(Runtime& rt, const EvalOptions& e);

struct GradcheckRow {
  std::string group;
  double max_rel_error = 0, tolerance = 0;
  bool ok() const { return max_rel_error <= tolerance; }
};
// Compares every adjoint with central finite differences (double precision, OpenCL float64
// where the device has it) on random inputs of the configuration: the PSF chain (OpenCL vs CPU
// reference adjoint, and CPU adjoint vs differences), the parameterization and quantizer in
// `mode`, the objective with respect to the PSF. N is capped at 64 to keep it quick.
std::vector<GradcheckRow> gradcheck(Runtime& rt, const DesignRunOptions& o, std::uint64_t seed);

}  // namespace qdo
