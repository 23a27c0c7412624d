// qdo demo as a library call: a QDO+A design at L levels on synthetic scenes (small preset)
// against conventional deep optics (DO: full-precision training, quantized afterwards), evaluated
// on held-out synthetic scenes and real CAVE scenes (unless data is none), with a summary table
// (summary.md) and the forward-model figures (chart_scene.png, chart_sensor_qdoa.png). With a
// network decoder, the network trains with the optics on the training scenes, and doft/ is the do
// run's network fine-tuned with its DOE quantized and frozen.
#pragma once
#include <cstddef>
#include <functional>
#include <string>

#include "qdo/design/design_run_options.hpp"
#include "qdo/runtime/parse.hpp"
#include "qdo/runtime/runtime.hpp"

namespace qdo {

struct DemoPlan {
  std::string dir;       // the demo folder (claimed)
  DesignRunOptions o;    // the options every design run shares
  bool network = false;  // a network decoder
  std::string real;      // the real test scenes (empty: none)
  std::size_t finetune_steps = 100;
};

// The demo's options as a user typed them (TextOptions: out (default out/demo), preset, levels,
// epochs, steps-per-epoch, decoder, train-data, finetune-steps, data, precision, into-existing),
// each checked (InputError naming the option as typed), the datasets resolved under the data root,
// and the folder claimed as command demo's (claim_output_dir; a demo folder of an earlier qdo, its
// run folders marked, is adopted). Its run folders qdoa/, do/ (and doft/) must be absent, empty or
// an earlier demo's. Nothing runs on the device.
DemoPlan prepare_demo(const TextOptions& a);
// The designs, their evaluation and the figures into plan.dir; every progress and table line
// (without "\n") goes to say, the last one the seconds in all and the files written.
void run_demo(Runtime& rt, const DemoPlan& plan, const std::function<void(const std::string&)>& say);

}  // namespace qdo
