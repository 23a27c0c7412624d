// `qdo sweep` beyond one process: the plan, Slurm-style cells and shards, --collect,
// and mpirun with rank 0 handing out cells; each must give the tables of the serial sweep. The
// seed axis and its statistics are checked on the same folders. Doctest suite "sweep-cluster".
#include <dirent.h>

#include <chrono>
#include <cmath>
#include <fstream>
#include <iterator>
#include <sstream>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <thread>

#include "svg_text.hpp"
#include "qdo/data/config.hpp"
#include "qdo/data/io.hpp"
#include "qdo/runtime/mpi.hpp"
#include "qdo/design/run.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/evaluate/sweep_stats.hpp"
#include "stress_common.hpp"

using namespace qdo;
using namespace qdo::test;
using namespace qdo::test::stress_suite;
namespace fs = std::filesystem;

namespace {

// The smallest grid with a shared DO run per seed and two seeds: 8 cells, 6 runs of 30 steps. Recipe
// qdo: random initial heights per seed (the seed statistics below need seeds that differ).
std::vector<std::string> grid_args(const std::string& cfg, const std::string& out, std::vector<std::string> extra = {}) {
  std::vector<std::string> a = {QDO_QDO_BINARY, "sweep", "--config", cfg, "--recipe", "qdo", "--grid", "levels=2", "--grid", "mode=do,qdo,qdo+a",
                                "--grid", "seed=5,6", "--epochs", "10", "--steps-per-epoch", "3", "--t0", "1", "--t1", "3",
                                "--synthetic-scenes", "3", "--eval-scenes", "2", "--out", out};
  a.insert(a.end(), extra.begin(), extra.end());
  return a;
}
std::vector<std::string> mpirun(int ranks, std::vector<std::string> args) {
  std::vector<std::string> a = {QDO_MPIEXEC, "-np", std::to_string(ranks), "--oversubscribe"};
  a.insert(a.end(), args.begin(), args.end());
  return a;
}
// OpenMPI refuses root unless told (the CI machine runs as root).
void allow_mpirun_as_root() {
  ::setenv("OMPI_ALLOW_RUN_AS_ROOT", "1", 1);
  ::setenv("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1", 1);
}

std::string config_file(const fs::path& dir) {
  const std::string cfg = (dir / "cfg.json").string();
  write_text_atomic(cfg, config_to_json_text(tiny_config(32, 3)));
  return cfg;
}

// The table files of a sweep as name -> (header, raw[c][row]) without the `inputs` column (a hash
// of paths and bytes: it differs between folders).
using Tables = std::map<std::string, CsvTable>;
Tables tables(const fs::path& out) {
  Tables t;
  for (const char* name : {"table1.csv", "table2.csv", "table1_seeds.csv", "comparisons.csv"}) {
    REQUIRE(fs::exists(out / name));
    t[name] = read_csv((out / name).string());
  }
  return t;
}
// Same cells, same text where not a number, numbers within 1e-6 relative: the processes share the
// kernel cache and its FFTW wisdom, so the values are normally identical; the tolerance only keeps
// a plan chosen differently under load (a rounding difference) from failing the comparison.
void check_same_tables(const Tables& got, const Tables& want) {
  for (const auto& [name, w] : want) {
    CAPTURE(name);
    const CsvTable& g = got.at(name);
    REQUIRE(g.header == w.header);
    for (std::size_t c = 0; c < w.header.size(); ++c) {
      if (w.header[c] == "inputs") continue;
      REQUIRE(g.raw[c].size() == w.raw[c].size());
      for (std::size_t r = 0; r < w.raw[c].size(); ++r) {
        CAPTURE(w.header[c]);
        CAPTURE(r);
        const double a = g.columns[c][r], b = w.columns[c][r];
        if (std::isnan(b)) CHECK(g.raw[c][r] == w.raw[c][r]);
        else CHECK(a == doctest::Approx(b).epsilon(1e-6));
      }
    }
  }
}

// The serial sweep every case compares with, made once per test binary.
struct Reference {
  fs::path dir, out;
  std::string cfg;
  Tables values;
  ~Reference() {
    std::error_code ec;
    if (!dir.empty()) fs::remove_all(dir, ec);
  }
};
const Reference& reference() {
  static Reference r;
  if (r.values.empty()) {
    r.dir = temp_dir("sweep_cluster_ref");
    r.cfg = config_file(r.dir);
    r.out = r.dir / "serial";
    Child c(grid_args(r.cfg, r.out.string()), (r.dir / "log.txt").string());
    const int code = c.exit_code();
    INFO(slurp((r.dir / "log.txt").string()));
    REQUIRE(code == 0);
    r.values = tables(r.out);
  }
  return r;
}

int run(const std::vector<std::string>& args, const fs::path& log) {
  Child c(args, log.string());
  return c.exit_code();
}

}  // namespace

TEST_SUITE("sweep-cluster") {
  TEST_CASE("the seed axis: mean ± sd over seeds, every seed's row, and the paired comparisons with their intervals") {
    const Reference& ref = reference();
    const CsvTable& t1 = ref.values.at("table1.csv");
    CHECK(t1.header[2] == "seeds");
    for (double n : t1.column("seeds")) CHECK(n == 2);
    // Each row's mean and sd are those of its two seeds' rows in table1_seeds.csv.
    const CsvTable& per_seed = ref.values.at("table1_seeds.csv");
    REQUIRE(per_seed.raw[0].size() == 8);
    for (std::size_t r = 0; r < t1.raw[0].size(); ++r) {
      std::vector<double> v;
      for (std::size_t s = 0; s < per_seed.raw[0].size(); ++s)
        if (per_seed.raw[1][s] == t1.raw[0][r] && per_seed.raw[2][s] == t1.raw[1][r]) v.push_back(per_seed.column("psnr_db")[s]);
      REQUIRE(v.size() == 2);
      CHECK(t1.column("psnr_db")[r] == doctest::Approx((v[0] + v[1]) / 2).epsilon(1e-5));
      CHECK(t1.column("psnr_db_sd")[r] == doctest::Approx(std::fabs(v[0] - v[1]) / std::sqrt(2.0)).epsilon(1e-4));
    }
    // qdo+a − do and qdo − do at L = 2, paired over 2 seeds x 2 test scenes; the interval holds the mean.
    const CsvTable& cmp = ref.values.at("comparisons.csv");
    REQUIRE(cmp.raw[0].size() == 2);
    CHECK(cmp.raw[1][0] == "qdo+a");
    CHECK(cmp.raw[2][0] == "do");
    CHECK(cmp.raw[1][1] == "qdo");
    for (std::size_t r = 0; r < 2; ++r) {
      CHECK(cmp.column("seeds")[r] == 2);
      CHECK(cmp.column("pairs")[r] == 4);
      CHECK(cmp.column("dpsnr_db_lo")[r] < cmp.column("dpsnr_db")[r]);
      CHECK(cmp.column("dpsnr_db")[r] < cmp.column("dpsnr_db_hi")[r]);
      // Over seeds: 1 degree of freedom, t = 12.706: wider than the 3-dof pair interval here.
      CHECK(cmp.column("dpsnr_db_seeds_hi")[r] - cmp.column("dpsnr_db_seeds_lo")[r] >
            cmp.column("dpsnr_db_hi")[r] - cmp.column("dpsnr_db_lo")[r]);
    }
    CHECK(fs::exists(ref.out / "differences.png"));
    const auto svg = svg_texts((ref.out / "differences.svg").string());  // the same figure, its texts
    CHECK(svg_has(svg, "L2  qdo+a − do  (4 pairs, 2 seeds)"));
    CHECK(svg_has(svg, "ΔPSNR a − b (dB)"));
    CHECK(slurp(ref.out / "table1.md").find(" ± ") != std::string::npos);
  }

  TEST_CASE("--plan, --cell, --shard and --collect: the cells of the serial sweep, run in any order by any process, give its tables") {
    const Reference& ref = reference();
    const auto dir = temp_dir("sweep_cluster_cells");
    const fs::path out = dir / "sweep", log = dir / "log.txt";
    // The plan: 8 cells in a fixed order, nothing written.
    REQUIRE(run(grid_args(ref.cfg, out.string(), {"--plan"}), log) == 0);
    const std::string plan = slurp(log);
    CAPTURE(plan);
    CHECK(has(plan, "0\tfull_s5\tfull\t0\t5\tdo_s5"));
    CHECK(has(plan, "3\tqdo+a_L2_s5\tqdo+a\t2\t5\tqdo+a_L2_s5"));
    CHECK(has(plan, "7\tqdo+a_L2_s6\tqdo+a\t2\t6\tqdo+a_L2_s6"));
    CHECK(!fs::exists(out));
    // One cell: its own run and evaluation only.
    REQUIRE(run(grid_args(ref.cfg, out.string(), {"--cell", "2"}), log) == 0);
    CHECK(fs::exists(out / "cells" / "qdo_L2_s5" / "metrics.json"));
    CHECK(fs::exists(out / "runs" / "qdo_L2_s5" / "DONE"));
    CHECK(!fs::exists(out / "runs" / "do_s5"));
    CHECK(!fs::exists(out / "table1.csv"));
    // --collect now: exit 2 naming the unfinished cells, no table written.
    fs::remove(log);
    CHECK(run(grid_args(ref.cfg, out.string(), {"--collect"}), log) == 2);
    const std::string missing = slurp(log);
    CAPTURE(missing);
    CHECK(has(missing, "7 of 8 are not"));
    CHECK(has(missing, "0 full_s5"));
    CHECK(!has(missing, "2 qdo_L2_s5"));
    CHECK(!fs::exists(out / "table1.csv"));
    // A cell another process is running is refused, naming it.
    {
      fs::create_directories(out / "cells" / "do_L2_s6");
      RunLock held((out / "cells" / "do_L2_s6").string(), "cell");
      fs::remove(log);
      CHECK(run(grid_args(ref.cfg, out.string(), {"--cell", "5"}), log) == 2);
      CHECK(has(slurp(log), "cell 5 (do_L2_s6) is being run by another process"));
    }
    // A Slurm job array task: --cell slurm reads SLURM_ARRAY_TASK_ID.
    ::setenv("SLURM_ARRAY_TASK_ID", "6", 1);
    CHECK(run(grid_args(ref.cfg, out.string(), {"--cell", "slurm"}), log) == 0);
    ::unsetenv("SLURM_ARRAY_TASK_ID");
    CHECK(fs::exists(out / "cells" / "qdo_L2_s6" / "metrics.json"));
    // The rest as two shards at once: both need each seed's DO run; one trains it, the other waits.
    Child a(grid_args(ref.cfg, out.string(), {"--shard", "0/2"}), (dir / "a.txt").string());
    Child b(grid_args(ref.cfg, out.string(), {"--shard", "1/2"}), (dir / "b.txt").string());
    CHECK(a.exit_code() == 0);
    CHECK(b.exit_code() == 0);
    const std::string logs = slurp(dir / "a.txt") + slurp(dir / "b.txt");
    INFO(logs);
    // Cells 2 and 6 were finished earlier and are not evaluated again.
    CHECK(has(slurp(dir / "a.txt"), "cell #2 of 8 qdo_L2_s5"));
    CHECK(has(slurp(dir / "a.txt"), "finished earlier"));
    fs::remove(log);
    REQUIRE(run(grid_args(ref.cfg, out.string(), {"--collect"}), log) == 0);
    check_same_tables(tables(out), ref.values);
    // Bad selections are refused before any work.
    fs::remove(log);
    CHECK(run(grid_args(ref.cfg, out.string(), {"--cell", "8"}), log) == 2);
    CHECK(has(slurp(log), "an integer in [0, 7]"));
    CHECK(run(grid_args(ref.cfg, out.string(), {"--shard", "2/2"}), log) == 2);
    CHECK(run(grid_args(ref.cfg, out.string(), {"--cell", "1", "--collect"}), log) == 2);
    CHECK(has(slurp(log), "one of them at a time"));
    fs::remove_all(dir);
  }

  TEST_CASE("mpirun -np 2: rank 0 hands out the cells, the serial sweep's tables; a killed rank ends the job, and reruns with and without mpirun complete it") {
    if (!skip_unless(mpi::built_with_mpi(), "qdo built without MPI (libopenmpi-dev missing)")) return;
    if (!skip_unless(fs::exists(QDO_MPIEXEC), std::string("no MPI launcher at ") + QDO_MPIEXEC)) return;
    allow_mpirun_as_root();
    const Reference& ref = reference();
    const auto dir = temp_dir("sweep_cluster_mpi");
    const fs::path out = dir / "sweep", log = dir / "log.txt";
    {
      const int code = run(mpirun(2, grid_args(ref.cfg, out.string())), log);
      INFO(slurp(log));
      REQUIRE(code == 0);
      check_same_tables(tables(out), ref.values);
    }
    // Options only a process without mpirun takes are refused under it.
    CHECK(run(mpirun(2, grid_args(ref.cfg, (dir / "x").string(), {"--collect"})), log) != 0);
    CHECK(has(slurp(log), "a sweep without mpirun"));
    // kill -9 of one rank as soon as the first seed's DO run has a checkpoint, then again under a
    // second mpirun that resumes, once it has finished a cell: each time mpirun ends the job.
    const fs::path out2 = dir / "killed";
    int killed = 0;
    auto cells_logged = [&] {
      const std::string text = fs::exists(dir / "killed.txt") ? slurp(dir / "killed.txt") : std::string();
      std::size_t n = 0;
      for (std::size_t p = text.find("[sweep] cell #"); p != std::string::npos; p = text.find("[sweep] cell #", p + 1)) ++n;
      return n;
    };
    for (int round = 0; round < 2; ++round) {
      const std::size_t before = cells_logged();
      Child job(mpirun(2, grid_args(ref.cfg, out2.string())), (dir / "killed.txt").string());
      // First: once the first DO run has a checkpoint; then: once the resuming job has finished a cell.
      auto due = [&] { return round == 0 ? fs::exists(out2 / "runs" / "do_s5" / "checkpoint.h5") : cells_logged() > before; };
      while (job.running() && !due()) std::this_thread::sleep_for(std::chrono::milliseconds(1));
      const std::vector<pid_t> ranks = children_of(job.pid());
      if (job.running() && !ranks.empty()) {
        ::kill(ranks.back(), SIGKILL);
        ++killed;
        CHECK(job.exit_code() != 0);
      } else {
        CHECK(job.exit_code() == 0);
      }
    }
    MESSAGE("ranks killed: " << killed);
    CHECK(killed >= 1);
    // The last rerun without mpirun: the folder resumes either way.
    const int code = run(grid_args(ref.cfg, out2.string()), dir / "rerun.txt");
    const std::string logs = slurp(dir / "killed.txt") + slurp(dir / "rerun.txt");
    INFO(logs);
    REQUIRE(code == 0);
    check_same_tables(tables(out2), ref.values);
    for (const char* r : {"do_s5", "do_s6", "qdo_L2_s5", "qdo+a_L2_s6"}) {
      const ResumeState st = load_resume_state((out2 / "runs" / r).string());
      CHECK(st.state.step == 30);
      CHECK(st.log_rows.size() == 30);  // one log row per step, none lost or repeated by the kill
    }
    fs::remove_all(dir);
  }

  TEST_CASE("Student t quantiles and intervals") {
    CHECK(student_t_975(1) == doctest::Approx(12.706));
    CHECK(student_t_975(2) == doctest::Approx(4.303));
    CHECK(student_t_975(30) == doctest::Approx(2.042));
    CHECK(student_t_975(40) == doctest::Approx(2.021));
    CHECK(student_t_975(50) == doctest::Approx(2.009).epsilon(1e-3));  // table value 2.009
    CHECK(student_t_975(100) == doctest::Approx(1.984).epsilon(1e-3));  // table value 1.984
    CHECK(student_t_975(100000) == doctest::Approx(1.960).epsilon(1e-3));
    const MeanInterval m = mean_interval({1, 2, 3, 4});
    CHECK(m.mean == doctest::Approx(2.5));
    CHECK(m.sd == doctest::Approx(std::sqrt(5.0 / 3.0)));
    CHECK(m.half_width == doctest::Approx(3.182 * std::sqrt(5.0 / 3.0) / 2));
    CHECK(std::isnan(mean_interval({7}).sd));
    // Pairs match by seed and scene; a scene on one side only is left out.
    std::vector<SceneScore> s = {{"a", 4, 1, "x", 20, 0.5}, {"b", 4, 1, "x", 19, 0.4}, {"a", 4, 1, "y", 22, 0.6},
                                 {"b", 4, 1, "y", 20, 0.5}, {"a", 4, 2, "x", 21, 0.5}, {"b", 4, 2, "x", 21, 0.5},
                                 {"a", 4, 2, "z", 30, 0.9}};
    const auto d = paired_differences(s, {{"a", "b"}});
    REQUIRE(d.size() == 1);
    CHECK(d[0].psnr_db.n == 3);
    CHECK(d[0].psnr_db.mean == doctest::Approx(1.0));
    CHECK(d[0].seeds == 2);
    CHECK(d[0].psnr_db_seeds.mean == doctest::Approx((1.5 + 0.0) / 2));
  }
}
