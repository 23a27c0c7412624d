// `qdo demo`: QDO+A against conventional deep optics (DO) at L levels, designed and evaluated end
// to end, with a summary table and the forward-model figures. The work is the library's
// (include/qdo/evaluate/demo.hpp); this file opens the device and prints its lines.
#include <cstdio>
#include <string>

#include "cli.hpp"
#include "qdo/decode/decoder_spec.hpp"
#include "qdo/evaluate/demo.hpp"
#include "qdo/runtime/runtime.hpp"

namespace qdo::cli {

static int cmd_demo(const Args& a) {
  const DemoPlan plan = prepare_demo(a);  // every option checked, the datasets found, --out claimed
  Runtime rt(a.get("device"));
  run_demo(rt, plan, [](const std::string& line) { std::printf("%s\n", line.c_str()); });
  return 0;
}

// qdo demo: its entry in the command table (help order 90).
const RegisterCommand registered_demo(90, [] {
  using namespace opts;
  return CommandSpec{"demo", "QDO+A against conventional deep optics (DO) at L levels, designed and evaluated end to end", "", "",
                   {opt("preset", "system preset: paper or small", "small"), opt("levels", "height levels L, an integer in [2, 65536]", "4"),
                    opt("epochs", "epochs per design, an integer in [2, 100000] (default: 15; 8 with a network decoder)"),
                    opt("steps-per-epoch", "optimiser steps per epoch, an integer in [1, 100000] (default: 8; 50 with a network decoder)"),
                    opt("decoder", "decoder: wiener (closed form, trained on synthetic scenes) or a network spec (resunet, ...; "
                                   "trained with the optics on --train-data; about 10 minutes on 2 cores with resunet)", DecoderSpec{}.to_string()),
                    opt("train-data", "training scenes of the network decoder: dataset names under the data root or paths, "
                                      "comma-separated (each must exist)", "cave_train,cave_png"),
                    opt("finetune-steps", "network decoder: do-finetune steps (doft/), an integer in [1, 100000000]", "100"),
                    opt("data", "real test scenes: a dataset name under the data root or a path; none leaves the real-scene rows out", "cave"),
                    data_root(), precision(), device(),
                    opt("out", "output folder (created; its qdoa/ and do/ (and doft/) run folders are replaced)", "out/demo")},
                   cmd_demo, true};
});

}  // namespace qdo::cli
