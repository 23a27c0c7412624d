// qdo demo as a library call (demo.hpp): QDO+A against conventional deep optics at L levels,
// designed, evaluated and summarised.
#include "qdo/evaluate/demo.hpp"

#include <chrono>
#include <cmath>
#include <filesystem>
#include <utility>

#include "qdo/data/io.hpp"
#include "qdo/data/scenes.hpp"
#include "qdo/decode/network_decoder.hpp"
#include "qdo/design/design_run.hpp"
#include "qdo/design/option_inputs.hpp"
#include "qdo/design/run.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/evaluate/eval.hpp"
#include "qdo/physics/camera.hpp"
#include "qdo/physics/cpu_reference.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/strprintf.hpp"
#include "qdo/runtime/util.hpp"

namespace fs = std::filesystem;

namespace qdo {

namespace {

// The marker demo writes into its run folders (on a rerun it replaces the RunFolder::file_names() there).
const char* const kDemoMarker = ".qdo-demo";

// One design run of the demo: its mode and its folder's name under the demo folder.
struct Job {
  DesignMode mode;
  std::string name;
};
std::vector<Job> demo_jobs(bool network) {
  std::vector<Job> jobs = {Job{DesignMode::QDOA, "qdoa"}, Job{DesignMode::DO, "do"}};
  if (network) jobs.push_back(Job{DesignMode::DO, "doft"});  // do-finetune of do/ (the network's refit)
  return jobs;
}

}  // namespace

DemoPlan prepare_demo(const TextOptions& given) {
  TextOptions a = given;  // the defaults of the datasets, where the caller declares none
  for (const auto& [k, v] :
       {std::pair<const char*, const char*>{"data", "cave"}, {"train-data", "cave_train,cave_png"}})
    if (a.defaults[k].empty()) a.defaults[k] = v;
  DemoPlan plan;
  plan.dir = a.get("out", "out/demo");
  const std::string& dir = plan.dir;
  plan.network = decoder_spec_from_string(a.get("decoder", DecoderSpec{}.to_string())).network();
  const bool network = plan.network;
  // The datasets, resolved under the data root before anything is written: a missing one is an
  // error naming where qdo looked (--data none leaves the real-scene rows out).
  const std::vector<std::string> train =
      network ? scene_paths_from_options(a, "train-data") : std::vector<std::string>{};
  plan.real = a.get("data", "cave") == "none" ? std::string() : scene_paths_from_options(a, "data").front();
  // A demo folder of a qdo from before the output marker (claim_output_dir) is recognised by its
  // run folders' demo markers, and adopted.
  bool earlier_demo = !fs::exists(fs::path(dir) / kOutputMarker);
  bool any_run = false;
  for (const char* r : {"do", "qdoa", "doft"}) any_run = any_run || fs::exists(fs::path(dir) / r / kDemoMarker);
  earlier_demo = earlier_demo && any_run;
  claim_output_dir(dir, "--out", "demo", a.has("into-existing") || earlier_demo);
  DesignRunOptions& o = plan.o;
  o.cfg = preset_config(a.get("preset", "small"));
  o.decoder = decoder_spec_from_string(a.get("decoder", DecoderSpec{}.to_string()));
  o.design.quantizer.levels = parse_int("--levels", a.get("levels", "4"), 2, 65536);
  // The Wiener demo: 15 x 8 steps on synthetic scenes. The network demo: 8 x 50 steps on the CAVE
  // training scenes (the network needs real data and more steps; README: how long it takes).
  o.epochs = std::size_t(parse_int("--epochs", a.get("epochs", network ? "8" : "15"), 2, 100000));
  o.design.steps_per_epoch =
      std::size_t(parse_int("--steps-per-epoch", a.get("steps-per-epoch", network ? "50" : "8"), 1, 100000));
  o.design.t0_epochs = 0.1 * double(o.epochs);
  o.design.t1_epochs = 0.8 * double(o.epochs);
  // The network demo decays both learning rates as the release does, by 0.8 every 500 steps (the
  // paper's 0.8 per epoch assumes epochs of ~1500 steps; with 50-step epochs it would stop the
  // network learning early).
  if (network) o.design.lr_decay_per_epoch = std::pow(0.8, double(o.design.steps_per_epoch) / 500.0);
  o.precision = precision_from_string(a.get("precision", "f32"));
  o.objective = network ? Objective::Network : Objective::Wiener;
  o.data = train;
  plan.finetune_steps = std::size_t(parse_int("--finetune-steps", a.get("finetune-steps", "100"), 1, 100000000));
  const std::vector<Job> jobs = demo_jobs(network);
  // demo replaces only what it made: its run folders must be absent, empty, or run folders
  // an earlier demo wrote (its marker file inside). All are checked before any work.
  for (const Job& j : jobs) {
    const fs::path run = fs::path(dir) / j.name;
    if (!fs::exists(run)) continue;
    if (!fs::is_directory(run))
      reject("--out", dir,
             "a folder where '" + run.string() +
                 "' is absent or a run folder qdo demo made (it is a file; move it, or choose another --out)");
    if (!fs::is_empty(run) && !fs::exists(run / kDemoMarker))
      reject("--out", dir,
             "a folder where '" + run.string() +
                 "' is absent, empty or a run folder qdo demo made (it holds files qdo demo did not write, and demo "
                 "would replace them; move them, or choose another --out)");
  }
  if (o.decoder.kind == DecoderSpec::Kind::ResUNet && !network_decoder_available())  // the LibTorch plugin
    reject("--decoder", o.decoder.to_string(), "wiener: " + network_decoder_unavailable_reason());
  return plan;
}

void run_demo(Runtime& rt, const DemoPlan& plan, const std::function<void(const std::string&)>& say) {
  const std::string& dir = plan.dir;
  const DesignRunOptions& o = plan.o;
  const bool network = plan.network;
  const std::string& real = plan.real;
  const std::size_t finetune_steps = plan.finetune_steps;
  say(strprintf("qdo demo: preset %s (N = %zu, %zu bands, z = %.4g m), %d levels, %zu steps per design, device %s\n",
                o.cfg.preset.c_str(), o.cfg.n, o.cfg.bands, o.cfg.sensor_distance_m, o.design.quantizer.levels,
                o.epochs * o.design.steps_per_epoch, rt.info().name.c_str()));
  const auto t0 = std::chrono::steady_clock::now();
  for (const Job& j : demo_jobs(network)) {
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
    say(strprintf("[%s] designing (%s) into %s", j.name.c_str(),
                  j.name == "doft" ? "do-finetune" : to_string(j.mode).c_str(), r.out.c_str()));
    fs::create_directories(r.out);
    {
      // Under the folder's lock (a concurrent writer is refused): drop the previous demo run's
      // files (a fresh run refuses a folder with a checkpoint), keep anything else, mark it ours.
      const RunLock lock(r.out);
      for (const std::string& f : RunFolder::file_names()) {
        std::error_code ec;
        fs::remove(fs::path(r.out) / f, ec);
      }
      write_text_atomic((fs::path(r.out) / kDemoMarker).string(),
                        "a run folder written by qdo demo; qdo demo may replace its run files\n");
    }
    run_design(rt, r, false);
  }
  struct Cell {
    std::string label, run;
    bool full;
    DecoderFit decoder;
  };
  const std::string L = std::to_string(o.design.quantizer.levels);
  std::vector<Cell> cells = {
      {"DO, full precision (reference)", "do", true, DecoderFit::Matched},
      {"DO, " + L + " levels (decoder for H_f, the paper's DO)", "do", false, DecoderFit::Mismatch},
      {"DO, " + L + " levels (decoder refit)", "do", false, DecoderFit::Matched},
      {"QDO+A, " + L + " levels", "qdoa", false, DecoderFit::Matched}};
  if (network)
    cells[2] = {"DO, " + L + " levels (network fine-tuned, do-finetune)", "doft", false, DecoderFit::Matched};
  std::string md =
      "| design | test set | PSNR [dB] | SSIM | RMSE | ERGAS | deviation [nm] |\n|---|---|---|---|---|---|---|\n";
  say("");
  say(strprintf("%-46s %-10s %9s %7s %8s %8s %10s", "design", "test set", "PSNR", "SSIM", "RMSE", "ERGAS", "dev [nm]"));
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
      say(strprintf("%-46s %-10s %9.2f %7.4f %8.4f %8.2f %10.1f", c.label.c_str(), set.c_str(), r.mean.psnr,
                    r.mean.ssim, r.mean.rmse, r.mean.ergas, r.deviation_nm));
      md += strprintf("| %s | %s | %.2f | %.4f | %.4f | %.2f | %.1f |\n", c.label.c_str(), set.c_str(), r.mean.psnr,
                      r.mean.ssim, r.mean.rmse, r.mean.ergas, r.deviation_nm);
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
  md = "# qdo demo\n\nPreset `" + cfg.preset + "`, " + L + " levels, " +
       std::to_string(o.epochs * o.design.steps_per_epoch) + " optimiser steps per design, " +
       (network
            ? "decoder " + o.decoder.to_string() + " trained with the optics (Eq. 14) on " +
                  (o.data.empty() ? std::string("synthetic scenes")
                                  : "the scenes in " + o.data.front() + (o.data.size() > 1 ? " and more" : "")) +
                  "; do-finetune: " + std::to_string(finetune_steps) + " network steps with the quantized DOE frozen.\n"
            : std::string("Wiener decoder, objective: expected MSE under the synthetic-scene prior.\n")) +
       "Test sets: held-out synthetic scenes" + (real.empty() ? "" : std::string(" and the CAVE scenes in ") + real) +
       ".\n\n" + md;
  write_text_atomic(dir + "/summary.md", md);
  say("");
  say(strprintf(
      "%.0f s in all. wrote %s/: qdoa/ and do/%s (run folders), eval/ (metrics, renders), summary.md, chart_*.png\n",
      seconds_since(t0), dir.c_str(), network ? " and doft/" : ""));
}

}  // namespace qdo
