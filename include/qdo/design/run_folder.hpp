// A run folder of `qdo design`, in one place: the names of its files, and every reader of what a
// run leaves (the writers are run_design's, through these names). Layout (run.hpp has the
// checkpoint format and the lock):
//   RUN/config.json          system configuration + design options (written once)
//   RUN/checkpoint.h5        optimiser state, atomic; RUN/checkpoint.prev.h5 the one it replaced;
//                            RUN/checkpoint.refused.h5 a checkpoint a resume refused (kept for inspection);
//                            RUN/checkpoint.next.h5 the next one, written before the rotation (a kill's leftover)
//   RUN/log.csv              one row per step
//   RUN/prior.h5             the scene prior of the Wiener objective
//   RUN/design.h5            the fabrication-ready design; RUN/design_full.h5 the full-precision H_f
//   RUN/psf.h5, RUN/design.png, RUN/psf.png, RUN/loss.png
//   RUN/.lock                held while a process writes the folder
#pragma once
#include <string>
#include <vector>

#include "qdo/design/design.hpp"
#include "qdo/design/design_run_options.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/data/io.hpp"
#include "qdo/decode/wiener.hpp"

namespace qdo {

// A design .h5 for cfg (read_design: N x N at the configured pitch, heights in [0, 2 h_max]); an
// InputError "argument '<argument>' = PATH: ..." otherwise. Checked without a device.
Map2D read_design_heights_for(const SystemConfig& cfg, const std::string& path, const std::string& argument);
// A design given by name, as the commands' --design takes it: lens:NM (a diffractive lens for NM
// nanometres, doe.hpp lens_design), flat, or a design .h5 file (read_design_heights_for). The
// N x N heights, metres; an InputError naming `argument` otherwise.
Map2D design_heights_from_spec(const SystemConfig& cfg, const std::string& spec, const std::string& argument);

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
// A run designed over several object points (a range run, design_run.hpp) is refused unless
// allow_range ("argument '<argument>' = RUN: a run of one object point ..."): the commands that
// consume a run image through one point's PSF stack; qdo design's own --resume check allows it.
DesignRunOptions read_run_config(const std::string& run, const std::string& argument = "run",
                                 const std::string& allowed = "a run folder written by qdo design (config.json missing)",
                                 bool allow_range = false);
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

// The run's scene prior (RUN/prior.h5: /cov bins x B x B with attributes rows, cols).
void save_prior(const std::string& path, const wiener::SpectralPrior& p);
wiener::SpectralPrior load_prior(const std::string& path);

class RunFolder {
 public:
  explicit RunFolder(std::string dir);
  const std::string& dir() const { return dir_; }
  // RUN/<name> for a name of file_names() (or any other name).
  std::string path(const std::string& name) const;
  std::string config_path() const { return path("config.json"); }
  std::string checkpoint_path() const { return path("checkpoint.h5"); }
  std::string log_path() const { return path("log.csv"); }
  std::string prior_path() const { return path("prior.h5"); }
  std::string design_path() const { return path("design.h5"); }
  std::string design_full_path() const { return path("design_full.h5"); }
  std::string psf_path() const { return path("psf.h5"); }
  // Every file a run writes (config.json ... loss.png, the checkpoints; not the lock).
  static const std::vector<std::string>& file_names();

  // read_run_config(dir, argument, allowed).
  DesignRunOptions config(const std::string& argument = "run",
                          const std::string& allowed = "a run folder written by qdo design (config.json missing)") const;
  Design design() const;       // RUN/design.h5 (read_design: checked)
  Design design_full() const;  // RUN/design_full.h5
  // RUN/prior.h5, which must be on the grid_px x grid_px sensor grid (InputError naming the file).
  wiener::SpectralPrior prior(std::size_t grid_px) const;
  ResumeState resume_state() const { return load_resume_state(dir_); }

 private:
  std::string dir_;
};

}  // namespace qdo
