// qdo command bodies: devices, config, quantize, design, eval, gradcheck (main() and the command table:
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
#include "qdo/psf_source.hpp"
#include "qdo/reconstruct.hpp"
#include "qdo/config.hpp"
#include "qdo/cpu_reference.hpp"
#include "qdo/design_run.hpp"
#include "qdo/eval.hpp"
#include "qdo/gradcheck.hpp"
#include "qdo/doe.hpp"
#include "qdo/error.hpp"
#include "qdo/camera.hpp"
#include "qdo/io.hpp"
#include "qdo/mpi.hpp"
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
  static const std::set<std::string> allowed = {"mode",      "from",      "levels", "placement", "finetune-steps", "lr-decoder",
                                                "checkpoint-every", "max-steps", "device", "out", "precision", "psf", "design"};
  for (const auto& [k, v] : a.opt)
    if (!allowed.count(k))
      reject("--" + k, v, "not with --mode do-finetune (it takes the do run's options; allowed: --from --levels --placement --psf --design "
                          "--finetune-steps --lr-decoder --checkpoint-every --max-steps --precision --device --out)");
  if (!a.has("from")) reject("--from", "(missing)", "the network do run folder to fine-tune (--mode do-finetune)");
  const std::string from = a.get("from");
  DesignRunOptions o = read_run_config(from, "--from", "a run folder written by qdo design (config.json missing)");
  if (o.design.mode != DesignMode::DO || !o.decoder.network())
    reject("--from", from, "a do run with a network decoder (it is a " + to_string(o.design.mode) + " run, decoder " + o.decoder.to_string() +
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
  o.lr_decoder = a.has("lr-decoder") ? parse_double("--lr-decoder", a.get("lr-decoder"), 0, 1, "", true) : last_lr;
  o.checkpoint_every = std::size_t(parse_int("--checkpoint-every", a.get("checkpoint-every", "10"), 1, 100000000));
  o.max_steps = a.has("max-steps") ? parse_int("--max-steps", a.get("max-steps"), 0, 2147483647) : -1;
  if (a.has("precision")) o.precision = precision_from_string(a.get("precision"));
  // do-finetune for the camera as built: the frozen PSF is a measured stack or a fitted design's,
  // checked against the do run's configuration here, before any work.
  if (a.has("psf") && a.has("design"))
    reject("--design", a.get("design"), "either --psf or --design, not both (the frozen PSF comes from one of them)");
  if (a.has("psf")) {
    if (a.has("levels")) reject("--levels", a.get("levels"), "no --levels with --psf (the measured stack is used as it is)");
    o.finetune_psf = a.get("psf");
    (void)read_psf_stack_for(o.cfg, o.finetune_psf, "--psf");
  }
  if (a.has("design")) {
    if (a.has("levels")) reject("--levels", a.get("levels"), "no --levels with --design (the fitted design is used as it is)");
    o.finetune_design = a.get("design");
    (void)read_design_heights_for(o.cfg, o.finetune_design, "--design");
  }
  o.out = a.get("out");
  return o;
}
// An option given explicitly that does nothing in the run's mode, objective or decoder is
// refused, naming where it acts (it was ignored silently).
void check_options_act(const Args& a, const DesignRunOptions& o) {
  const DesignMode m = o.design.mode;
  const bool levels_trained = m == DesignMode::QDOA || m == DesignMode::QDOM;
  const bool network = o.objective == Objective::Network;
  const bool wiener = o.objective == Objective::Wiener || o.objective == Objective::WienerMse || o.objective == Objective::WienerMae;
  struct Rule {
    const char* option;
    bool acts;
    const char* where;
  };
  const Rule rules[] = {
      {"beta", levels_trained, "--mode qdo+a or qdo+m (the regulariser of the trained levels)"},
      {"lr-offsets", levels_trained, "--mode qdo+a or qdo+m (the trained level offsets or mask depths)"},
      {"lr-decoder", network, "a network --decoder"},
      {"gamma", network, "a network --decoder"},
      {"target", o.objective == Objective::PsfTarget, "--objective psf-target"},
      {"wiener-on", wiener, "the Wiener objectives (--objective wiener, wiener-mse or wiener-mae)"},
      {"from", false, "--mode do-finetune"},
      {"finetune-steps", false, "--mode do-finetune"},
      {"psf", false, "--mode do-finetune (the measured PSF the network is fine-tuned for)"},
      {"design", false, "--mode do-finetune (the fitted design whose PSF the network is fine-tuned for)"},
  };
  for (const Rule& r : rules)
    if (a.has(r.option) && !r.acts)
      reject(std::string("--") + r.option, a.get(r.option),
             std::string("an option of ") + r.where + "; this run (--mode " + to_string(m) + ", --objective " + to_string(o.objective) +
                 (network ? ", --decoder " + o.decoder.to_string() : std::string()) + ") would ignore it: leave it out");
}

}  // namespace

int cmd_design(const Args& a) {
  const bool finetune = a.get("mode") == "do-finetune";
  if (finetune && a.has("resume")) {  // a do-finetune run resumes like any run: its stored options
    Args b = a;
    b.opt.erase("mode");
    b.opt.erase("from");
    b.opt.erase("psf");
    b.opt.erase("design");
    return cmd_design(b);
  }
  DesignRunOptions o = finetune ? finetune_options(a) : design_options(a, true);
  const bool resume = a.has("resume");
  if (!resume) o.validate();
  else check_resume_options(a, o);
  if (!resume && !finetune) check_options_act(a, o);
  // Under mpirun rank 0 owns the run folder (run_design); each rank opens its own device.
  const qdo::mpi::World* world = qdo::mpi::world();
  const bool writer = !world || world->rank() == 0;
  if (!resume && writer) claim_out(a, o.out);  // --resume: the run folder is checked by the resume itself
  Runtime rt(process_device(a.get("device")));
  if (a.has("check-gradients")) {
    // A design over several points: each point's chain is the one-point chain of point_config(cfg, p)
    // (the range objective is their mean); checked at the first point.
    DesignRunOptions g = o;
    if (o.cfg.point_count() > 1) {
      g.cfg = point_config(o.cfg, 0);
      g.design.points_per_step = 1;
    }
    std::printf("gradient check on this run's configuration (reduced to N <= 64)%s:\n",
                o.cfg.point_count() > 1 ? ", at object point 0" : "");
    if (const int rc = print_gradcheck(gradcheck(rt, g, g.design.seed)); rc != 0) return rc;
  }
  const auto t0 = std::chrono::steady_clock::now();
  const DesignRunResult r = run_design(rt, o, resume);
  if (!writer) return 0;
  std::printf("design: %ld steps, final loss %.6g, %.1f s; levels (nm):", r.steps_done, r.final_loss, seconds_since(t0));
  for (double l : r.levels_m) std::printf(" %.1f", l * 1e9);
  std::printf("\n");
  if (!r.point_losses.empty()) {  // a design over a range of object points: its spread over the range
    std::printf("%-6s %12s %12s %12s %14s\n", "point", "distance_m", "field_x_deg", "field_y_deg", "loss");
    double worst = r.point_losses[0], sum = 0;
    for (std::size_t p = 0; p < r.point_losses.size(); ++p) {
      const ObjectPoint& pt = r.points[p];
      std::printf("%-6zu %12s %12.4g %12.4g %14.6g\n", p, pt.at_infinity() ? "inf" : to_str(pt.distance_m).c_str(), pt.field_x_deg,
                  pt.field_y_deg, r.point_losses[p]);
      worst = std::max(worst, r.point_losses[p]);
      sum += r.point_losses[p];
    }
    std::printf("range: mean loss %.6g, worst %.6g over %zu points\n", sum / double(r.point_losses.size()), worst,
                r.point_losses.size());
  }
  std::printf("wrote %s/ (config.json checkpoint.h5 log.csv design.h5 psf.h5 design.png psf.png loss.png%s)\n", o.out.c_str(),
              r.point_losses.empty() ? "" : " range.csv range.png");
  return 0;
}

int cmd_eval(const Args& a) {
  EvalOptions e;
  e.run = a.positional;
  e.data = scene_paths(a, "data");
  e.levels = a.has("levels") ? parse_int("--levels", a.get("levels"), 2, 65536) : 0;
  e.placement = placement_from_string(a.get("placement"));
  e.decoder = decoder_fit_from_string(a.get("decoder"), "--decoder");
  if (a.has("decoder-kind")) e.decoder_kind = decoder_spec_from_string(a.get("decoder-kind"));
  e.psf_file = a.get("psf");
  if (a.has("psf") && a.has("levels")) reject("--levels", a.get("levels"), "no --levels with --psf (the PSF file is the measured camera)");
  e.design_file = a.get("design");
  if (a.has("design") && a.has("psf")) reject("--design", e.design_file, "either --psf or --design, not both (the camera as built is one of them)");
  if (a.has("design") && a.has("levels")) reject("--levels", a.get("levels"), "no --levels with --design (the fitted design is used as it is)");
  if (a.has("design")) (void)read_design_heights_for(read_run_config(e.run, "RUN").cfg, e.design_file, "--design");
  e.noise_sigma = a.has("noise-sigma") ? parse_double("--noise-sigma", a.get("noise-sigma"), 0, 10, "(units of full scale)") : -1;
  e.renders = std::size_t(parse_int("--renders", a.get("renders"), 0, 1000));
  e.synthetic_scenes = std::size_t(parse_int("--synthetic-scenes", a.get("synthetic-scenes"), 1, 100000));
  for (const auto& p : split_items(a.get("pixels"))) {
    const auto c = p.find(':');
    if (c == std::string::npos) reject("--pixels", p, "y:x pairs separated by commas");
    e.pixels.push_back({std::size_t(parse_int("--pixels", p.substr(0, c), 0, 1 << 20)),
                        std::size_t(parse_int("--pixels", p.substr(c + 1), 0, 1 << 20))});
  }
  e.precision = precision_from_string(a.get("precision"));
  e.out = a.get("out");
  claim_out(a, e.out);
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
  // A generic state whatever the training recipe: qdo's (random heights away from the quantizer's
  // thresholds, 10 steps an epoch so the checked step 6 lies inside the alpha window). The release
  // recipe's own terms (L_aq over the rings, the pinned top level) are checked by suite recipe.
  b.opt["recipe"] = "qdo";
  DesignRunOptions o = design_options(b);
  o.validate();  // every option checked before the device is opened
  Runtime rt(a.get("device"));
  return print_gradcheck(gradcheck(rt, o, o.design.seed));
}

}  // namespace qdo::cli
