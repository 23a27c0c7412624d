// qdo sweep's grid read from options as typed, its cell selection, and its tables as text
// (sweep_text.hpp).
#include "qdo/evaluate/sweep_text.hpp"

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <set>

#include "qdo/design/design_run_text.hpp"
#include "qdo/design/option_inputs.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/strprintf.hpp"
#include "qdo/runtime/util.hpp"

namespace fs = std::filesystem;

namespace qdo {

GridOptions grid_options_from_options(const TextOptions& a) {
  GridOptions g;
  TextOptions b = a;
  b.opt["out"] = "(per run)";
  b.opt["mode"] = "do";
  g.base = design_run_options_from_options(b);  // qdo design's options; levels and mode are set per cell
  std::set<std::string> axes;
  for (const auto& spec : a.all("grid")) {
    const auto eq = spec.find('=');
    if (eq == std::string::npos)
      reject("--grid", spec, "AXIS=V1,V2,... with AXIS levels, mode, encoder, decoder or seed");
    const std::string axis = spec.substr(0, eq);
    if (axis != "levels" && axis != "mode" && axis != "encoder" && axis != "decoder" && axis != "seed")
      reject("--grid", axis, "levels, mode, encoder, decoder or seed");
    if (!axes.insert(axis).second) reject("--grid", spec, "each axis once (" + axis + " is given twice)");
    std::vector<std::string> vals = split_items(spec.substr(eq + 1));
    // A decoder spec holds commas of its own (resunet:depth=4,root=16): a key=value item after a
    // spec with parameters belongs to it.
    if (axis == "decoder") {
      std::vector<std::string> joined;
      for (const auto& v : vals) {
        if (!joined.empty() && v.find('=') != std::string::npos && v.find(':') == std::string::npos &&
            joined.back().find(':') != std::string::npos)
          joined.back() += "," + v;
        else
          joined.push_back(v);
      }
      vals = joined;
    }
    if (vals.empty()) reject("--grid", spec, "at least one value after " + axis + "=");
    std::set<std::string> distinct(vals.begin(), vals.end());
    if (distinct.size() != vals.size()) reject("--grid", spec, "distinct values on the " + axis + " axis");
    if (axis == "levels") {
      g.levels.clear();
      for (const auto& v : vals) g.levels.push_back(parse_int("--grid levels", v, 2, 256));
    } else if (axis == "mode") {
      g.modes = vals;
    } else if (axis == "encoder") {
      g.encoders = vals;
    } else if (axis == "decoder") {
      g.decoders.clear();
      for (const auto& v : vals) g.decoders.push_back(decoder_spec_from_string(v));
    } else if (axis == "seed") {
      for (const auto& v : vals) g.seeds.push_back(std::uint64_t(parse_int("--grid seed", v, 0, 2147483647)));
    } else {
      reject("--grid", axis, "levels, mode, encoder, decoder or seed");
    }
  }
  if (a.has("seeds")) {
    if (axes.count("seed")) reject("--seeds", a.get("seeds"), "omitted with --grid seed=... (one seed axis)");
    const std::uint64_t first = g.base.design.seed;
    const int n = parse_int("--seeds", a.get("seeds"), 1, 1000);
    for (int i = 0; i < n; ++i) g.seeds.push_back(first + std::uint64_t(i));
  }
  g.finetune_steps = std::size_t(parse_int("--finetune-steps", a.get("finetune-steps", "100"), 1, 100000000));
  g.test_data = scene_paths_from_options(a, "test-data");
  g.eval_synthetic_scenes = std::size_t(parse_int("--eval-scenes", a.get("eval-scenes", "4"), 1, 10000));
  // An option no cell of this grid uses is refused, naming where it acts (as qdo design does for
  // its one run); one that some cells use applies to those.
  {
    const bool levels_trained =
        std::any_of(g.modes.begin(), g.modes.end(), [](const std::string& m) { return m == "qdo+a" || m == "qdo+m"; });
    const bool network = g.decoders.empty() ? g.base.decoder.network()
                                            : std::any_of(g.decoders.begin(), g.decoders.end(),
                                                          [](const DecoderSpec& d) { return d.network(); });
    const bool finetune_net = network && std::find(g.modes.begin(), g.modes.end(), "do-finetune") != g.modes.end();
    const bool psf_target = g.base.objective == Objective::PsfTarget;
    const bool wiener = !psf_target;
    const struct {
      const char* option;
      bool used;
      const char* where;
    } rules[] = {
        {"beta", levels_trained, "a grid with mode qdo+a or qdo+m"},
        {"lr-offsets", levels_trained, "a grid with mode qdo+a or qdo+m"},
        {"lr-decoder", network, "a grid with a network decoder"},
        {"gamma", network, "a grid with a network decoder"},
        {"finetune-steps", finetune_net, "a grid with mode do-finetune and a network decoder"},
        {"target", psf_target, "--objective psf-target"},
        {"wiener-on", wiener, "the Wiener objectives"},
    };
    for (const auto& r : rules)
      if (a.has(r.option) && !r.used)
        reject(std::string("--") + r.option, a.get(r.option),
               std::string("an option of ") + r.where + "; no cell of this grid uses it: leave it out");
  }
  g.out = a.get("out");
  return g;
}

SweepAction sweep_action_from_options(const TextOptions& a, bool under_mpirun) {
  const int actions = int(a.has("plan")) + int(a.has("cell")) + int(a.has("shard")) + int(a.has("collect"));
  if (actions > 1) reject("--plan/--cell/--shard/--collect", "more than one", "one of them at a time");
  if (under_mpirun && actions > 0)
    reject(a.has("plan")    ? "--plan"
           : a.has("cell")  ? "--cell"
           : a.has("shard") ? "--shard"
                            : "--collect",
           "(given under mpirun)", "a sweep without mpirun (under mpirun, rank 0 hands out the cells itself)");
  const std::string out = a.get("out");
  if (a.has("plan") && out.empty()) reject("--out", "(missing)", "the sweep folder the cells will be written to");
  if (a.has("collect") && (out.empty() || !fs::is_directory(out)))
    reject("--out", out.empty() ? "(missing)" : out, "the folder of a sweep whose cells were run");
  return a.has("plan")      ? SweepAction::Plan
         : a.has("collect") ? SweepAction::Collect
         : actions > 0      ? SweepAction::Cells
                            : SweepAction::All;
}

std::string collect_grid_report(const GridOptions& g) {
  const auto t0 = std::chrono::steady_clock::now();
  const auto cells = collect_grid(g);
  return grid_cells_table(cells) + strprintf(
                                       "%.1f s; %zu cells collected; wrote %s/ (table1.md table1.csv table2.md "
                                       "table2.csv comparisons.md comparisons.csv "
                                       "differences.png differences.svg psnr_vs_levels.png)\n",
                                       seconds_since(t0), cells.size(), g.out.c_str());
}

std::string grid_cells_run_report(const GridOptions& g, const std::vector<std::size_t>& which, double seconds) {
  return strprintf(
      "%.0f s; %zu cell(s) run into %s/ (qdo sweep ... --collect writes the tables once every cell is finished)\n",
      seconds, which.size(), g.out.c_str());
}

std::string grid_report(const std::vector<GridCell>& cells, const GridOptions& g, double seconds) {
  return grid_cells_table(cells) +
         strprintf(
             "%.0f s; wrote %s/ (runs/ cells/ table1.md table1.csv table2.md table2.csv comparisons.md comparisons.csv "
             "differences.png differences.svg psnr_vs_levels.png%s)\n",
             seconds, g.out.c_str(), g.seeds.empty() ? "" : " table1_seeds.csv");
}

std::vector<std::size_t> grid_selection(const TextOptions& a, const GridOptions& g) {
  std::vector<std::size_t> which;
  if (!a.has("cell") && !a.has("shard")) return which;
  const auto plan = plan_grid(g);  // validates the options before any folder is made
  const long n = long(plan.size());
  if (a.has("cell")) {
    std::string v = a.get("cell");
    if (v == "slurm") {
      const char* id = std::getenv("SLURM_ARRAY_TASK_ID");
      if (!id || !*id)
        reject("--cell", v, "a cell index, or slurm inside a Slurm job array (SLURM_ARRAY_TASK_ID is not set here)");
      v = id;
    }
    which.push_back(std::size_t(parse_int("--cell", v, 0, int(std::max(0L, n - 1)))));
  } else {
    const std::string v = a.get("shard");
    const auto slash = v.find('/');
    if (slash == std::string::npos) reject("--shard", v, "i/n: shard i (from 0) of n, cells i, i + n, i + 2n, ...");
    const int parts = parse_int("--shard n", v.substr(slash + 1), 1, 1000000);
    const int i = parse_int("--shard i", v.substr(0, slash), 0, parts - 1);
    for (long k = i; k < n; k += parts) which.push_back(std::size_t(k));
  }
  return which;
}

std::string grid_plan_table(const std::vector<PlannedCell>& plan, const std::string& out) {
  std::string s = strprintf(
      "# %zu cells of sweep %s (qdo sweep ... --cell K runs cell K; a Slurm job array: --array=0-%zu and --cell "
      "$SLURM_ARRAY_TASK_ID, or --cell slurm)\n",
      plan.size(), out.c_str(), plan.size() - 1);
  s += strprintf("%s\t%s\t%s\t%s\t%s\t%s\n", "cell", "name", "mode", "levels", "seed", "runs");
  for (const auto& c : plan) {
    std::string runs;
    for (const auto& r : c.runs) runs += (runs.empty() ? "" : ",") + fs::path(r).filename().string();
    s += strprintf("%zu\t%s\t%s\t%d\t%llu\t%s\n", c.index, c.name.c_str(), c.mode.c_str(), c.levels,
                   (unsigned long long)c.seed, runs.c_str());
  }
  return s;
}

std::string grid_cells_table(const std::vector<GridCell>& cells) {
  std::string s = strprintf("%-6s %-7s %-9s %9s %8s %8s %8s %10s\n", "seed", "levels", "mode", "PSNR", "SSIM", "RMSE",
                            "ERGAS", "dev [nm]");
  for (const auto& c : cells)
    s += strprintf("%-6llu %-7s %-9s %9.2f %8.4f %8.4f %8.2f %10.2f\n", (unsigned long long)c.seed,
                   c.levels == 0  ? "full"
                   : c.levels < 0 ? "n/a"
                                  : std::to_string(c.levels).c_str(),
                   c.mode.c_str(), c.mean.psnr, c.mean.ssim, c.mean.rmse, c.mean.ergas, c.deviation_nm);
  return s;
}

PsfSweepOptions psf_sweep_options_from_options(const TextOptions& a) {
  PsfSweepOptions o;
  const std::string design = a.get("design");
  if (design.empty()) reject("--design", "(missing)", "a design .h5 file or a run folder");
  if (fs::is_directory(design)) {
    if (a.has("preset") || a.has("config"))
      reject("--preset", "(given)", "omitted with a run folder (its config.json is used)");
    o.cfg = read_run_config(design).cfg;
    o.design_full_m = RunFolder(design).design_full().height_m;
  } else {
    o.cfg = config_from_options(a);
    o.design_full_m = design_heights_from_spec(o.cfg, design, "--design");
  }
  const Placement pl = placement_from_string(a.get("placement", "inclusive"));
  std::set<int> seen_levels;
  for (const auto& l : split_items(a.get("levels", "2,4,8,16,32"))) {
    PsfSweepVariant v;
    v.quantizer.levels = parse_int("--levels", l, 2, 65536);
    if (!seen_levels.insert(v.quantizer.levels).second)
      reject("--levels", a.get("levels"), "distinct level counts (" + l + " appears twice)");
    v.quantizer.placement = pl;
    v.label = "L" + l;
    o.variants.push_back(v);
  }
  if (a.has("adaptive-from")) {
    const PsfSweepVariant v = adaptive_psf_sweep_variant(a.get("adaptive-from"), "--adaptive-from");
    o.variants.push_back(v);
  }
  o.precision = precision_from_string(a.get("precision", "f32"));
  o.max_designs_per_pass = std::size_t(parse_int("--designs-per-pass", a.get("designs-per-pass", "0"), 0, 1000));
  return o;
}

std::string psf_sweep_table(const std::vector<PsfSweepRow>& rows) {
  std::string s = strprintf("%-14s %7s %12s %12s %12s %12s %14s\n", "variant", "levels", "dev [nm]", "rel L2",
                            "peak ratio", "EE80 [um]", "outside win.");
  const auto mean = [](const std::vector<double>& v) {
    double sum = 0;
    for (double x : v) sum += x;
    return sum / double(v.size());
  };
  for (const auto& r : rows)
    s += strprintf("%-14s %7d %12.3f %12.4f %12.4f %12.2f %14.4f\n", r.label.c_str(), r.levels, r.deviation_nm,
                   mean(r.rel_l2), mean(r.peak_ratio), mean(r.ee80_um), mean(r.energy_outside));
  return s;
}

}  // namespace qdo
