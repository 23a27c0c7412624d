// qdo sweep-psf's options, and qdo sweep's experiment grid (sweep.hpp), read from options as a user typed them
// (TextOptions, qdo/runtime/parse.hpp), the cells a process runs, and the grid's tables as text. Every refusal is an
// InputError naming the option as typed ("--grid"), the value and what is allowed, before any device work.
#pragma once
#include <cstddef>
#include <string>
#include <vector>

#include "qdo/evaluate/sweep.hpp"
#include "qdo/runtime/parse.hpp"

namespace qdo {

// The grid: qdo design's options (design_run_options_from_options; levels and mode are set per
// cell), each --grid AXIS=V1,V2,... (repeatable: a.all("grid"); axes levels, mode, encoder, decoder, seed, each once,
// values distinct; a decoder spec's own key=value items stay with it), --seeds N (seeds --seed ..
// --seed + N - 1), --finetune-steps, --test-data, --eval-scenes. An option no cell of the grid uses
// (--beta without qdo+a or qdo+m, ...) is refused, naming where it acts. g.out: --out as given.
GridOptions grid_options_from_options(const TextOptions& a);
// What one qdo sweep process does: every cell (All), --plan (list the cells: no device, no files;
// --out required), --cell / --shard (some cells, no tables) or --collect (the tables from finished
// cells; --out an existing sweep folder). At most one of them, and none under mpirun (rank 0
// hands out the cells itself): an InputError naming them otherwise.
enum class SweepAction { All, Plan, Cells, Collect };
SweepAction sweep_action_from_options(const TextOptions& a, bool under_mpirun);
// --collect: collect_grid(g) and its report (the cells' table, seconds, the files written).
std::string collect_grid_report(const GridOptions& g);
// After run_grid_cells(g, which): the seconds, the count of cells run and where (no tables).
std::string grid_cells_run_report(const GridOptions& g, const std::vector<std::size_t>& which, double seconds);
// After run_grid: the cells' table, the seconds and the files written into g.out.
std::string grid_report(const std::vector<GridCell>& cells, const GridOptions& g, double seconds);
// The cells --cell K (K = slurm: $SLURM_ARRAY_TASK_ID) or --shard i/n (cells i, i + n, ...) select,
// indices into plan_grid(g) (g.out set); empty when neither option is given.
std::vector<std::size_t> grid_selection(const TextOptions& a, const GridOptions& g);
// `qdo sweep --plan`'s listing: a comment line (the cell count, how to run one), then one
// tab-separated line per cell: index, name, mode, levels, seed, run folders. Lines end with "\n".
std::string grid_plan_table(const std::vector<PlannedCell>& plan, const std::string& out);
// The cells' table: seed, levels, mode, PSNR, SSIM, RMSE, ERGAS, deviation (nm). Lines end with "\n".
std::string grid_cells_table(const std::vector<GridCell>& cells);

// qdo sweep-psf's options as a user typed them (TextOptions: design (a design .h5, or a run folder
// whose config.json is then the configuration: no preset or config), preset, config, levels
// (distinct counts, comma-separated), placement, adaptive-from, precision, designs-per-pass), each
// checked and the design read (InputError naming the option as typed). o.out is left empty.
PsfSweepOptions psf_sweep_options_from_options(const TextOptions& a);
// The variants' table: label, levels, deviation (nm), and the means over the bands of the relative
// L2 error, peak ratio, EE80 (um) and energy outside the window. Lines end with "\n".
std::string psf_sweep_table(const std::vector<PsfSweepRow>& rows);

}  // namespace qdo
