// Run folders of `qdo design`: atomic checkpoints that resume bit-identically, a CSV log, and
// a line plot of the loss. Layout:
//   RUN/config.json      system configuration + design options (written once)
//   RUN/checkpoint.h5    optimiser state (/w, /offsets, Adam moments, /step), atomic
//   RUN/log.csv          one row per step: step, loss, loss_aq, alpha, lr, step_s, level heights
//   RUN/design.h5        the fabrication-ready height map (only the L level heights) + /levels_m
//   RUN/psf.h5, RUN/*.png
//   RUN/.lock            held (flock) by the process writing the folder; holds its pid
#pragma once
#include <string>
#include <vector>

#include "qdo/design/design.hpp"
#include "qdo/runtime/error.hpp"

namespace qdo {

// Ownership of a run folder: an exclusive, non-blocking flock(2) on DIR/.lock, held for the
// object's lifetime, with the holder's pid written in the file. A second writer (another
// process, or another RunLock on the same folder in this process) gets an InputError naming
// the folder and the holder's pid. The kernel drops the lock when the holder dies (even by
// kill -9), so a stale .lock file never blocks a --resume. The file itself is left in place
// (unlinking a lock file races with a writer that has just opened it).
// `what` names the argument in the error (e.g. "out"). A folder held by another writer is a
// RunBusyError (an InputError), so that a caller may wait for it (the sweep's shared runs).
class RunBusyError : public InputError {
 public:
  using InputError::InputError;
};
class RunLock {
 public:
  explicit RunLock(const std::string& dir, const std::string& what = "out");
  ~RunLock();
  RunLock(const RunLock&) = delete;
  RunLock& operator=(const RunLock&) = delete;
  const std::string& path() const { return path_; }

 private:
  std::string path_;
  int fd_ = -1;
};

// Writes the checkpoint so that at every instant `path` holds a complete checkpoint (a kill -9
// anywhere leaves the old or the new one): the new one is written whole to
// checkpoint_next_path(path), the one it replaces is kept as checkpoint_prev_path(path) (a hard
// link, or a copy, renamed into place), then the new one is renamed onto `path`. A checkpoint
// damaged after writing thus still leaves the previous good state to resume from.
void save_checkpoint(const std::string& path, const DesignState& s);
// ".../checkpoint.h5" -> ".../checkpoint.prev.h5" (any name: ".prev" before the extension).
std::string checkpoint_prev_path(const std::string& path);
// ".../checkpoint.h5" -> ".../checkpoint.next.h5": where the next checkpoint is written first.
std::string checkpoint_next_path(const std::string& path);
// Throws InputError naming the file and dataset when missing, corrupt or mis-shaped
// (expected_w and expected_levels are the sizes the run's configuration implies).
// mask_depths: /offsets holds qdo+m's normalised mask depths (each in [0, 1], sum <= 1) instead of
// the adaptive offsets of the other modes (the pinned level's 0: level 0, or level L - 1 with
// pin_top; |a_l| <= 1, or 0.2 at L = 2).
DesignState load_checkpoint(const std::string& path, std::size_t expected_w, std::size_t expected_levels,
                            bool mask_depths = false, bool pin_top = false);



}  // namespace qdo
