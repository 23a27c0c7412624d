// `qdo design` as a library call (the CLI is a thin wrapper; tests call it). The options are
// design_run_options.hpp; `qdo eval` is eval.hpp, `qdo gradcheck` gradcheck.hpp.
#pragma once
#include <memory>
#include <string>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/design/design_run_options.hpp"
#include "qdo/runtime/types.hpp"
#include "qdo/decode/network_decoder.hpp"
#include "qdo/runtime/runtime.hpp"

namespace qdo {

struct DesignRunResult {
  long steps_done = 0;
  double final_loss = 0;
  std::vector<double> levels_m;        // the fabricated design's level heights
  std::vector<std::string> notes;      // what the run noted on stderr (e.g. a resume with another thread count)
  // A design over a range of object points (config object_points, P > 1): the points and the
  // fabricated design's objective at each (what RUN/range.csv holds). Empty for a one-point run.
  std::vector<ObjectPoint> points;
  std::vector<double> point_losses;
};
// Runs (or, with resume, continues from RUN/checkpoint.h5 with RUN/config.json's options, of
// which only max_steps and quiet are taken from `o`) and writes the run folder (run.hpp). The
// folder is locked (RunLock) while this runs: a second writer gets an InputError naming the pid.
//
// A run whose configuration lists P > 1 object points is a design over that range: each step
// trains on design.points_per_step of them (Designer::range_step: the mean of the objective over
// their PSF stacks, one 2-D or radial source per point, point_config(cfg, p)).
// log.csv then has two more columns, points (the indices trained on, ';'-separated) and
// point_losses (the objective at each); at the end RUN/range.csv holds, per point, its distance,
// field angles, the fabricated design's objective there (design_point_losses) and the number of
// steps that trained on it, and range.png plots that loss against the point index. psf.h5 and
// psf.png hold the PSF at point 0.
DesignRunResult run_design(Runtime& rt, const DesignRunOptions& o, bool resume);

// The objective (without beta L_aq) of the design `height_m` (N x N, metres, row-major) at every
// object point of o.cfg (one value for a one-point configuration), each point's PSF computed on the
// 2-D path; the problem (scenes, prior, targets) built as run_design builds it, wiener-mse and
// wiener-mae on the batch of step epochs x steps_per_epoch. What a range run writes to range.csv,
// for any design: designs trained on different points compare on the same points.
std::vector<double> design_point_losses(Runtime& rt, const DesignRunOptions& o, const Map2D& height_m);

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
