// `qdo design` as a library call (the CLI is a thin wrapper; tests call it). The options are
// design_run_options.hpp; `qdo eval` is eval.hpp, `qdo gradcheck` gradcheck.hpp.
#pragma once
#include <memory>
#include <string>
#include <vector>

#include "qdo/design_run_options.hpp"
#include "qdo/network_decoder.hpp"
#include "qdo/runtime.hpp"

namespace qdo {

struct DesignRunResult {
  long steps_done = 0;
  double final_loss = 0;
  std::vector<double> levels_m;        // the fabricated design's level heights
  std::vector<std::string> notes;      // what the run noted on stderr (e.g. a resume with another thread count)
};
// Runs (or, with resume, continues from RUN/checkpoint.h5 with RUN/config.json's options, of
// which only max_steps and quiet are taken from `o`) and writes the run folder (run.hpp). The
// folder is locked (RunLock) while this runs: a second writer gets an InputError naming the pid.
DesignRunResult run_design(Runtime& rt, const DesignRunOptions& o, bool resume);

// The OpenCL device (a Runtime selector) of the process of local rank `local_rank` among
// `devices`: `given` when not empty; else, when there are GPUs, GPU number (local_rank mod their
// count) in list_devices() order, as "P:D"; else "" (Runtime's default).
std::string device_for_rank(const std::string& given, int local_rank, const std::vector<DeviceInfo>& devices);
// This process's device: `given` (--device), else $QDO_DEVICE, else under mpirun with N > 1 ranks
// device_for_rank("", local rank, list_devices()) (one GPU per rank on a node while they last),
// else "" (Runtime's default: the first GPU, else the first CPU).
std::string process_device(const std::string& given);

// The network of a run that trained one (decoder a resunet spec), in the state of its last
// checkpoint (a finished run: the final network), checksum verified. InputError naming the run
// for a Wiener run, a missing or corrupt state, or a qdo built without LibTorch.
std::unique_ptr<NetworkDecoder> load_run_network(const std::string& run);

}  // namespace qdo
