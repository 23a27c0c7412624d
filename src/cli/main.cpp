// qdo command bodies: devices, config, quantize, demo, design, eval, gradcheck (main() and the command table:
// commands.cpp; psf: cmd_psf.cpp; simulate and image: cmd_simulate.cpp).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <future>
#include <iostream>
#include <map>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "qdo/run_folder.hpp"
#include "qdo/config.hpp"
#include "qdo/cpu_reference.hpp"
#include "qdo/design_run.hpp"
#include "qdo/doe.hpp"
#include "qdo/error.hpp"
#include "qdo/camera.hpp"
#include "qdo/io.hpp"
#include "qdo/network_decoder.hpp"
#include "qdo/optics.hpp"
#include "qdo/run.hpp"
#include "qdo/runtime.hpp"
#include "qdo/scenes.hpp"
#include "qdo/release.hpp"
#include "qdo/simulator.hpp"
#include "cli.hpp"

namespace fs = std::filesystem;
using namespace qdo;
using namespace qdo::cli;

namespace qdo::cli {

int cmd_devices(const Args&) {
  const auto devs = list_devices();
  for (const auto& d : devs)
    std::printf("%zu:%zu  %s / %s  [%s]  driver %s  %s  fp64 %s  %u CUs  %.1f GiB\n", d.platform_index, d.device_index,
                d.platform.c_str(), d.name.c_str(), d.type.c_str(), d.driver_version.c_str(), d.version.c_str(),
                d.fp64 ? "yes" : "no", d.compute_units, double(d.global_mem_bytes) / 1073741824.0);
  Runtime rt;
  std::printf("default: %zu:%zu %s\n", rt.info().platform_index, rt.info().device_index, rt.info().name.c_str());
  return 0;
}

int cmd_config(const Args& a) {
  std::cout << config_to_json_text(load_config(a)) << "\n";
  return 0;
}

int cmd_quantize(const Args& a) {
  const SystemConfig cfg = load_config(a);
  if (!a.has("levels")) reject("--levels", "(missing)", "the number of levels L >= 2");
  const std::string out = a.get("out");
  if (out.empty()) reject("--out", "(missing)", "an output .h5 file");
  const Map2D full = load_design(cfg, a.get("design"));
  const QuantSpec qs = load_quantizer(a);
  const Map2D hq = quantize_heights(full, cfg.h_max_m(), qs.q);
  Design d;
  d.height_m = hq;
  d.pitch_m = cfg.pitch_m;
  d.levels_m = qs.q.level_heights_m(cfg.h_max_m());
  if (fs::path(out).has_parent_path()) make_output_dir(fs::path(out).parent_path().string(), "--out");
  write_design(out, d, {{"source", a.get("design")}, {"mode", "DO (post-hoc uniform quantization)"},
                        {"levels", std::to_string(qs.q.levels)}, {"placement", to_string(qs.q.placement)}});
  std::printf("quantized to %d levels (%s): mean |H_q - H_f| = %.3f nm; levels (nm):", qs.q.levels,
              to_string(qs.q.placement).c_str(), quantization_deviation_m(hq, full) * 1e9);
  for (double l : d.levels_m) std::printf(" %.1f", l * 1e9);
  std::printf("\nwrote %s\n", out.c_str());
  return 0;
}


namespace {
int print_gradcheck(const std::vector<GradcheckRow>& rows) {
  bool ok = true;
  std::printf("%-78s %12s %10s  %s\n", "parameter group", "max rel err", "tolerance", "");
  for (const auto& r : rows) {
    std::printf("%-78s %12.3e %10.1e  %s\n", r.group.c_str(), r.max_rel_error, r.tolerance, r.ok() ? "ok" : "FAIL");
    ok = ok && r.ok();
  }
  return ok ? 0 : 5;
}

}  // namespace

namespace {
// qdo design --mode do-finetune --from RUN: the options of the do run RUN with this run's levels
// and placement, frozen optics, finetune-steps network steps in one epoch at the do run's last
// network learning rate (or --lr-decoder), constant. Options that would be dropped are refused.
DesignRunOptions finetune_options(const Args& a) {
  static const std::set<std::string> allowed = {"mode",  "from", "levels", "placement", "finetune-steps", "lr-decoder", "checkpoint-every",
                                                "max-steps", "device", "out", "precision"};
  for (const auto& [k, v] : a.opt)
    if (!allowed.count(k))
      reject("--" + k, v, "not with --mode do-finetune (it takes the do run's options; allowed: --from --levels --placement "
                          "--finetune-steps --lr-decoder --checkpoint-every --max-steps --precision --device --out)");
  if (!a.has("from")) reject("--from", "(missing)", "the network do run folder to fine-tune (--mode do-finetune)");
  const std::string from = a.get("from");
  DesignRunOptions o = read_run_config(from, "--from", "a run folder written by qdo design (config.json missing)");
  if (o.design.mode != DesignMode::DO || o.decoder == "wiener")
    reject("--from", from, "a do run with a network decoder (it is a " + to_string(o.design.mode) + " run, decoder " + o.decoder +
                               "); with the Wiener decoder the refit is qdo eval --decoder matched");
  const double last_lr = o.lr_decoder * std::pow(o.design.lr_decay_per_epoch, double(o.epochs - 1));
  o.finetune_from = from;
  if (a.has("levels")) o.design.quantizer.levels = parse_int("--levels", a.get("levels"), 2, 65536);
  if (a.has("placement")) o.design.quantizer.placement = placement_from_string(a.get("placement"));
  o.design.steps_per_epoch = std::size_t(parse_int("--finetune-steps", a.get("finetune-steps", "200"), 1, 100000000));
  o.epochs = 1;
  o.design.t0_epochs = 0;
  o.design.t1_epochs = 1;
  o.design.lr_decay_per_epoch = 1;
  o.lr_decoder = a.has("lr-decoder") ? parse_double("--lr-decoder", a.get("lr-decoder")) : last_lr;
  o.checkpoint_every = std::size_t(parse_int("--checkpoint-every", a.get("checkpoint-every", "10"), 1, 100000000));
  o.max_steps = a.has("max-steps") ? parse_int("--max-steps", a.get("max-steps"), 0, 2147483647) : -1;
  if (a.has("precision")) o.precision = precision_from_string(a.get("precision"));
  o.out = a.get("out");
  return o;
}
}  // namespace

int cmd_design(const Args& a) {
  const bool finetune = a.get("mode") == "do-finetune";
  if (finetune && a.has("resume")) {  // a do-finetune run resumes like any run: its stored options
    Args b = a;
    b.opt.erase("mode");
    b.opt.erase("from");
    return cmd_design(b);
  }
  DesignRunOptions o = finetune ? finetune_options(a) : design_options(a);
  const bool resume = a.has("resume");
  if (!resume) o.validate();
  else check_resume_options(a, o);
  Runtime rt(a.get("device"));
  if (a.has("check-gradients")) {
    std::printf("gradient check on this run's configuration (reduced to N <= 64):\n");
    if (const int rc = print_gradcheck(gradcheck(rt, o, o.design.seed)); rc != 0) return rc;
  }
  const auto t0 = std::chrono::steady_clock::now();
  const DesignRunResult r = run_design(rt, o, resume);
  std::printf("design: %ld steps, final loss %.6g, %.1f s; levels (nm):", r.steps_done, r.final_loss, seconds_since(t0));
  for (double l : r.levels_m) std::printf(" %.1f", l * 1e9);
  std::printf("\nwrote %s/ (config.json checkpoint.h5 log.csv design.h5 psf.h5 design.png psf.png loss.png)\n", o.out.c_str());
  return 0;
}

int cmd_eval(const Args& a) {
  EvalOptions e;
  e.run = a.positional;
  e.data = split_list(a.get("data"));
  e.levels = a.has("levels") ? parse_int("--levels", a.get("levels"), 2, 65536) : 0;
  e.placement = placement_from_string(a.get("placement"));
  e.decoder = a.get("decoder");
  e.noise_sigma = a.has("noise-sigma") ? parse_double("--noise-sigma", a.get("noise-sigma")) : -1;
  e.renders = std::size_t(parse_int("--renders", a.get("renders"), 0, 1000));
  e.synthetic_scenes = std::size_t(parse_int("--synthetic-scenes", a.get("synthetic-scenes"), 1, 100000));
  for (const auto& p : split_list(a.get("pixels"))) {
    const auto c = p.find(':');
    if (c == std::string::npos) reject("--pixels", p, "y:x pairs separated by commas");
    e.pixels.push_back({std::size_t(parse_int("--pixels", p.substr(0, c), 0, 1 << 20)),
                        std::size_t(parse_int("--pixels", p.substr(c + 1), 0, 1 << 20))});
  }
  e.precision = precision_from_string(a.get("precision"));
  e.out = a.get("out");
  Runtime rt(a.get("device"));
  const EvalResult r = evaluate_run(rt, e);
  std::printf("%-28s %8s %8s %7s %8s %8s %8s\n", "scene", "PSNR", "PSNR-H", "SSIM", "RMSE", "ERGAS", "SAM");
  for (const auto& row : r.rows)
    std::printf("%-28s %8.2f %8.2f %7.4f %8.4f %8.2f %8.4f\n", row.scene.c_str(), row.psnr, row.psnr_hyper, row.ssim, row.rmse,
                row.ergas, row.sam_rad);
  std::printf("%-28s %8.2f %8.2f %7.4f %8.4f %8.2f %8.4f\n", "mean", r.mean.psnr, r.mean.psnr_hyper, r.mean.ssim, r.mean.rmse,
              r.mean.ergas, r.mean.sam_rad);
  std::printf("quantization deviation %.3f nm; wrote %s/ (metrics.csv metrics.json reconstructions.h5 render_*.png spectra_*.png)\n",
              r.deviation_nm, e.out.c_str());
  return 0;
}

int cmd_gradcheck(const Args& a) {
  Args b = a;
  b.opt["out"] = "(unused)";
  b.opt["epochs"] = "10";
  DesignRunOptions o = design_options(b);
  o.validate();  // every option checked before the device is opened
  Runtime rt(a.get("device"));
  return print_gradcheck(gradcheck(rt, o, o.design.seed));
}

// The marker demo writes into its run folders (on a rerun it replaces the RunFolder::file_names() there).
const char* const kDemoMarker = ".qdo-demo";

// The main job: a QDO+A design at L levels on synthetic scenes (small preset), compared with
// conventional deep optics (DO: full-precision training, quantized afterwards) on held-out
// synthetic scenes and, when present, the real CAVE scenes; plus the forward-model figures.
int cmd_demo(const Args& a) {
  const std::string dir = out_dir(a, "out/demo");
  DesignRunOptions o;
  o.cfg = preset_config(a.get("preset"));
  o.decoder = decoder_spec_from_string(a.get("decoder", "wiener")).to_string();
  const bool network = o.decoder != "wiener";
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
  o.objective = network ? "network" : "wiener";
  if (network) {
    for (const std::string& d : split_list(a.get("train-data")))
      if (fs::exists(d)) o.data.push_back(d);
    if (o.data.empty())
      std::fprintf(stderr, "qdo demo: note: no --train-data found (%s); the network trains on synthetic scenes\n",
                   a.get("train-data").c_str());
  }
  const std::size_t finetune_steps = std::size_t(parse_int("--finetune-steps", a.get("finetune-steps"), 1, 100000000));
  std::string real = a.get("data");
  if (!fs::exists(real)) real.clear();
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
    reject("--decoder", o.decoder, "wiener: " + network_decoder_unavailable_reason());
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
    std::string decoder;
  };
  const std::string L = std::to_string(o.design.quantizer.levels);
  std::vector<Cell> cells = {{"DO, full precision (reference)", "do", true, "matched"},
                             {"DO, " + L + " levels (decoder for H_f, the paper's DO)", "do", false, "mismatch"},
                             {"DO, " + L + " levels (decoder refit)", "do", false, "matched"},
                             {"QDO+A, " + L + " levels", "qdoa", false, "matched"}};
  if (network) cells[2] = {"DO, " + L + " levels (network fine-tuned, do-finetune)", "doft", false, "matched"};
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
      e.out = dir + "/eval/" + c.run + "_" + (c.full ? "full" : c.decoder) + "_" + set;
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
       (network ? "decoder " + o.decoder + " trained with the optics (Eq. 14) on " +
                      (o.data.empty() ? std::string("synthetic scenes") : "the scenes in " + o.data.front() + (o.data.size() > 1 ? " and more" : "")) +
                      "; do-finetune: " + std::to_string(finetune_steps) + " network steps with the quantized DOE frozen.\n"
                : std::string("Wiener decoder, objective: expected MSE under the synthetic-scene prior.\n")) +
       "Test sets: held-out synthetic scenes" + (real.empty() ? "" : std::string(" and the CAVE scenes in ") + real) + ".\n\n" + md;
  write_text_atomic(dir + "/summary.md", md);
  std::printf("\n%.0f s in all. wrote %s/: qdoa/ and do/%s (run folders), eval/ (metrics, renders), summary.md, chart_*.png\n",
              seconds_since(t0), dir.c_str(), network ? " and doft/" : "");
  return 0;
}

}  // namespace qdo::cli
