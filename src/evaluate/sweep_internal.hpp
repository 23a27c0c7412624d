// The sweep's private helpers (sweep.cpp), shared by its parts: the grid's plan (sweep_grid.cpp),
// its cells (sweep_cells.cpp), their running and collection (sweep_dispatch.cpp) and its tables
// (sweep_tables.cpp).
#pragma once
#include <nlohmann/json.hpp>

#include <filesystem>
#include <set>
#include <string>
#include <vector>

#include "qdo/design/design_run_options.hpp"
#include "qdo/evaluate/eval.hpp"
#include "qdo/runtime/hash.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/evaluate/sweep.hpp"

namespace qdo::sweep_detail {

bool run_finished(const std::filesystem::path& run);  // RUN/DONE exists
// The bytes of a file, or of every regular file under a folder (sorted by path, each with its
// relative path and size); "missing" for a path that does not exist. Of `p` itself only its last
// name enters, never its spelling (sw, ./sw/ and $PWD/sw name the same inputs).
void hash_path(Fnv1a64& f, const std::filesystem::path& p);
std::string hash_paths(const std::vector<std::string>& paths);
std::string read_text(const std::filesystem::path& p);
// Test cubes as S x S patches, as evaluate_run cuts them (bands x S x S each).
std::vector<RealStack> test_patches(const SystemConfig& cfg, const std::vector<std::string>& test, std::size_t synthetic,
                                    std::uint64_t seed);
// cells/NAME/metrics.json and inputs of a cell scored outside evaluate_run (fresnel, cassi).
void write_cell_metrics(const std::filesystem::path& dir, const GridCell& c);
// InputError naming the differences when the run folder o.out holds a run made with other options
// (its config.json, `ignore`d fields aside) or other training scenes (`inputs`, its sweep_inputs).
void check_run_inputs(const DesignRunOptions& o, const std::string& inputs, const std::string& sweep_out,
                      const std::set<std::string>& ignore);
// A training run of the sweep: refused when its folder holds a run of other options or scenes,
// skipped when finished (RUN/DONE), else trained or resumed; `ignore`: config fields that do not
// change what the sweep reads from the run. `inputs`: the hash of the training scenes' bytes.
void ensure_run(Runtime& rt, const DesignRunOptions& o, const std::string& inputs, bool quiet, const std::string& sweep_out,
                const std::set<std::string>& ignore = {"design.checkpoint_every"});
// ensure_run that waits (polling every 2 s) while another process holds the run's lock.
void ensure_run_waiting(Runtime& rt, const DesignRunOptions& o, const std::string& inputs, bool quiet,
                        const std::string& sweep_out, const std::set<std::string>& ignore = {"design.checkpoint_every"});

// The tables, figures and comparisons of the cells (sweep_tables.cpp); `seed_axis`: the grid has one.
void write_grid_tables(const std::filesystem::path& out, const std::vector<GridCell>& cells, bool seed_axis);

// The experiment grid: its plan (the constructor, sweep_grid.cpp) and its cells (sweep_cells.cpp).
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
  std::filesystem::path out_;
  std::vector<Job> jobs_;
};

}  // namespace qdo::sweep_detail
