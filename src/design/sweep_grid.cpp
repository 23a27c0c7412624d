// The experiment grid of `qdo sweep`: its plan (a fixed list of cells), the running of any subset
// of cells by any process (one sweep, Slurm job array tasks, MPI ranks), and the tables from the
// finished cells. sweep.cpp holds the run and cell helpers, sweep_tables.cpp the tables.
#include <nlohmann/json.hpp>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <deque>
#include <filesystem>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <thread>
#include <utility>

#include "design/sweep_internal.hpp"
#include "qdo/datasets.hpp"
#include "qdo/decoder_registry.hpp"
#include "qdo/design_run.hpp"
#include "qdo/encoders.hpp"
#include "qdo/error.hpp"
#include "qdo/hash.hpp"
#include "qdo/io.hpp"
#include "qdo/mpi.hpp"
#include "qdo/optics.hpp"
#include "qdo/run.hpp"
#include "qdo/run_folder.hpp"
#include "qdo/simulator.hpp"
#include "qdo/sweep.hpp"

namespace fs = std::filesystem;

namespace qdo {

using namespace sweep_detail;

namespace {

enum class CellKind { Eval, Fresnel, Cassi };

// One cell and what running it takes.
struct Job {
  PlannedCell plan;
  CellKind kind = CellKind::Eval;
  std::vector<DesignRunOptions> runs;           // trained in this order (plan.runs are their folders)
  std::vector<std::set<std::string>> ignores;   // per run: config fields the sweep does not read
  EvalOptions eval;                             // Eval: the evaluation (its run set)
  nlohmann::json key;                           // the cell's own fields of its inputs hash
  std::string prior_run;                        // Fresnel, Cassi: the DO run whose prior they use
};

class Grid {
 public:
  explicit Grid(const GridOptions& g);
  const std::vector<Job>& jobs() const { return jobs_; }
  bool seed_axis() const { return !g_.seeds.empty(); }
  // Trains what cell k needs and evaluates it (under the cell's lock).
  void run_cell(Runtime& rt, std::size_t k, bool progress);
  // The finished cell k as the tables show it; false when it is not finished (or stale).
  bool read_cell(std::size_t k, GridCell& c) const;

 private:
  std::string cell_inputs(const Job& j) const;
  std::string run_outputs(const std::string& run) const;
  const std::string& train_inputs();

  GridOptions g_;
  DesignRunOptions base_;
  std::vector<std::string> test_;
  std::string test_inputs_, train_inputs_;
  fs::path out_;
  std::vector<Job> jobs_;
};

// Runs of decoder `dec`: Wiener runs keep the names they always had, network runs carry the spec.
std::string tag_of(const DecoderSpec& dec) {
  if (dec.kind == DecoderSpec::Kind::Wiener) return std::string();
  std::string t = "_";
  for (char ch : dec.to_string()) t += ch == ':' || ch == ',' ? '-' : ch == '=' ? '\0' : ch;
  t.erase(std::remove(t.begin(), t.end(), '\0'), t.end());
  return t;
}

Grid::Grid(const GridOptions& g) : g_(g), out_(g.out) {
  if (g.out.empty()) reject("out", "(missing)", "an output folder");
  for (const auto& m : g.modes)
    if (m != "do" && m != "do-refit" && m != "do-finetune" && m != "qdo" && m != "qdo+a" && m != "ste" && m != "qdo+m")
      reject("grid mode", m, "do, do-refit, do-finetune, qdo, qdo+a, ste or qdo+m");
  for (const auto& e : g.encoders)
    if (e != "doe" && e != "fresnel" && e != "cassi") reject("grid encoder", e, "doe, fresnel or cassi");
  std::vector<DecoderSpec> decoders;
  for (const DecoderSpec& d : g.decoders.empty() ? std::vector<DecoderSpec>{g.base.decoder} : g.decoders)
    if (std::find(decoders.begin(), decoders.end(), d) == decoders.end()) decoders.push_back(d);
  if (g.finetune_steps < 1) reject("finetune_steps", g.finetune_steps, ">= 1");
  for (int l : g.levels)
    if (l < 2 || l > 256) reject("grid levels", l, "integers in [2, 256]");
  std::set<std::uint64_t> distinct_seeds(g.seeds.begin(), g.seeds.end());
  if (distinct_seeds.size() != g.seeds.size()) reject("grid seed", g.seeds.size(), "distinct seeds");
  base_ = g.base;
  base_.out = "(set per run)";
  base_.decoder = DecoderSpec{};
  if (base_.objective == Objective::Network) base_.objective = Objective::Wiener;
  base_.validate();
  for (const auto& d : decoders) {  // every decoder's runs validated before any work
    DesignRunOptions o = base_;
    o.decoder = d;
    if (d.network()) o.objective = Objective::Network;
    o.validate();
    if (d.network() && !network_decoder_available())
      reject("grid decoder", d.to_string(), "wiener: " + network_decoder_unavailable_reason());
  }
  // Test scenes: the same for every seed (the split of base.design.seed).
  test_ = g.test_data;
  if (test_.empty() && !base_.data.empty()) {
    const SceneIndex idx(base_.data, base_.data_format, base_.cfg.bands, base_.cfg.wavelengths_nm());
    for (std::size_t i : idx.split(base_.design.seed, 0.8, 0.1).test) test_.push_back(idx[i].path);
    if (test_.empty()) reject("data", base_.data.size(), "enough scenes for a test split (or pass test scenes explicitly)");
  }
  test_inputs_ = test_.empty() ? "synthetic" : hash_paths(test_);

  const std::vector<std::uint64_t> seeds = g.seeds.empty() ? std::vector<std::uint64_t>{base_.design.seed} : g.seeds;
  const bool doe = std::find(g.encoders.begin(), g.encoders.end(), "doe") != g.encoders.end();
  const bool fresnel = std::find(g.encoders.begin(), g.encoders.end(), "fresnel") != g.encoders.end();
  const bool cassi = std::find(g.encoders.begin(), g.encoders.end(), "cassi") != g.encoders.end();
  for (std::uint64_t seed : seeds) {
    const std::string sfx = g.seeds.empty() ? std::string() : "_s" + std::to_string(seed);
    auto run_opts = [&](DesignMode mode, int levels, const std::string& name, const DecoderSpec& dec) {
      DesignRunOptions o = base_;
      o.design.mode = mode;
      o.design.quantizer.levels = levels;
      o.design.seed = seed;
      o.decoder = dec;
      if (dec.network()) o.objective = Objective::Network;
      o.out = (out_ / "runs" / (name + tag_of(dec) + sfx)).string();
      return o;
    };
    auto add = [&](Job j, const std::string& name, const std::string& mode, int levels, const DecoderSpec& dec) {
      j.plan.index = jobs_.size();
      j.plan.name = name + sfx;
      j.plan.mode = mode;
      j.plan.decoder = dec;
      j.plan.levels = levels;
      j.plan.seed = seed;
      for (const auto& r : j.runs) j.plan.runs.push_back(r.out);
      j.key["cell"] = j.plan.name;
      j.key["mode"] = mode;
      j.key["levels"] = levels;
      j.key["seed"] = seed;
      jobs_.push_back(std::move(j));
    };
    const std::set<std::string> do_ignore{"design.checkpoint_every", "design.levels", "design.placement"};
    std::string first_do;  // the first decoder's DO run: the prior of the other encoders
    for (const DecoderSpec& dec : decoders) {
      const bool network = dec.network();
      const std::string tag = tag_of(dec), label = network ? "@" + dec.to_string() : "";
      // DO is trained once per seed in full precision; its levels and placement only shape its
      // design.h5, which no cell reads (cells quantize design_full.h5 themselves).
      const DesignRunOptions do_run = run_opts(DesignMode::DO, g.levels.front(), "do", dec);
      if (first_do.empty()) first_do = do_run.out;
      auto eval_job = [&](std::vector<DesignRunOptions> runs, std::vector<std::set<std::string>> ignores, EvalOptions e) {
        Job j;
        j.runs = std::move(runs);
        j.ignores = std::move(ignores);
        e.data = test_;
        e.synthetic_scenes = g.eval_synthetic_scenes;
        e.renders = 1;
        e.precision = base_.precision;
        j.eval = e;
        j.key["eval_levels"] = e.levels;
        j.key["placement"] = to_string(e.placement);
        j.key["decoder"] = to_string(e.decoder);
        j.key["full_precision"] = e.full_precision;
        j.key["renders"] = e.renders;
        return j;
      };
      {
        EvalOptions e;
        e.run = do_run.out;
        e.full_precision = true;
        add(eval_job({do_run}, {do_ignore}, e), "full" + tag, "full" + label, 0, dec);
      }
      if (doe)
        for (int L : g.levels)
          for (const auto& m : g.modes) {
            if (network && m == "do-refit") continue;  // a network has no closed-form refit (do-finetune is its counterpart)
            const std::string name = m + "_L" + std::to_string(L) + tag;
            EvalOptions e;
            std::vector<DesignRunOptions> runs{do_run};
            std::vector<std::set<std::string>> ignores{do_ignore};
            if (m == "do" || m == "do-refit" || (m == "do-finetune" && !network)) {
              e.run = do_run.out;
              e.levels = L;
              e.placement = base_.design.quantizer.placement;
              e.decoder = m == "do" ? DecoderFit::Mismatch : DecoderFit::Matched;
            } else if (m == "do-finetune") {  // the do run's network trained on, the DOE quantized to L and frozen
              DesignRunOptions r = run_opts(DesignMode::DO, L, "do-finetune_L" + std::to_string(L), dec);
              r.finetune_from = do_run.out;
              r.epochs = 1;
              r.design.steps_per_epoch = g.finetune_steps;
              r.design.t0_epochs = 0;
              r.design.t1_epochs = 1;
              r.lr_decoder = base_.lr_decoder * std::pow(base_.design.lr_decay_per_epoch, double(base_.epochs - 1));
              r.design.lr_decay_per_epoch = 1;
              runs.push_back(r);
              ignores.push_back({"design.checkpoint_every"});
              e.run = r.out;
            } else {
              const DesignRunOptions r = run_opts(design_mode_from_string(m), L, m + "_L" + std::to_string(L), dec);
              runs = {r};
              ignores = {{"design.checkpoint_every"}};
              e.run = r.out;
            }
            add(eval_job(runs, ignores, e), name, m + label, L, dec);
          }
    }
    // Other encoders with the DO run's prior (the first decoder's), Wiener / CG decoders.
    const DesignRunOptions prior_run = run_opts(DesignMode::DO, g.levels.front(), "do", decoders.front());
    auto encoder_job = [&](CellKind kind) {
      Job j;
      j.kind = kind;
      j.runs = {prior_run};
      j.ignores = {do_ignore};
      j.prior_run = first_do;
      j.key["fresnel_design_nm"] = g.fresnel_design_nm;
      j.key["cassi_shift_px"] = g.cassi_shift_px;
      j.key["noise_sigma"] = base_.decoder_noise_sigma;
      return j;
    };
    if (fresnel)
      for (int L : g.levels) add(encoder_job(CellKind::Fresnel), "fresnel_L" + std::to_string(L), "fresnel", L, DecoderSpec{});
    if (cassi) add(encoder_job(CellKind::Cassi), "cassi", "cassi", -1, DecoderSpec{});
  }
}

const std::string& Grid::train_inputs() {
  if (train_inputs_.empty()) train_inputs_ = hash_paths(base_.data);  // every run trains on base.data
  return train_inputs_;
}

std::string Grid::run_outputs(const std::string& run) const {
  const RunFolder folder(run);
  return hash_paths({folder.config_path(), folder.design_path(), folder.design_full_path(), folder.prior_path()});
}

// What determines a cell: its own fields, the test scenes (bytes), and its runs' outputs (bytes).
std::string Grid::cell_inputs(const Job& job) const {
  nlohmann::json j = job.key;
  j["test"] = test_inputs_;
  j["test_files"] = test_.size();  // their bytes and names are in test_inputs_, never their spelling
  j["eval_synthetic_scenes"] = g_.eval_synthetic_scenes;
  j["precision"] = to_string(base_.precision);
  j["system"] = nlohmann::json::parse(config_to_json_text(base_.cfg));
  if (job.kind == CellKind::Eval) j["run"] = run_outputs(job.eval.run);
  else j["prior_run"] = run_outputs(job.prior_run);
  Fnv1a64 f;
  f.add(j.dump());
  return f.hex();
}

// A cell's metrics.json is reused only when the cell's `inputs` file (written after it) holds the
// same hash. Reading changes nothing (--collect only reads); run_cell drops a stale stamp before
// it evaluates again, so that a stamp never vouches for metrics of other inputs.
bool Grid::read_cell(std::size_t k, GridCell& c) const {
  const Job& job = jobs_.at(k);
  c = GridCell{};
  c.name = job.plan.name;
  c.mode = job.plan.mode;
  c.decoder = job.plan.decoder;
  c.levels = job.plan.levels;
  c.seed = job.plan.seed;
  for (const auto& r : job.plan.runs)
    if (!run_finished(r)) return false;
  c.inputs = cell_inputs(job);
  const fs::path dir = out_ / "cells" / job.plan.name, f = dir / "metrics.json", stamp = dir / "inputs";
  std::string held = fs::exists(stamp) ? read_text(stamp) : std::string();
  while (!held.empty() && (held.back() == '\n' || held.back() == ' ')) held.pop_back();
  return held == c.inputs && fs::exists(f) &&
         read_cell_metrics(f.string(), c.mean, c.deviation_nm, job.kind == CellKind::Eval ? &c.scenes : nullptr,
                           &c.deviation_rings_nm);
}

void Grid::run_cell(Runtime& rt, std::size_t k, bool progress) {
  const mpi::Solo alone;  // a cell's runs train in this process alone, whatever the other ranks do
  const Job& job = jobs_.at(k);
  const auto t0 = std::chrono::steady_clock::now();
  const fs::path dir = out_ / "cells" / job.plan.name;
  // Runs of other options or scenes are refused before anything is written (the cell's lock included).
  for (std::size_t i = 0; i < job.runs.size(); ++i) check_run_inputs(job.runs[i], train_inputs(), g_.out, job.ignores[i]);
  fs::create_directories(dir);
  fs::create_directories(out_ / "runs");
  std::unique_ptr<RunLock> lock;
  try {
    lock = std::make_unique<RunLock>(dir.string(), "cell");
  } catch (const RunBusyError& e) {
    throw InputError("cell " + std::to_string(k) + " (" + job.plan.name + ") is being run by another process: " + e.what());
  }
  for (std::size_t i = 0; i < job.runs.size(); ++i) ensure_run_waiting(rt, job.runs[i], train_inputs(), g_.quiet, g_.out, job.ignores[i]);
  GridCell c;
  const bool cached = read_cell(k, c);
  if (!cached) {
    std::error_code ec;
    fs::remove(dir / "inputs", ec);  // the cell's own stale stamp, under its lock: evaluated again below
    if (job.kind == CellKind::Eval) {
      EvalOptions e = job.eval;
      e.out = dir.string();
      const EvalResult r = evaluate_run(rt, e);
      write_text_atomic((dir / "inputs").string(), c.inputs + "\n");
      c.mean = r.mean;
    } else {
      const std::uint64_t seed = job.plan.seed;
      const wiener::SpectralPrior prior = load_prior(RunFolder(job.prior_run).prior_path());
      const Eigen::MatrixXd srf = sensor_response(base_.cfg);
      const double sigma = base_.decoder_noise_sigma;
      const std::vector<RealStack> cubes = test_patches(base_.cfg, test_, g_.eval_synthetic_scenes, base_.design.seed);
      // The decoders of the other encoders come from the registry: wiener for the Fresnel lens's
      // PSF, cg for CASSI (any linear encoder), on the DO run's prior.
      auto decoder_of = [&](const DecoderSpec& spec, RealStack psf, std::shared_ptr<const Encoder> enc) {
        DecoderInputs in;
        in.spec = spec;
        in.psf = std::move(psf);
        in.srf = srf;
        in.encoder = std::move(enc);
        in.prior = prior;
        in.noise_sigma = sigma;
        return make_decoder(in);
      };
      EncoderEval ev;
      if (job.kind == CellKind::Fresnel) {
        Simulator sim(rt, base_.cfg, base_.precision);
        sim.set_heights(fresnel_lens_heights(base_.cfg, g_.fresnel_design_nm, job.plan.levels));
        sim.compute_psf();
        const RealStack psf = sim.psf_sensor();
        const DoeEncoder enc(wiener::psf_to_otf(psf, prior.rows, prior.cols), srf);
        ev = evaluate_encoder(enc, *decoder_of(DecoderSpec{}, psf, nullptr), cubes, sigma, seed + 77);
      } else {
        DecoderSpec cg;
        cg.kind = DecoderSpec::Kind::Named;
        cg.name = "cg";
        const std::size_t s = base_.cfg.sensor_size_px();
        auto enc = std::make_shared<CassiEncoder>(random_binary_mask(s, s, 0.5, seed + 5), base_.cfg.bands, g_.cassi_shift_px);
        ev = evaluate_encoder(*enc, *decoder_of(cg, RealStack(), enc), cubes, sigma, seed + 77);
      }
      c.mean.psnr = ev.psnr_db;
      c.mean.ssim = ev.ssim;
      c.mean.rmse = ev.rmse;
      c.mean.ergas = ev.ergas;
      c.mean.sam_rad = ev.sam_rad;
      write_cell_metrics(dir, c);
    }
  }
  if (progress)
    std::fprintf(stderr, "[sweep] cell #%zu of %zu %-22s PSNR %.2f dB%s (%.1f s)\n", k, jobs_.size(), job.plan.name.c_str(), c.mean.psnr,
                 cached ? ", finished earlier" : "",
                 std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
}

// Rank 0's dispatcher (a thread beside rank 0's own work): hands each idle rank the first cell in
// plan order whose runs are finished or used by no running cell, so that no two ranks train one
// run; a rank that finds none ready waits until a running cell finishes.
// Messages: a rank sends kRequest with the cell it finished (-1 at first); rank 0 answers kAssign
// with a cell or kStop when none is left. Rank 0's own work goes through `local` instead of MPI.
constexpr int kRequest = 1, kAssign = 2, kStop = 3;

class Dispatcher {
 public:
  Dispatcher(const Grid& grid, const mpi::World& world) : grid_(grid), world_(world), state_(grid.jobs().size(), 0) {}
  // The dispatcher thread's body: returns when every rank has been told to stop.
  void serve() {
    std::size_t stopped = 0;
    std::deque<int> idle;
    const std::size_t ranks = std::size_t(world_.size());
    while (stopped < ranks) {
      bool busy = false;
      mpi::Message m;
      if (world_.poll(m)) {
        busy = true;
        if (m.tag != kRequest) throw std::logic_error("sweep dispatcher: unexpected message tag " + std::to_string(m.tag));
        finished(m.value);
        idle.push_back(m.source);
      }
      {
        std::lock_guard<std::mutex> lk(mu_);
        if (local_request_) {
          busy = true;
          local_request_ = false;
          finished(local_done_);
          idle.push_back(0);
        }
      }
      while (!idle.empty()) {
        const int rank = idle.front();
        const long k = next_ready();
        if (k == -2) break;  // cells remain, none ready: wait for a running one
        idle.pop_front();
        if (k < 0) ++stopped;
        if (rank == 0) {
          std::lock_guard<std::mutex> lk(mu_);
          local_assigned_ = k;
          cv_.notify_all();
        } else {
          world_.send(rank, k < 0 ? kStop : kAssign, k);
        }
      }
      if (!busy) std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
  }
  // Rank 0's work loop asks here: the cell it finished (-1 at first); returns its next cell or -1.
  long local_next(long done) {
    std::unique_lock<std::mutex> lk(mu_);
    local_done_ = done;
    local_request_ = true;
    local_assigned_ = -3;
    cv_.wait(lk, [&] { return local_assigned_ != -3; });
    return local_assigned_;
  }

 private:
  void finished(long k) {
    if (k >= 0 && std::size_t(k) < state_.size()) state_[std::size_t(k)] = 2;
  }
  // The next ready cell (marked running), -1 when every cell is handed out, -2 when cells remain
  // but each needs a run that a running cell trains.
  long next_ready() {
    bool pending = false;
    for (std::size_t k = 0; k < state_.size(); ++k) {
      if (state_[k] != 0) continue;
      pending = true;
      bool ready = true;
      for (const auto& run : grid_.jobs()[k].plan.runs) {
        if (run_finished(run)) continue;
        for (std::size_t r = 0; r < state_.size() && ready; ++r)
          if (state_[r] == 1) {
            const auto& used = grid_.jobs()[r].plan.runs;
            if (std::find(used.begin(), used.end(), run) != used.end()) ready = false;
          }
      }
      if (ready) {
        state_[k] = 1;
        return long(k);
      }
    }
    return pending ? -2 : -1;
  }

  const Grid& grid_;
  const mpi::World& world_;
  std::vector<int> state_;  // per cell: 0 pending, 1 running, 2 done
  std::mutex mu_;
  std::condition_variable cv_;
  bool local_request_ = false;
  long local_done_ = -1, local_assigned_ = -3;
};

std::vector<GridCell> collect(const Grid& grid, const fs::path& out, bool write) {
  std::vector<GridCell> cells;
  std::vector<std::string> missing;
  for (std::size_t k = 0; k < grid.jobs().size(); ++k) {
    GridCell c;
    if (grid.read_cell(k, c)) cells.push_back(c);
    else missing.push_back(std::to_string(k) + " " + grid.jobs()[k].plan.name);
  }
  if (!missing.empty()) {
    std::string list;
    for (std::size_t i = 0; i < missing.size() && i < 40; ++i) list += (i ? ", " : "") + missing[i];
    if (missing.size() > 40) list += ", ... (" + std::to_string(missing.size() - 40) + " more)";
    reject("out", out.string(),
           "a sweep folder whose cells are all finished; " + std::to_string(missing.size()) + " of " + std::to_string(grid.jobs().size()) +
               " are not (or their inputs changed since): " + list + ". Run them (qdo sweep with the same options, or --cell K / --shard i/n), then collect");
  }
  if (write) write_grid_tables(out, cells, grid.seed_axis());
  return cells;
}

}  // namespace

std::vector<PlannedCell> plan_grid(const GridOptions& g) {
  const Grid grid(g);
  std::vector<PlannedCell> out;
  for (const auto& j : grid.jobs()) out.push_back(j.plan);
  return out;
}

void run_grid_cells(Runtime& rt, const GridOptions& g, const std::vector<std::size_t>& which, bool progress) {
  Grid grid(g);
  for (std::size_t k : which)
    if (k >= grid.jobs().size()) reject("cell", k, "a cell index in [0, " + std::to_string(grid.jobs().size() - 1) + "] (qdo sweep --plan lists them)");
  for (std::size_t k : which) grid.run_cell(rt, k, progress);
}

std::vector<GridCell> collect_grid(const GridOptions& g) {
  const Grid grid(g);
  return collect(grid, fs::path(g.out), true);
}

std::vector<GridCell> run_grid(Runtime& rt, const GridOptions& g) {
  Grid grid(g);
  const mpi::World* world = mpi::world();
  if (!world || !world->active() || world->size() < 2) {
    for (std::size_t k = 0; k < grid.jobs().size(); ++k) grid.run_cell(rt, k, !g.quiet);
    return collect(grid, fs::path(g.out), true);
  }
  if (world->rank() != 0) {  // a worker: ask rank 0 for cells until it says stop
    long done = -1;
    for (;;) {
      world->send(0, kRequest, done);
      const mpi::Message m = world->receive_any();
      if (m.tag == kStop) break;
      grid.run_cell(rt, std::size_t(m.value), !g.quiet);
      done = long(m.value);
    }
    return {};
  }
  Dispatcher d(grid, *world);
  std::thread serving([&] {
    try {
      d.serve();
    } catch (const std::exception& e) {
      std::fprintf(stderr, "qdo sweep: the MPI dispatcher failed: %s\n", e.what());
      world->abort(1);
    }
  });
  try {
    long k = d.local_next(-1);
    while (k >= 0) {
      grid.run_cell(rt, std::size_t(k), !g.quiet);
      k = d.local_next(k);
    }
  } catch (...) {
    serving.detach();  // the caller ends the job (MPI_Abort)
    throw;
  }
  serving.join();
  return collect(grid, fs::path(g.out), true);
}

}  // namespace qdo
