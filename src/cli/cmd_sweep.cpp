// qdo sweep: a grid of designs (levels x modes x encoders), each designed and evaluated, with summary
// tables (sweep.hpp); sharded, resumable, and one cell per Slurm array task.
#include <algorithm>
#include <cstdlib>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>

#include "cli.hpp"
#include "options.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/design/design_run.hpp"
#include "qdo/data/io.hpp"
#include "qdo/runtime/mpi.hpp"
#include "qdo/design/run.hpp"
#include "qdo/evaluate/sweep.hpp"

namespace fs = std::filesystem;
using namespace qdo;
using namespace qdo::cli;

namespace qdo::cli {
namespace {

void print_cells(const std::vector<GridCell>& cells) {
  std::printf("%-6s %-7s %-9s %9s %8s %8s %8s %10s\n", "seed", "levels", "mode", "PSNR", "SSIM", "RMSE", "ERGAS", "dev [nm]");
  for (const auto& c : cells)
    std::printf("%-6llu %-7s %-9s %9.2f %8.4f %8.4f %8.2f %10.2f\n", (unsigned long long)c.seed,
                c.levels == 0 ? "full" : c.levels < 0 ? "n/a" : std::to_string(c.levels).c_str(), c.mode.c_str(), c.mean.psnr,
                c.mean.ssim, c.mean.rmse, c.mean.ergas, c.deviation_nm);
}

}  // namespace

static int cmd_sweep(const Args& a) {
  GridOptions g;
  Args b = a;
  b.opt["out"] = "(per run)";
  b.opt["mode"] = "do";
  g.base = design_options(b);  // qdo design's options; levels and mode are set per cell
  const auto grids = a.multi.find("grid");
  std::set<std::string> axes;
  for (const auto& spec : grids == a.multi.end() ? std::vector<std::string>{} : grids->second) {
    const auto eq = spec.find('=');
    if (eq == std::string::npos) reject("--grid", spec, "AXIS=V1,V2,... with AXIS levels, mode, encoder, decoder or seed");
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
  g.test_data = scene_paths(a, "test-data");
  g.eval_synthetic_scenes = std::size_t(parse_int("--eval-scenes", a.get("eval-scenes"), 1, 10000));
  // An option no cell of this grid uses is refused, naming where it acts (as qdo design does for
  // its one run); one that some cells use applies to those.
  {
    const bool levels_trained = std::any_of(g.modes.begin(), g.modes.end(), [](const std::string& m) { return m == "qdo+a" || m == "qdo+m"; });
    const bool network = g.decoders.empty() ? g.base.decoder.network()
                                            : std::any_of(g.decoders.begin(), g.decoders.end(), [](const DecoderSpec& d) { return d.network(); });
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
        reject(std::string("--") + r.option, a.get(r.option), std::string("an option of ") + r.where + "; no cell of this grid uses it: leave it out");
  }
  // What to do: every cell (the default), the plan, some cells, or the tables of finished cells.
  const int actions = int(a.has("plan")) + int(a.has("cell")) + int(a.has("shard")) + int(a.has("collect"));
  if (actions > 1) reject("--plan/--cell/--shard/--collect", "more than one", "one of them at a time");
  const mpi::World* world = mpi::world();
  const bool ranks = world && world->active() && world->size() > 1;
  if (ranks && actions > 0)
    reject(a.has("plan") ? "--plan" : a.has("cell") ? "--cell" : a.has("shard") ? "--shard" : "--collect", "(given under mpirun)",
           "a sweep without mpirun (under mpirun, rank 0 hands out the cells itself)");
  g.quiet = false;
  if (a.has("plan")) {  // no device, no files: the cells and the runs each trains or reads
    g.out = a.get("out");
    if (g.out.empty()) reject("--out", "(missing)", "the sweep folder the cells will be written to");
    const auto plan = plan_grid(g);
    std::printf("# %zu cells of sweep %s (qdo sweep ... --cell K runs cell K; a Slurm job array: --array=0-%zu and --cell "
                "$SLURM_ARRAY_TASK_ID, or --cell slurm)\n",
                plan.size(), g.out.c_str(), plan.size() - 1);
    std::printf("%s\t%s\t%s\t%s\t%s\t%s\n", "cell", "name", "mode", "levels", "seed", "runs");
    for (const auto& c : plan) {
      std::string runs;
      for (const auto& r : c.runs) runs += (runs.empty() ? "" : ",") + fs::path(r).filename().string();
      std::printf("%zu\t%s\t%s\t%d\t%llu\t%s\n", c.index, c.name.c_str(), c.mode.c_str(), c.levels, (unsigned long long)c.seed,
                  runs.c_str());
    }
    return 0;
  }
  if (a.has("collect")) {  // reads the finished cells, trains and evaluates nothing
    g.out = a.get("out");
    if (g.out.empty() || !fs::is_directory(g.out)) reject("--out", g.out.empty() ? "(missing)" : g.out, "the folder of a sweep whose cells were run");
    const auto t0 = std::chrono::steady_clock::now();
    const auto cells = collect_grid(g);
    print_cells(cells);
    std::printf("%.1f s; %zu cells collected; wrote %s/ (table1.md table1.csv table2.md table2.csv comparisons.md comparisons.csv "
                "differences.png differences.svg psnr_vs_levels.png)\n", seconds_since(t0), cells.size(), g.out.c_str());
    return 0;
  }
  std::vector<std::size_t> which;
  if (a.has("cell") || a.has("shard")) {
    g.out = a.get("out");
    const auto plan = plan_grid(g);  // validates the options before any folder is made
    const long n = long(plan.size());
    if (a.has("cell")) {
      std::string v = a.get("cell");
      if (v == "slurm") {
        const char* id = std::getenv("SLURM_ARRAY_TASK_ID");
        if (!id || !*id) reject("--cell", v, "a cell index, or slurm inside a Slurm job array (SLURM_ARRAY_TASK_ID is not set here)");
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
  }
  // The output folder is claimed once (rank 0 under mpirun; the others go on once it has it).
  if (ranks && world->rank() != 0) {
    world->barrier();
    g.out = a.get("out");
  } else {
    g.out = out_dir(a);
    if (ranks) world->barrier();
  }
  Runtime rt(process_device(a.get("device")));
  const auto t0 = std::chrono::steady_clock::now();
  if (!which.empty() || a.has("shard")) {
    run_grid_cells(rt, g, which);
    std::printf("%.0f s; %zu cell(s) run into %s/ (qdo sweep ... --collect writes the tables once every cell is finished)\n",
                seconds_since(t0), which.size(), g.out.c_str());
    return 0;
  }
  const auto cells = run_grid(rt, g);
  if (ranks && world->rank() != 0) return 0;  // rank 0 writes the tables and prints them
  print_cells(cells);
  std::printf("%.0f s; wrote %s/ (runs/ cells/ table1.md table1.csv table2.md table2.csv comparisons.md comparisons.csv "
              "differences.png differences.svg psnr_vs_levels.png%s)\n",
              seconds_since(t0), g.out.c_str(), g.seeds.empty() ? "" : " table1_seeds.csv");
  return 0;
}

namespace {
// qdo sweep: its entry in the command table (help order 180).
const RegisterCommand registered_sweep(180, [] {
  using namespace opts;
  CommandSpec c{"sweep", "a grid of designs (levels x modes x encoders), each designed and evaluated, with summary tables", "", "",
                   concat({{"grid", "a grid axis AXIS=V1,V2,...: levels=2,4,8; mode=do,do-refit,do-finetune,qdo,qdo+a; "
                                    "encoder=doe,fresnel,cassi; decoder=wiener,resunet; seed=1,2,3 (repeatable)",
                            "", false, true},
                           opt("finetune-steps", "do-finetune with a network decoder: network steps with the DOE frozen, an integer in [1, 100000000]", "100"),
                           preset(), config(), placement(), parameterization(), objective(),
                           data("training scenes (default: synthetic scenes)"), data_root(),
                           opt("test-data", "test scenes: dataset names under the data root, CAVE folders, cube files or folders of "
                                            "them, comma-separated (default: synthetic)"),
                           opt("eval-scenes", "synthetic test scenes, an integer in [1, 10000]", "4"),
                           opt("seeds", "N seeds as a grid axis: --seed, --seed + 1, ..., an integer in [1, 1000] (or --grid seed=S1,S2,...)"),
                           flag("plan", "print the grid's cells (index, name, mode, levels, seed, runs) and exit: nothing is run or written"),
                           opt("cell", "run cell K of --plan's list only (its runs, then its evaluation), no tables; K = slurm reads "
                                       "SLURM_ARRAY_TASK_ID"),
                           opt("shard", "run shard i/n of the cells only (cells i, i + n, ...), no tables"),
                           flag("collect", "write the tables from the finished cells only, naming any that are not finished")},
                          concat(training_options(), {precision(), device(), out_dir_opt()})),
                   cmd_sweep, true};
  return c;
});
}  // namespace

}  // namespace qdo::cli
