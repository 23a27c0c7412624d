// `qdo design` and `qdo gradcheck` as library calls (the CLI is a thin wrapper; tests call these).
#pragma once
#include <memory>
#include <string>
#include <vector>

#include "qdo/design.hpp"
#include "qdo/network_decoder.hpp"
#include "qdo/runtime.hpp"
#include "qdo/wiener.hpp"

namespace qdo {

struct DesignRunOptions {
  SystemConfig cfg;
  DesignOptions design;
  // wiener (closed-form expected MSE under the scene prior, REFERENCE §3b), wiener-mse,
  // wiener-mae (empirical, on batches of training scenes), psf-target (match `target`),
  // network (the network decoder's loss, Eq. 14: needs `decoder` a network spec, and only it).
  std::string objective = "wiener";
  // The decoder trained with the optics (decoder_spec.hpp): wiener (closed form, nothing to
  // train) or a resunet spec, trained jointly (qdo/joint.hpp) at lr_decoder with weight decay
  // gamma_decoder (Eq. 14's γ), Adam, decayed with the optics' lr_decay_per_epoch.
  std::string decoder = "wiener";
  double lr_decoder = 1e-3;
  double gamma_decoder = 1e-4;
  // do-finetune (issue 13 item 4): the finished network `do` run whose network is trained on for
  // epochs x steps_per_epoch steps with its DOE quantized to this run's levels and frozen. Mode do.
  std::string finetune_from;
  std::string target;                  // psf-target: lens:NM or a design .h5 whose PSF is the target
  std::vector<std::string> data;       // scene files/folders; empty: synthetic scenes
  std::string data_format = "auto";
  std::size_t synthetic_scenes = 12;   // when data is empty
  std::size_t batch = 4;               // scenes per step (wiener-mse, wiener-mae)
  std::size_t epochs = 50;
  double decoder_noise_sigma = 1e-3;   // σ of the Wiener filter (REFERENCE §1 training noise)
  std::size_t prior_bins = 16;
  // Where the `wiener` objective runs: device (kernels/wiener.cl, the run's precision; float32
  // with float64 accumulation where the device has it) or cpu (double, the reference). Run
  // folders written before the device objective existed resume on the CPU.
  std::string wiener_on = "device";
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

struct DesignRunResult {
  long steps_done = 0;
  double final_loss = 0;
  std::vector<double> levels_m;        // the fabricated design's level heights
};
// Runs (or, with resume, continues from RUN/checkpoint.h5 with RUN/config.json's options, of
// which only max_steps and quiet are taken from `o`) and writes the run folder (run.hpp). The
// folder is locked (RunLock) while this runs: a second writer gets an InputError naming the pid.
DesignRunResult run_design(Runtime& rt, const DesignRunOptions& o, bool resume);

// The network of a run that trained one (decoder a resunet spec), in the state of its last
// checkpoint (a finished run: the final network), checksum verified. InputError naming the run
// for a Wiener run, a missing or corrupt state, or a qdo built without LibTorch.
std::unique_ptr<NetworkDecoder> load_run_network(const std::string& run);

// `qdo eval`: reconstruct test scenes through a run's design with its decoder (the Wiener decoder,
// or the run's network).
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
  // Network runs: mismatch is the network as trained; matched only where the evaluated design
  // is the one it was trained with (see evaluate_run).
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
