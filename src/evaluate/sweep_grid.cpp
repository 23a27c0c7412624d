// The experiment grid of `qdo sweep`: its plan, a fixed list of cells (Grid, sweep_internal.hpp).
// Its cells are sweep_cells.cpp, their running by any process (one sweep, Slurm job array tasks,
// MPI ranks) sweep_dispatch.cpp; sweep.cpp the run and cell helpers, sweep_tables.cpp the tables.
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <set>
#include <utility>

#include "evaluate/sweep_internal.hpp"
#include "qdo/data/datasets.hpp"
#include "qdo/decode/decoder_registry.hpp"
#include "qdo/design/design_run.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/evaluate/sweep.hpp"

namespace fs = std::filesystem;

namespace qdo {

using namespace sweep_detail;

namespace {

// Runs of decoder `dec`: Wiener runs keep the names they always had, network runs carry the spec.
std::string tag_of(const DecoderSpec& dec) {
  if (dec.kind == DecoderSpec::Kind::Wiener) return std::string();
  std::string t = "_";
  for (char ch : dec.to_string()) t += ch == ':' || ch == ',' ? '-' : ch == '=' ? '\0' : ch;
  t.erase(std::remove(t.begin(), t.end(), '\0'), t.end());
  return t;
}

}  // namespace

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
    if (d.kind == DecoderSpec::Kind::ResUNet && !network_decoder_available())  // the LibTorch plugin
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

std::vector<PlannedCell> plan_grid(const GridOptions& g) {
  const Grid grid(g);
  std::vector<PlannedCell> out;
  for (const auto& j : grid.jobs()) out.push_back(j.plan);
  return out;
}

}  // namespace qdo
