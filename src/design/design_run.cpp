// `qdo design` as a library call: the run loop (design_run.hpp). The options and their config.json
// codec are design_run_options.cpp, the problem and objectives design_problem.cpp, the network
// state files network_state.cpp.
#include "qdo/design/design_run.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <sstream>
#include <unistd.h>

#include "design/network_state.hpp"
#include "design/problem.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/figure.hpp"
#include "qdo/data/io.hpp"
#include "qdo/design/joint.hpp"
#include "qdo/runtime/mpi.hpp"
#include "qdo/decode/decoder_registry.hpp"
#include "qdo/decode/network_decoder.hpp"
#include "qdo/physics/psf_source.hpp"
#include "qdo/design/run.hpp"
#include "qdo/design/psf_spec.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/physics/simulator.hpp"

namespace fs = std::filesystem;
using nlohmann::json;

namespace qdo {

namespace {

std::string fmt_time(double s) {
  char b[32];
  if (s >= 3600) std::snprintf(b, sizeof b, "%dh%02dm", int(s / 3600), int(std::fmod(s, 3600) / 60));
  else if (s >= 60) std::snprintf(b, sizeof b, "%dm%02ds", int(s / 60), int(std::fmod(s, 60)));
  else std::snprintf(b, sizeof b, "%.1fs", s);
  return b;
}

}  // namespace

namespace {

// The objective (without beta L_aq) of `height_m` at every object point of the run: each point's
// PSF through its 2-D source (the evaluation path), wiener-mse and wiener-mae on the batch of step
// `step`.
std::vector<double> point_losses(const DesignRunOptions& o, const Problem& pb, const std::vector<std::unique_ptr<Simulator>>& sims,
                                 wiener::DeviceObjective* dev, const Map2D& height_m, long step) {
  const PointObjective obj = make_point_objective(o, pb, step, dev);
  std::vector<double> out;
  for (std::size_t p = 0; p < sims.size(); ++p) {
    sims[p]->set_heights(height_m);
    sims[p]->compute_psf();
    const RealStack psf = sims[p]->psf_sensor();
    RealStack g(psf.planes, psf.rows, psf.cols);
    out.push_back(obj(p, psf, g));
  }
  return out;
}

// One 2-D source per object point of the run: the configuration itself for a one-point run (as
// before object points), point_config(cfg, p) for each point of a range.
std::vector<std::unique_ptr<Simulator>> point_sources(Runtime& rt, const DesignRunOptions& o) {
  std::vector<std::unique_ptr<Simulator>> sims;
  const std::size_t points = o.cfg.point_count();
  for (std::size_t p = 0; p < points; ++p)
    sims.push_back(std::make_unique<Simulator>(rt, points == 1 ? o.cfg : point_config(o.cfg, p), o.precision));
  return sims;
}

std::string join_points(const std::vector<std::size_t>& v) {
  std::string t;
  for (std::size_t i = 0; i < v.size(); ++i) t += (i ? ";" : "") + std::to_string(v[i]);
  return t;
}

}  // namespace

std::vector<double> design_point_losses(Runtime& rt, const DesignRunOptions& given, const Map2D& height_m) {
  DesignRunOptions o = given;
  o.quiet = true;
  o.validate();
  if (o.objective == Objective::Network)
    reject("objective", "network", "wiener, wiener-mse, wiener-mae or psf-target (the point losses of a fixed design)");
  const Problem pb = make_problem(rt, o);
  const auto sims = point_sources(rt, o);
  const std::unique_ptr<wiener::DeviceObjective> dev = make_device_objective(rt, o, pb);
  return point_losses(o, pb, sims, dev.get(), height_m, long(o.epochs * o.design.steps_per_epoch));
}

std::string device_for_rank(const std::string& given, int local_rank, const std::vector<DeviceInfo>& devices) {
  if (!given.empty()) return given;
  if (local_rank < 0) reject("local_rank", local_rank, ">= 0");
  std::vector<const DeviceInfo*> gpus;
  for (const DeviceInfo& d : devices)
    if (d.type == "GPU") gpus.push_back(&d);
  if (gpus.empty()) return "";
  const DeviceInfo& g = *gpus[std::size_t(local_rank) % gpus.size()];
  return std::to_string(g.platform_index) + ":" + std::to_string(g.device_index);
}

std::string process_device(const std::string& given) {
  if (!given.empty()) return given;
  if (const char* e = std::getenv("QDO_DEVICE"); e && *e) return e;
  const mpi::World* w = mpi::world();
  if (!w || !w->active() || w->size() < 2) return "";
  return device_for_rank("", w->local_rank(), list_devices());
}

DesignRunResult run_design(Runtime& rt, const DesignRunOptions& given, bool resume) {
  const fs::path dir(given.out);
  const RunFolder folder(given.out);
  const fs::path cfg_path = folder.config_path(), ckpt_path = folder.checkpoint_path(), log_path = folder.log_path();
  DesignRunOptions o = given;
  // Under mpirun (data-parallel network training, joint.hpp) every rank runs this call in
  // lock-step, and rank 0 owns the run folder: it alone takes the RunLock, sets a refused
  // checkpoint aside and writes files. The others read the folder once rank 0 has it (the
  // barriers below) and write nothing; their states stay rank 0's (joint.hpp), so the checkpoint
  // holds no per-rank state and a run resumes at any rank count.
  const mpi::World* world = mpi::world();
  const bool parallel = world && world->active() && world->size() > 1, writer = !parallel || world->rank() == 0;
  // The folder is ours while this call runs (RunLock): taken first when the folder exists, so
  // its config and checkpoint are read and judged under the lock; else right after creating it.
  std::unique_ptr<RunLock> lock;
  if (writer && !given.out.empty() && fs::is_directory(dir)) lock = std::make_unique<RunLock>(given.out);
  if (parallel && !writer) world->barrier();  // rank 0 holds the folder and has judged its checkpoint
  ResumeState resumed;  // read and checked before any work (no device needed)
  if (resume) {
    resumed = load_resume_state(given.out);
    o = resumed.options;
    o.out = given.out;
    o.max_steps = given.max_steps;
    o.quiet = given.quiet;
    if (!resumed.refused.empty() && writer) {
      // Resume from the previous checkpoint; the refused one is set aside (kept for inspection,
      // never deleted), so the next save does not rotate it into checkpoint.prev.h5.
      const fs::path aside = dir / "checkpoint.refused.h5";
      std::fprintf(stderr, "qdo: note: %s: %s; resuming from the previous checkpoint %s (step %ld)%s\n",
                   ckpt_path.string().c_str(), resumed.refused.c_str(), resumed.checkpoint.c_str(), resumed.state.step,
                   fs::exists(ckpt_path) ? ", the refused one kept as checkpoint.refused.h5" : "");
      if (fs::exists(ckpt_path)) fs::rename(ckpt_path, aside);
    }
  } else if (fs::exists(ckpt_path) || fs::exists(checkpoint_prev_path(ckpt_path.string()))) {
    reject("out", given.out, "a folder without a checkpoint (this one holds one: continue it with --resume)");
  }
  if (parallel && writer) world->barrier();
  if (!writer) o.quiet = true;
  o.validate();
  const bool network = o.objective == Objective::Network, finetune = !o.finetune_from.empty();
  if (parallel && !network)  // every rank would repeat the whole run
    reject("objective", to_string(o.objective),
           "network (a network --decoder) under mpirun: data-parallel training splits a network's batch over the ranks; a " +
               to_string(o.objective) + " run has no network and would run whole on every rank (run it without mpirun)");
  if (parallel && network && o.batch % std::size_t(world->size()) != 0)  // refused before any writing (as JointTrainer does)
    reject("batch", o.batch, "a multiple of the MPI world size " + std::to_string(world->size()) + " (each rank trains on batch / " +
                                 std::to_string(world->size()) + " scenes of every step's batch)");
  // A checkpoint belongs to its run: a network run's checkpoint (it names a network state) in a
  // Wiener run folder is refused, as a Wiener one in a network run is (read_network_state).
  if (resume && !network && !resumed.state.network_file.empty())
    throw InputError("file '" + resumed.checkpoint + "': names a network state (" + resumed.state.network_file +
                     "): a network run's checkpoint, but this run folder's config.json trains with the " + o.decoder.to_string() +
                     " decoder; it is not this run's checkpoint");
  // do-finetune: the network `do` run it continues (its state, network and configuration checked
  // here, before any writing).
  ResumeState source;
  std::string source_network;
  if (finetune && !resume) {
    source = load_resume_state(o.finetune_from);
    const DesignRunOptions& so = source.options;
    if (so.design.mode != DesignMode::DO || so.decoder != o.decoder || so.design.parameterization != o.design.parameterization ||
        config_to_json_text(so.cfg) != config_to_json_text(o.cfg))
      reject("finetune_from", o.finetune_from,
             "a network do run of this configuration and decoder (it is a " + to_string(so.design.mode) + " run with decoder " +
                 so.decoder.to_string() + ")");
    // Only a finished do run: an unfinished one would freeze optics still in training, and a
    // do-finetune run's own network was trained for a quantized DOE it no longer has.
    if (!so.finetune_from.empty())
      reject("finetune_from", o.finetune_from, "a network do run (it is itself a do-finetune run, of " + so.finetune_from + ")");
    const long source_total = long(so.epochs * so.design.steps_per_epoch);
    if (source.state.step != source_total)
      reject("finetune_from", o.finetune_from,
             "a finished network do run (its checkpoint is at step " + std::to_string(source.state.step) + " of " +
                 std::to_string(source_total) + "; finish it with qdo design --resume --out " + o.finetune_from + ")");
    source_network = read_network_state(o.finetune_from, source.state, source.checkpoint);
  }
  // do-finetune for the camera as built: the measured stack or the fitted design, read and checked
  // against the configuration before any writing.
  RealStack asbuilt_psf;
  Map2D asbuilt_heights;
  if (finetune && (!o.finetune_psf.empty() || !o.finetune_design.empty())) {
    const PsfInput in = read_psf_input(
        psf_spec_from_options(o.finetune_psf, o.finetune_design, "psf", "design", "the frozen PSF comes from one of them"), o.cfg);
    asbuilt_psf = in.stack;
    asbuilt_heights = in.heights;
  }
  const Problem pb = make_problem(rt, o);  // reads data and estimates the prior before any writing
  std::unique_ptr<NetworkDecoder> net;
  if (network) net = make_trained_decoder(network_settings(o));  // a resunet is refused here when built without LibTorch
  if (network && resume) net->load(read_network_state(dir, resumed.state, resumed.checkpoint), (dir / resumed.state.network_file).string());
  std::vector<std::string> notes;
  if (network && resume) {  // the thread count the run trained with (split.json; runs before it recorded none)
    long recorded = 0;
    try {
      std::ifstream f(dir / "split.json");
      const json sp = json::parse(f);
      if (sp.contains("threads") && sp["threads"].is_number_integer()) recorded = sp["threads"].get<long>();
    } catch (const json::exception&) {  // a torn or edited split.json: nothing recorded to compare
      recorded = 0;
    }
    const int now = network_threads();
    if (recorded > 0 && recorded != now && writer) {
      notes.push_back("this network run trained with " + std::to_string(recorded) + " LibTorch threads and resumes with " +
                      std::to_string(now) + ": the network's sums run in another order, so the run continues differently from "
                      "an uninterrupted one (about 1e-7 in the loss); QDO_TORCH_THREADS=" + std::to_string(recorded) +
                      " continues it bit-identically");
      std::fprintf(stderr, "qdo: note: %s: %s\n", dir.string().c_str(), notes.back().c_str());
    }
  }
  if (finetune && !resume) net->load(source_network, (fs::path(o.finetune_from) / source.state.network_file).string());
  if (writer) make_output_dir(dir.string(), "out");
  if (writer && !lock) {
    lock = std::make_unique<RunLock>(given.out);
    if (!resume && fs::exists(ckpt_path))  // another writer made it meanwhile and has finished
      reject("out", given.out, "a folder without a checkpoint (this one holds one: continue it with --resume)");
  }
  if (!resume && writer) write_text_atomic(cfg_path.string(), design_run_options_to_json(o) + "\n");
  if (o.objective != Objective::PsfTarget && writer) save_prior(folder.prior_path(), pb.prior);
  if (network && !resume && writer) {  // split.json: the scenes the network trains and validates on
    json sp;
    sp["train"] = pb.joint.train_names;
    sp["validation"] = pb.joint.val_names;
    sp["validation_patches"] = pb.joint.val.size();
    sp["patch_px"] = o.cfg.sensor_size_px();
    sp["augmentation"] = "random S x S crops, one of the 8 flips/rotations each (qdo/design/joint.hpp)";
    sp["threads"] = network_threads();  // LibTorch's summation order depends on it (network_decoder.hpp)
    if (finetune) sp["finetune_from"] = o.finetune_from;
    if (!o.finetune_psf.empty()) sp["finetune_psf"] = o.finetune_psf;
    if (!o.finetune_design.empty()) sp["finetune_design"] = o.finetune_design;
    write_text_atomic((dir / "split.json").string(), sp.dump(2) + "\n");
  }

  // One PSF source per object point (a range design's training conditions), heights shared.
  const std::size_t npoints = o.cfg.point_count();
  const bool range = npoints > 1;
  const std::vector<std::unique_ptr<Simulator>> sims = point_sources(rt, o);
  std::vector<HeightMapPsfSource*> sources;
  for (const auto& sp : sims) sources.push_back(sp.get());
  Simulator& sim = *sims[0];
  Designer d(sources, o.design);
  const std::unique_ptr<wiener::DeviceObjective> dev = network ? nullptr : make_device_objective(rt, o, pb);
  // The device objective evaluated where the PSF lies (Designer::gradient's device path): the same
  // numbers as through the host (float32 survives the double round trip exactly), no PSF copies.
  DevicePsfObjective dev_resident;
  if (dev) dev_resident = [&dev](const cl::Buffer& psf, cl::Buffer& grad) { return dev->expected(psf, grad); };
  std::unique_ptr<JointTrainer> joint;
  if (network) joint = std::make_unique<JointTrainer>(rt, o.cfg, o.precision, *net, pb.joint, o.batch, o.decoder_noise_sigma, o.design.seed,
                                                         o.sampling);
  const std::size_t levels = static_cast<std::size_t>(o.design.quantizer.levels);
  DesignState s;
  if (resume) {
    s = std::move(resumed.state);
  } else if (finetune) {  // the do run's optics, frozen; a fresh step count
    s = source.state;
    s.step = 0;
  } else {
    s = d.initial_state(initial_params(o));
  }
  if (s.w.size() != parameter_count(o.design.parameterization, o.cfg.n))
    throw Error("internal: resume state sized for another parameterization");
  if (s.offsets.size() != d.level_parameter_count()) {
    if (!finetune) throw Error("internal: resume state sized for another level count");
    s.offsets.assign(d.level_parameter_count(), 0.0);  // do has no trained offsets; the finetune's levels may differ
    s.adam_a = Adam{};
  }
  // do-finetune: the PSF of the frozen, quantized DOE (the run's levels), computed once; for the
  // camera as built, the measured stack or the fitted design's PSF instead.
  RealStack frozen_psf;
  if (finetune && !o.finetune_psf.empty()) {
    frozen_psf = asbuilt_psf;
  } else if (finetune) {
    sim.set_heights(o.finetune_design.empty() ? d.fabricated_heights(s) : asbuilt_heights);
    sim.compute_psf();
    frozen_psf = sim.psf_sensor();
  }
  std::vector<std::string> rows = std::move(resumed.log_rows);
  std::vector<double> losses = std::move(resumed.losses);
  const long total = long(o.epochs * o.design.steps_per_epoch);
  const long stop = o.max_steps >= 0 ? std::min(total, o.max_steps) : total;
  auto write_log = [&]() {
    std::string text = "step,loss,loss_aq,alpha,lr,step_s,level_heights_nm";
    if (network) text += ",mae,train_psnr_db,val_psnr_db,lr_decoder";
    if (range) text += ",points,point_losses";  // the object points the step trained on, the objective at each
    text += ",deviation_nm\n";  // mean |H_q - H_f| over the parameterization's values (the release's ring profile)
    for (const auto& r : rows) text += r + "\n";
    write_text_atomic(log_path.string(), text);
  };
  const auto t_start = std::chrono::steady_clock::now();
  const long first = s.step;
  double last_loss = losses.empty() ? NAN : losses.back();
  while (s.step < stop) {
    const auto t0 = std::chrono::steady_clock::now();
    const long cur = s.step;
    const double lr_net = network ? network_lr(o, cur) : 0.0;
    StepReport rep;
    if (finetune) {  // the network alone; the optics stay as they are
      RealStack unused;
      rep.step = cur;
      rep.loss = joint->step(cur, lr_net, frozen_psf, unused);
      rep.alpha = 1;
      rep.lr = 0;
      ++s.step;
    } else if (network) {
      const PsfObjective obj = [&](const RealStack& psf, RealStack& grad) { return joint->step(cur, lr_net, psf, grad); };
      rep = d.step(s, obj, nullptr);
    } else {
      rep = d.range_step(s, make_point_objective(o, pb, s.step, dev.get()), dev ? &dev_resident : nullptr);
    }
    if (!std::isfinite(rep.loss) || !std::isfinite(rep.loss_aq))
      throw NumericalError("design step " + std::to_string(rep.step) + ": the loss is " + to_str(rep.loss) +
                           " (L_aq " + to_str(rep.loss_aq) + "); stopped before writing it: " + ckpt_path.string() +
                           " still holds step " + std::to_string(s.step - 1 >= 0 ? s.step - 1 : 0) +
                           " or earlier (lower --lr, or check the data)");
    // Validation at the end of each epoch (not where a session stops: a resumed run logs what an
    // uninterrupted one does).
    const bool epoch_end = s.step % long(o.design.steps_per_epoch) == 0;
    double val_psnr = NAN;
    if (network && epoch_end && writer) val_psnr = joint->validation_psnr_db(joint->last_psf());  // logged by rank 0
    const double dt = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    last_loss = rep.loss;
    losses.push_back(rep.loss);
    std::ostringstream row;
    row.precision(10);
    row << rep.step << "," << rep.loss << "," << rep.loss_aq << "," << rep.alpha << "," << rep.lr << "," << dt << ",";
    const auto lv = d.quantizer(s).level_heights_m(o.cfg.h_max_m());
    for (std::size_t l = 0; l < lv.size(); ++l) row << (l ? ";" : "") << lv[l] * 1e9;
    if (network) {
      row << "," << joint->last().mae << "," << joint->last().psnr_db << ",";
      if (std::isfinite(val_psnr)) row << val_psnr;
      row << "," << lr_net;
    }
    if (range) {
      row << "," << join_points(rep.points) << ",";
      for (std::size_t i = 0; i < rep.point_loss.size(); ++i) row << (i ? ";" : "") << rep.point_loss[i];
    }
    row << "," << rep.deviation_m * 1e9;
    rows.push_back(row.str());
    const bool tty = ::isatty(2) != 0;
    const long every = std::max<long>(1, (stop - first) / 20);
    if (!o.quiet && (tty || (s.step - first) % every == 0 || s.step == stop || (network && epoch_end))) {
      const double el = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count();
      const double eta = el / double(s.step - first) * double(stop - s.step);
      std::string extra;
      if (network) {
        char b[96];
        std::snprintf(b, sizeof b, "  train PSNR %.2f dB", joint->last().psnr_db);
        extra = b;
        if (std::isfinite(val_psnr)) {
          std::snprintf(b, sizeof b, "  val PSNR %.2f dB", val_psnr);
          extra += b;
        }
      }
      if (range) extra += "  points " + join_points(rep.points) + " of " + std::to_string(npoints);
      std::fprintf(stderr, "%s[design %s%s] step %ld/%ld  loss %.5g%s  alpha %.3f  lr %.4g  %.2f s/step  ETA %s   %s",
                   tty ? "\r" : "", finetune ? "do-finetune" : to_string(o.design.mode).c_str(),
                   network ? (", " + o.decoder.to_string()).c_str() : "", s.step, total, rep.loss, extra.c_str(), rep.alpha, rep.lr, dt,
                   fmt_time(eta).c_str(), tty && !(network && epoch_end) ? "" : "\n");
      std::fflush(stderr);
    }
    if (writer && (s.step % long(o.checkpoint_every) == 0 || s.step == stop)) {
      write_log();  // the log first: a kill between the two leaves rows the resume redoes, never a gap
      NetworkStateRef dropped;  // the state the rotation drops with the old checkpoint.prev.h5
      if (network) {
        save_network_state(dir, *net, s);  // then the network state the checkpoint will name
        dropped = network_state_of(checkpoint_prev_path(ckpt_path.string()));
      }
      save_checkpoint(ckpt_path.string(), s);
      if (network) drop_network_state(dir, dropped);
    }
  }
  if (!o.quiet && ::isatty(2)) std::fprintf(stderr, "\n");
  DesignRunResult r;
  r.notes = std::move(notes);
  r.steps_done = s.step;
  r.final_loss = last_loss;
  if (!writer) {  // rank 0 writes the outputs
    if (o.design.mode != DesignMode::Full) r.levels_m = d.quantizer(s).level_heights_m(o.cfg.h_max_m());
    return r;
  }
  if (first == s.step) write_log();

  // Outputs of the design as it would be fabricated.
  Design out;
  out.height_m = d.fabricated_heights(s);
  out.pitch_m = o.cfg.pitch_m;
  if (o.design.mode != DesignMode::Full) out.levels_m = d.quantizer(s).level_heights_m(o.cfg.h_max_m());
  std::map<std::string, std::string> provenance = {{"mode", to_string(o.design.mode)}, {"levels", std::to_string(levels)},
                                                   {"objective", to_string(o.objective)}, {"steps", std::to_string(s.step)},
                                                   {"run", dir.string()}, {"decoder", o.decoder.to_string()}};
  if (finetune) provenance["finetune_from"] = o.finetune_from;
  if (!o.finetune_psf.empty()) provenance["finetune_psf"] = o.finetune_psf;
  if (!o.finetune_design.empty()) provenance["finetune_design"] = o.finetune_design;
  if (o.design.mode == DesignMode::QDOM) {  // the k binary-mask etch depths (level l = sum over the bits of l)
    std::ostringstream md;
    md.precision(12);
    for (std::size_t j = 0; j < s.offsets.size(); ++j) md << (j ? "," : "") << s.offsets[j] * o.cfg.h_max_m() * 1e9;
    provenance["mask_depths_nm"] = md.str();
  }
  write_design(folder.design_path(), out, provenance);
  Design full;
  full.height_m = expand_parameters(o.design.parameterization, d.params_m(s), o.cfg.n, o.cfg.h_max_m());
  full.pitch_m = o.cfg.pitch_m;
  write_design(folder.design_full_path(), full, {{"mode", to_string(o.design.mode)}, {"note", "full-precision H_f"}});
  if (range) {
    // The fabricated design's objective at every training point (range.csv, range.png), with how
    // often each point was trained on (steps_point_list redrawn: the same draws as the steps).
    r.points = o.cfg.points();
    r.point_losses = point_losses(o, pb, sims, dev.get(), out.height_m, total);
    std::vector<long> sampled(npoints, 0);
    for (long k = 0; k < s.step; ++k)
      for (std::size_t p : d.step_points(k)) ++sampled[p];
    std::ostringstream csv;
    csv.precision(10);
    csv << "point,distance_m,field_x_deg,field_y_deg,loss,steps_trained\n";
    for (std::size_t p = 0; p < npoints; ++p) {
      const ObjectPoint& pt = r.points[p];
      csv << p << "," << (pt.at_infinity() ? std::string("inf") : to_str(pt.distance_m)) << "," << pt.field_x_deg << ","
          << pt.field_y_deg << "," << r.point_losses[p] << "," << sampled[p] << "\n";
    }
    write_text_atomic(folder.path("range.csv"), csv.str());
    write_index_plot(folder.path("range.png"), "Loss at each object point after training: " + dir.filename().string(),
                     "object point (row of range.csv)", "loss", {r.point_losses}, {"final design"});
  }
  // psf.h5 and psf.png: the PSF at the first object point (the run's one point when it has one).
  sim.set_heights(out.height_m);
  sim.compute_psf();
  // A training point whose spherical wave the DOE grid under-samples (qdo psf's "ALIASES" for that
  // point: an object too near for the pitch) trained on aliased physics: said, with qdo psf's report.
  for (std::size_t k = 0; k < sims.size(); ++k) {
    const SamplingReport& rep = sims[k]->sampling();
    const bool aliases = std::any_of(rep.bands.begin(), rep.bands.end(), [](const BandSampling& b) { return b.source_undersampled; });
    if (aliases)
      std::fprintf(stderr, "qdo: note: training point %zu of %zu INACCURATE, the point source's wave aliases on the DOE grid: %s\n", k,
                   sims.size(), rep.summary().c_str());
  }
  const RealStack psf = sim.psf_sensor();
  write_psf(folder.psf_path(), psf, o.cfg.wavelengths_nm(), o.cfg.sensor_pitch_m);
  const std::string run_name = dir.filename().string();
  write_psf_figure((dir / "psf.png").string(), "PSF stack on the sensor: " + run_name, psf, o.cfg.wavelengths_nm(),
                   o.cfg.sensor_pitch_m, std::min<std::size_t>(psf.rows, 96));
  write_height_figure((dir / "design.png").string(), "DOE height map: " + run_name, out.height_m, o.cfg.pitch_m);
  if (!losses.empty())
    write_index_plot((dir / "loss.png").string(), "Training loss: " + run_name, "optimiser step", "loss", {losses}, {"loss per step"});
  if (network && !rows.empty()) {  // training PSNR per step (blue), validation PSNR per epoch (red)
    std::vector<double> tr, va;
    for (const auto& row : rows) {
      std::vector<std::string> f;
      std::stringstream ss(row);
      for (std::string x; std::getline(ss, x, ',');) f.push_back(x);
      tr.push_back(f.size() > 8 && !f[8].empty() ? std::strtod(f[8].c_str(), nullptr) : NAN);
      va.push_back(f.size() > 9 && !f[9].empty() ? std::strtod(f[9].c_str(), nullptr) : NAN);
    }
    LinePlot lp;
    lp.title = "Network PSNR during training: " + run_name;
    lp.x_label = "optimiser step";
    lp.y_label = "PSNR (dB)";
    PlotSeries train{"training batch (per step)", {}, {}, {}, {}, false}, val{"validation (per epoch)", {}, {}, {}, {}, true};
    for (std::size_t i = 0; i < tr.size(); ++i) {
      if (std::isfinite(tr[i])) train.x.push_back(double(i)), train.y.push_back(tr[i]);
      if (std::isfinite(va[i])) val.x.push_back(double(i)), val.y.push_back(va[i]);
    }
    for (PlotSeries* ps : {&train, &val})
      if (!ps->x.empty()) lp.series.push_back(*ps);
    if (!lp.series.empty()) write_line_plot((dir / "psnr.png").string(), lp);
  }
  r.levels_m = out.levels_m;
  return r;
}

}  // namespace qdo
