// The options of a `qdo design` run (DesignRunOptions) and their typed parts. Each part is parsed
// once where it enters: the options as typed (design_run_text.hpp) and a run's config.json
// (design_run_options_from_json), which holds each as the string its to_string() writes (the
// strings the options always had there, so run folders of earlier versions read the same).
#pragma once
#include <cstddef>
#include <string>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/decode/decoder_spec.hpp"
#include "qdo/design/joint_sampling.hpp"
#include "qdo/decode/network_decoder.hpp"
#include "qdo/design/design.hpp"
#include "qdo/runtime/runtime.hpp"

namespace qdo {

// The design objective:
//   wiener                  the closed-form expected MSE under the scene prior (REFERENCE §3b)
//   wiener-mse, wiener-mae  empirical, on batches of training scenes
//   psf-target              match the target's PSF (TargetSpec)
//   network                 the network decoder's loss (Eq. 14): needs a network decoder, and only it
enum class Objective { Wiener, WienerMse, WienerMae, PsfTarget, Network };
// InputError "argument '<argument>' = S: one of wiener, ..." for any other S.
Objective objective_from_string(const std::string& s, const std::string& argument = "objective");
std::string to_string(Objective o);

// Where the `wiener` objective runs: device (kernels/wiener.cl, the run's precision; float32 with
// float64 accumulation where the device has it) or cpu (double, the reference).
enum class WienerOn { Device, Cpu };
WienerOn wiener_on_from_string(const std::string& s, const std::string& argument = "wiener_on");
std::string to_string(WienerOn w);

// The initial design: random heights in [0, h_max] (seeded), flat (all zero), or lens:NM, the
// diffractive lens for NM nanometres (lens_design).
// half: every parameter at w = -1e-4, i.e. u = 0.5 - 5e-5: the release's initial design (w = 1e-4
// on its etch-depth axis, u_release = 1 - u), half the quantization height, just off the
// quantizer's decision threshold for even L.
struct InitSpec {
  enum class Kind { Random, Flat, Lens, Half } kind = Kind::Random;
  double wavelength_nm = 0;       // Kind::Lens: finite, 100 ... 20000
  std::string wavelength_text;    // Kind::Lens: NM as written ("550.0"); empty: written from wavelength_nm
  std::string to_string() const;  // random, flat or lens:NM (NM as written, else the shortest decimal)
};
// InputError naming `argument`: "random, flat, half or lens:NM", or the range of NM.
InitSpec init_spec_from_string(const std::string& s, const std::string& argument = "init");

// The target of the psf-target objective: lens:NM (the PSF of the diffractive lens for NM nm) or
// a design .h5 file (its PSF); None ("") where the objective has no target.
struct TargetSpec {
  enum class Kind { None, Lens, File } kind = Kind::None;
  double wavelength_nm = 0;       // Kind::Lens: finite, 100 ... 20000
  std::string wavelength_text;    // Kind::Lens: NM as written; empty: written from wavelength_nm
  std::string path;               // Kind::File (checked to exist by DesignRunOptions::validate)
  std::string to_string() const;  // "", lens:NM (as InitSpec) or the path
};
// "" -> None, lens:... -> Lens (InputError naming `argument` for a bad NM), anything else -> File.
TargetSpec target_spec_from_string(const std::string& s, const std::string& argument = "target");

struct DesignRunOptions {
  // The system. With object_points of P > 1 points the run is a design over a range: the
  // points are training conditions, design.points_per_step of them per step, the step's loss the
  // mean of the objective over those points' PSF stacks (run_design). Objectives
  // wiener, wiener-mse, wiener-mae and psf-target (its target at each point: the target's PSF at
  // that point, lens:NM focused for that point's distance); a network decoder is refused.
  SystemConfig cfg;
  DesignOptions design;
  Objective objective = Objective::Wiener;
  // The decoder trained with the optics (decoder_spec.hpp): wiener (closed form, nothing to
  // train) or a resunet spec, trained jointly (qdo/design/joint.hpp) at lr_decoder with weight decay
  // gamma_decoder (Eq. 14's γ), Adam, decayed with the optics' lr_decay_per_epoch.
  DecoderSpec decoder;
  double lr_decoder = 1e-3;
  double gamma_decoder = 1e-4;
  // The network's batch-norm constants and last initialiser (network_decoder.hpp; recipe items
  // batch-norm and final-init).
  NetworkStyle network_style;
  // The network's training data (joint.hpp; recipe items noise-at and patches): the sensor noise
  // decoder_noise_sigma drawn on the band images before the response and the sensor's area
  // resampling (the release's) instead of on the RGB image; the release's fixed patches in order
  // instead of random crops with flips and transposes.
  JointSampling sampling;
  // The training recipe these options were filled from (recipe.hpp: "release" or "qdo"); a name
  // only: every item it sets is its own field here and in config.json. "custom" when unknown.
  std::string recipe = "qdo";
  // Fabrication height noise (design.height_noise_m) also on the PSF a run's evaluation measures
  // through (the release draws it on every forward pass, test included): one draw per test scene.
  bool height_noise_at_test = false;
  // do-finetune: the finished network `do` run whose network is trained on for
  // epochs x steps_per_epoch steps with its DOE quantized to this run's levels and frozen. Mode do.
  std::string finetune_from;
  // do-finetune for the camera as built: the frozen PSF the network is trained
  // on is a measured stack (finetune_psf: qdo calibrate's or qdo psf's psf.h5, checked against
  // the configuration's bands and sensor grid) or a fitted as-built design's (finetune_design: a
  // design .h5, simulated with this configuration), instead of the do run's quantized DOE. At most
  // one; only with finetune_from. Recorded in config.json, split.json and design.h5's provenance.
  std::string finetune_psf, finetune_design;
  TargetSpec target;                   // psf-target: lens:NM or a design .h5 whose PSF is the target
  std::vector<std::string> data;       // scene files/folders; empty: synthetic scenes
  std::string data_format = "auto";
  std::size_t synthetic_scenes = 12;   // when data is empty
  std::size_t batch = 4;               // scenes per step (wiener-mse, wiener-mae)
  std::size_t epochs = 50;
  double decoder_noise_sigma = 1e-3;   // σ of the Wiener filter (REFERENCE §1 training noise)
  std::size_t prior_bins = 16;
  // Run folders written before the device objective existed resume on the CPU.
  WienerOn wiener_on = WienerOn::Device;
  InitSpec init;
  std::size_t checkpoint_every = 10;
  long max_steps = -1;                 // stop after this many steps in total (-1: epochs * steps_per_epoch)
  Precision precision = Precision::F32;
  std::string out;                     // the run folder
  bool quiet = false;                  // no progress line
  void validate() const;               // InputError naming the option
};

// The initial parameters of the run's parameterization (parameter_count of them, metres): random
// heights in [0, h_max] drawn with seed + 17, zeros (flat), half (every one at h_max (1 - 1e-4) / 2),
// or the lens's heights sampled as the parameterization reads them (lens:NM). Defined in
// src/design/design_problem.cpp.
std::vector<double> initial_params(const DesignRunOptions& o);

// config.json's text: {"system": config_to_json_text(cfg), "design": {every option but cfg, out,
// max_steps and quiet, each typed part as its to_string()}}. from_json reads it strictly
// (InputError naming the file `origin` and the key); fields missing from run folders of earlier
// versions take the values those runs had (psf_path 2d, wiener_on cpu, decoder wiener, ...).
std::string design_run_options_to_json(const DesignRunOptions& o);
DesignRunOptions design_run_options_from_json(const std::string& text, const std::string& origin);

}  // namespace qdo
