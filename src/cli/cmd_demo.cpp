// `qdo demo`: QDO+A against conventional deep optics (DO) at L levels, designed and evaluated end
// to end, with a summary table and the forward-model figures.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

#include "cli.hpp"
#include "options.hpp"
#include "qdo/data/config.hpp"
#include "qdo/physics/cpu_reference.hpp"
#include "qdo/design/design_run.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/evaluate/eval.hpp"
#include "qdo/data/io.hpp"
#include "qdo/decode/network_decoder.hpp"
#include "qdo/design/run.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/data/scenes.hpp"
#include "qdo/physics/camera.hpp"
#include "qdo/physics/simulator.hpp"

namespace fs = std::filesystem;

namespace qdo::cli {

// The marker demo writes into its run folders (on a rerun it replaces the RunFolder::file_names() there).
const char* const kDemoMarker = ".qdo-demo";

// The main job: a QDO+A design at L levels on synthetic scenes (small preset), compared with
// conventional deep optics (DO: full-precision training, quantized afterwards) on held-out
// synthetic scenes and the real CAVE scenes (--data, unless none); plus the forward-model figures.
static int cmd_demo(const Args& a) {
  const std::string dir = a.get("out", "out/demo");
  const bool network = decoder_spec_from_string(a.get("decoder", "wiener")).network();
  // The datasets, resolved under the data root before anything is written: a missing one is an
  // error naming where qdo looked (--data none leaves the real-scene rows out).
  const std::vector<std::string> train = network ? scene_paths(a, "train-data") : std::vector<std::string>{};
  const std::string real = a.get("data") == "none" ? std::string() : scene_paths(a, "data").front();
  // A demo folder of a qdo from before the output marker (claim_output_dir) is recognised by its
  // run folders' demo markers, and adopted.
  bool earlier_demo = !fs::exists(fs::path(dir) / kOutputMarker);
  bool any_run = false;
  for (const char* r : {"do", "qdoa", "doft"}) any_run = any_run || fs::exists(fs::path(dir) / r / kDemoMarker);
  earlier_demo = earlier_demo && any_run;
  claim_output_dir(dir, "--out", a.command, a.has("into-existing") || earlier_demo);
  DesignRunOptions o;
  o.cfg = preset_config(a.get("preset"));
  o.decoder = decoder_spec_from_string(a.get("decoder", "wiener"));
  o.design.quantizer.levels = parse_int("--levels", a.get("levels"), 2, 65536);
  // The Wiener demo: 15 x 8 steps on synthetic scenes. The network demo: 8 x 50 steps on the CAVE
  // training scenes (the network needs real data and more steps; README: how long it takes).
  o.epochs = std::size_t(parse_int("--epochs", a.get("epochs", network ? "8" : "15"), 2, 100000));
  o.design.steps_per_epoch = std::size_t(parse_int("--steps-per-epoch", a.get("steps-per-epoch", network ? "50" : "8"), 1, 100000));
  o.design.t0_epochs = 0.1 * double(o.epochs);
  o.design.t1_epochs = 0.8 * double(o.epochs);
  // The network demo decays both learning rates as the release does, by 0.8 every 500 steps (the
  // paper's 0.8 per epoch assumes epochs of ~1500 steps; with 50-step epochs it would stop the
  // network learning early).
  if (network) o.design.lr_decay_per_epoch = std::pow(0.8, double(o.design.steps_per_epoch) / 500.0);
  o.precision = precision_from_string(a.get("precision"));
  o.objective = network ? Objective::Network : Objective::Wiener;
  o.data = train;
  const std::size_t finetune_steps = std::size_t(parse_int("--finetune-steps", a.get("finetune-steps"), 1, 100000000));
  struct Job {
    DesignMode mode;
    std::string name;
  };
  std::vector<Job> jobs = {Job{DesignMode::QDOA, "qdoa"}, Job{DesignMode::DO, "do"}};
  if (network) jobs.push_back(Job{DesignMode::DO, "doft"});  // do-finetune of do/ (the network's refit)
  // demo replaces only what it made: its run folders must be absent, empty, or run folders
  // an earlier demo wrote (its marker file inside). All are checked before any work.
  for (const Job& j : jobs) {
    const fs::path run = fs::path(dir) / j.name;
    if (!fs::exists(run)) continue;
    if (!fs::is_directory(run))
      reject("--out", dir, "a folder where '" + run.string() + "' is absent or a run folder qdo demo made (it is a file; move it, or choose another --out)");
    if (!fs::is_empty(run) && !fs::exists(run / kDemoMarker))
      reject("--out", dir, "a folder where '" + run.string() +
                               "' is absent, empty or a run folder qdo demo made (it holds files qdo demo did not write, and demo "
                               "would replace them; move them, or choose another --out)");
  }
  if (network && !network_decoder_available())
    reject("--decoder", o.decoder.to_string(), "wiener: " + network_decoder_unavailable_reason());
  Runtime rt(a.get("device"));
  std::printf("qdo demo: preset %s (N = %zu, %zu bands, z = %.4g m), %d levels, %zu steps per design, device %s\n",
              o.cfg.preset.c_str(), o.cfg.n, o.cfg.bands, o.cfg.sensor_distance_m, o.design.quantizer.levels,
              o.epochs * o.design.steps_per_epoch, rt.info().name.c_str());
  const auto t0 = std::chrono::steady_clock::now();
  for (const Job& j : jobs) {
    DesignRunOptions r = o;
    r.design.mode = j.mode;
    r.out = dir + "/" + j.name;
    if (j.name == "doft") {  // the do run's network trained on with its DOE quantized to L levels, frozen
      r.finetune_from = dir + "/do";
      r.epochs = 1;
      r.design.steps_per_epoch = finetune_steps;
      r.design.t0_epochs = 0;
      r.design.t1_epochs = 1;
      r.lr_decoder = o.lr_decoder * std::pow(o.design.lr_decay_per_epoch, double(o.epochs - 1));
      r.design.lr_decay_per_epoch = 1;
    }
    std::printf("[%s] designing (%s) into %s\n", j.name.c_str(), j.name == "doft" ? "do-finetune" : to_string(j.mode).c_str(), r.out.c_str());
    fs::create_directories(r.out);
    {
      // Under the folder's lock (a concurrent writer is refused): drop the previous demo run's
      // files (a fresh run refuses a folder with a checkpoint), keep anything else, mark it ours.
      const RunLock lock(r.out);
      for (const std::string& f : RunFolder::file_names()) {
        std::error_code ec;
        fs::remove(fs::path(r.out) / f, ec);
      }
      write_text_atomic((fs::path(r.out) / kDemoMarker).string(), "a run folder written by qdo demo; qdo demo may replace its run files\n");
    }
    run_design(rt, r, false);
  }
  struct Cell {
    std::string label, run;
    bool full;
    DecoderFit decoder;
  };
  const std::string L = std::to_string(o.design.quantizer.levels);
  std::vector<Cell> cells = {{"DO, full precision (reference)", "do", true, DecoderFit::Matched},
                             {"DO, " + L + " levels (decoder for H_f, the paper's DO)", "do", false, DecoderFit::Mismatch},
                             {"DO, " + L + " levels (decoder refit)", "do", false, DecoderFit::Matched},
                             {"QDO+A, " + L + " levels", "qdoa", false, DecoderFit::Matched}};
  if (network) cells[2] = {"DO, " + L + " levels (network fine-tuned, do-finetune)", "doft", false, DecoderFit::Matched};
  std::string md = "| design | test set | PSNR [dB] | SSIM | RMSE | ERGAS | deviation [nm] |\n|---|---|---|---|---|---|---|\n";
  std::printf("\n%-46s %-10s %9s %7s %8s %8s %10s\n", "design", "test set", "PSNR", "SSIM", "RMSE", "ERGAS", "dev [nm]");
  for (const std::string& set : {std::string("synthetic"), std::string("CAVE")}) {
    if (set == "CAVE" && real.empty()) continue;
    for (const Cell& c : cells) {
      EvalOptions e;
      e.run = dir + "/" + c.run;
      e.full_precision = c.full;
      e.decoder = c.decoder;
      if (set == "CAVE") e.data = {real};
      e.out = dir + "/eval/" + c.run + "_" + (c.full ? "full" : to_string(c.decoder)) + "_" + set;
      e.precision = o.precision;
      const EvalResult r = evaluate_run(rt, e);
      std::printf("%-46s %-10s %9.2f %7.4f %8.4f %8.2f %10.1f\n", c.label.c_str(), set.c_str(), r.mean.psnr, r.mean.ssim,
                  r.mean.rmse, r.mean.ergas, r.deviation_nm);
      char row[512];
      std::snprintf(row, sizeof row, "| %s | %s | %.2f | %.4f | %.4f | %.2f | %.1f |\n", c.label.c_str(), set.c_str(), r.mean.psnr,
                    r.mean.ssim, r.mean.rmse, r.mean.ergas, r.deviation_nm);
      md += row;
    }
  }
  // Forward-model figures through the QDO+A design: PSF stack and a sensor image of the chart.
  SystemConfig cfg = o.cfg;
  Simulator sim(rt, cfg, o.precision);
  const Design qd = read_design(dir + "/qdoa/design.h5");
  sim.set_heights(qd.height_m);
  sim.compute_psf();
  const RealStack scene = builtin_chart_scene(cfg);
  write_rgb_png(dir + "/chart_scene.png", ref::sensor_integrate(scene, sim.srf()));
  SkipOptions exact;
  exact.exact = true;
  write_rgb_png(dir + "/chart_sensor_qdoa.png", Camera(sim).images({scene}, exact).front());
  md = "# qdo demo\n\nPreset `" + cfg.preset + "`, " + L + " levels, " + std::to_string(o.epochs * o.design.steps_per_epoch) +
       " optimiser steps per design, " +
       (network ? "decoder " + o.decoder.to_string() + " trained with the optics (Eq. 14) on " +
                      (o.data.empty() ? std::string("synthetic scenes") : "the scenes in " + o.data.front() + (o.data.size() > 1 ? " and more" : "")) +
                      "; do-finetune: " + std::to_string(finetune_steps) + " network steps with the quantized DOE frozen.\n"
                : std::string("Wiener decoder, objective: expected MSE under the synthetic-scene prior.\n")) +
       "Test sets: held-out synthetic scenes" + (real.empty() ? "" : std::string(" and the CAVE scenes in ") + real) + ".\n\n" + md;
  write_text_atomic(dir + "/summary.md", md);
  std::printf("\n%.0f s in all. wrote %s/: qdoa/ and do/%s (run folders), eval/ (metrics, renders), summary.md, chart_*.png\n",
              seconds_since(t0), dir.c_str(), network ? " and doft/" : "");
  return 0;
}

namespace {
// qdo demo: its entry in the command table (help order 90).
const RegisterCommand registered_demo(90, [] {
  using namespace opts;
  CommandSpec c{"demo", "QDO+A against conventional deep optics (DO) at L levels, designed and evaluated end to end", "", "",
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
  return c;
});
}  // namespace

}  // namespace qdo::cli
