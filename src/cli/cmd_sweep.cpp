// qdo sweep: a grid of designs (levels x modes x encoders), each designed and evaluated, with summary
// tables (sweep.hpp); sharded, resumable, and one cell per Slurm array task. The grid is read from
// the options by the library (sweep_text.hpp); this file picks the action, claims --out and prints.
#include <chrono>
#include <cstdio>

#include "cli.hpp"
#include "qdo/design/design_run.hpp"
#include "qdo/evaluate/sweep_text.hpp"
#include "qdo/runtime/mpi.hpp"

namespace qdo::cli {

static int cmd_sweep(const Args& a) {
  GridOptions g = grid_options_from_options(a);
  const mpi::World* world = mpi::world();
  const bool ranks = world && world->active() && world->size() > 1;
  const SweepAction action = sweep_action_from_options(a, ranks);
  g.quiet = false;
  if (action == SweepAction::Plan) std::fputs(grid_plan_table(plan_grid(g), g.out).c_str(), stdout);
  if (action == SweepAction::Collect) std::fputs(collect_grid_report(g).c_str(), stdout);  // trains and evaluates nothing
  if (action == SweepAction::Plan || action == SweepAction::Collect) return 0;
  const std::vector<std::size_t> which = grid_selection(a, g);  // validates the options before any folder is made
  // The output folder is claimed once (rank 0 under mpirun; the others go on once it has it).
  if (!ranks || world->rank() == 0) g.out = out_dir(a);
  if (ranks) world->barrier();
  Runtime rt(process_device(a.get("device")));
  const auto t0 = std::chrono::steady_clock::now();
  if (action == SweepAction::Cells) {
    run_grid_cells(rt, g, which);
    std::fputs(grid_cells_run_report(g, which, seconds_since(t0)).c_str(), stdout);
    return 0;
  }
  const auto cells = run_grid(rt, g);
  if (!ranks || world->rank() == 0) std::fputs(grid_report(cells, g, seconds_since(t0)).c_str(), stdout);  // rank 0 writes the tables
  return 0;
}

// qdo sweep: its entry in the command table (help order 180).
const RegisterCommand registered_sweep(180, [] {
  using namespace opts;
  return CommandSpec{"sweep", "a grid of designs (levels x modes x encoders), each designed and evaluated, with summary tables", "", "",
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
});

}  // namespace qdo::cli
