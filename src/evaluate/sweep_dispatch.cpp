// The running of the sweep's grid cells by any process: cells by index (Slurm job array tasks),
// every cell in one process or over MPI ranks (rank 0's dispatcher), and collecting the finished
// cells into the tables.
#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <deque>
#include <filesystem>
#include <mutex>
#include <thread>

#include "evaluate/sweep_internal.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/mpi.hpp"
#include "qdo/evaluate/sweep.hpp"

namespace fs = std::filesystem;

namespace qdo {

using namespace sweep_detail;

namespace {

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
