// Stability suite (doctest suite "stress", STABILITY.md): one `qdo sweep` folder under
// several processes, kills and changed options. Two sweeps at once keep one writer per run
// folder; a sweep killed with kill -9 anywhere completes on rerun with the values of an
// uninterrupted sweep; other options on a finished folder are refused, nothing rewritten.
#include <chrono>
#include <filesystem>
#include <map>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "stress_common.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"
#include "qdo/design/run_folder.hpp"

using namespace qdo;
using namespace qdo::test;
using namespace qdo::test::stress_suite;
namespace fs = std::filesystem;

namespace {

// ---------------------------------------------------------------------------------------
// Sweep folders: the smallest `qdo sweep` that trains two runs (do, and qdo at
// L = 2) past a checkpoint (12 steps each, checkpoints at steps 10 and 12) and evaluates three
// cells (full, do_L2, qdo_L2).
// ---------------------------------------------------------------------------------------

std::vector<std::string> sweep_args(const std::string& cfg, const std::string& out, const std::string& epochs = "4") {
  return {QDO_QDO_BINARY, "sweep", "--config", cfg, "--grid", "levels=2", "--grid", "mode=do,qdo", "--epochs", epochs,
          "--steps-per-epoch", "3", "--t0", "1", "--t1", "3", "--synthetic-scenes", "3", "--eval-scenes", "2", "--seed", "5",
          "--out", out};
}
std::string sweep_config_file(const fs::path& dir) {
  const std::string cfg = (dir / "cfg.json").string();
  write_text_atomic(cfg, config_to_json_text(tiny_config(32, 3)));
  return cfg;
}

// table1.csv and table2.csv of a sweep folder, parsed, as text without the `inputs` column (a
// hash of the files' paths and bytes, so it differs between folders; the values must not).
std::string sweep_table_values(const fs::path& out) {
  std::string text;
  for (const char* name : {"table1.csv", "table2.csv"}) {
    const CsvTable t = read_csv((out / name).string());
    REQUIRE(!t.raw.empty());
    text += std::string(name) + ":";
    for (std::size_t r = 0; r < t.raw[0].size(); ++r) {
      for (std::size_t c = 0; c < t.header.size(); ++c)
        if (t.header[c] != "inputs") text += t.raw[c][r] + ",";
      text += "\n";
    }
  }
  return text;
}

// Every file under `dir` with its size and modification time (to show that nothing changed).
std::map<std::string, std::pair<std::uintmax_t, fs::file_time_type>> folder_listing(const fs::path& dir) {
  std::map<std::string, std::pair<std::uintmax_t, fs::file_time_type>> m;
  for (const auto& e : fs::recursive_directory_iterator(dir))
    if (e.is_regular_file()) m[fs::relative(e.path(), dir).string()] = {e.file_size(), e.last_write_time()};
  return m;
}
std::size_t temp_files(const fs::path& dir) {
  std::size_t n = 0;
  for (const auto& e : fs::recursive_directory_iterator(dir))
    if (e.path().filename().string().find(".tmp-") != std::string::npos) ++n;
  return n;
}

// The uninterrupted sweep the workflow cases compare with, made once per test binary.
struct ReferenceSweep {
  fs::path dir, cfg, out;
  std::string values;
  double seconds = 0;
  ~ReferenceSweep() {
    std::error_code ec;
    if (!dir.empty()) fs::remove_all(dir, ec);
  }
};
const ReferenceSweep& reference_sweep() {
  static ReferenceSweep r;
  if (r.values.empty()) {
    r.dir = temp_dir("stress_sweep_ref");
    r.cfg = sweep_config_file(r.dir);
    r.out = r.dir / "ref";
    const auto t0 = std::chrono::steady_clock::now();
    Child c(sweep_args(r.cfg.string(), r.out.string()), (r.dir / "log.txt").string());
    const int code = c.exit_code();
    r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    INFO(slurp((r.dir / "log.txt").string()));
    REQUIRE(code == 0);
    r.values = sweep_table_values(r.out);
  }
  return r;
}

}  // namespace

TEST_SUITE("stress") {
  TEST_CASE("two `qdo sweep` at once on one folder: one writer per run folder; the other is refused naming the holder's pid, or both finish alike") {
    // What the code guarantees: a sweep holds cells/NAME/.lock while it runs a cell, and
    // run_design holds RUN/.lock (RunLock) while it writes a run folder, so a cell and a run
    // folder have one writer at a time. A sweep that finds a cell locked stops, exit 2, naming
    // the holder's pid (a run another process trains is waited for, sweep_grid.cpp). One that comes to a run
    // folder after the other has released it goes on (resuming a finished run does no steps)
    // and finishes with the same values; if the other made the checkpoint between this one's
    // look and its lock, it stops, exit 2, asking for --resume (rerunning the sweep goes on).
    // Cells are written atomically (temporary file + rename) by either, with the same values.
    const ReferenceSweep& ref = reference_sweep();
    const auto dir = temp_dir("stress_sweep_two");
    const fs::path out = dir / "sweep";
    const std::string log_a = (dir / "a.txt").string(), log_b = (dir / "b.txt").string();
    const auto t0 = std::chrono::steady_clock::now();
    Child a(sweep_args(ref.cfg.string(), out.string()), log_a);
    Child b(sweep_args(ref.cfg.string(), out.string()), log_b);
    const pid_t pa = a.pid(), pb = b.pid();
    const int ca = a.exit_code(), cb = b.exit_code();
    const double both_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    const std::string ta = slurp(log_a), tb = slurp(log_b);
    CAPTURE(ta);
    CAPTURE(tb);
    auto refused_by = [&](const std::string& text, pid_t holder) {
      return has(text, "locked by pid " + std::to_string(holder) + " ") || has(text, "this one holds one: continue it with --resume");
    };
    CHECK((ca == 0 || ca == 2));
    CHECK((cb == 0 || cb == 2));
    CHECK((ca == 0 || cb == 0));
    if (ca == 2) CHECK(refused_by(ta, pb));
    if (cb == 2) CHECK(refused_by(tb, pa));
    MESSAGE("two sweeps at once: exit codes " << ca << " and " << cb << " (" << both_s << " s; one alone: " << ref.seconds << " s)");
    // Nothing half-written; the tables parse and hold the values of an uninterrupted sweep.
    CHECK(temp_files(out) == 0);
    CHECK(sweep_table_values(out) == ref.values);
    for (const char* run : {"do", "qdo_L2"}) {
      const fs::path r = out / "runs" / run;
      CHECK(fs::exists(r / "DONE"));
      CHECK(input_error([&] { load_resume_state(r.string()); }).empty());
    }
    // The refused one, run again, finds everything done and writes the same tables.
    Child again(sweep_args(ref.cfg.string(), out.string()), (dir / "again.txt").string());
    CHECK(again.exit_code() == 0);
    CHECK(sweep_table_values(out) == ref.values);
    CHECK(temp_files(out) == 0);
    fs::remove_all(dir);
  }

  TEST_CASE("kill -9 of `qdo sweep` during a run, between runs and during the second run: the rerun completes with the values of an uninterrupted sweep") {
    const ReferenceSweep& ref = reference_sweep();
    const auto dir = temp_dir("stress_sweep_kill");
    const fs::path out = dir / "sweep";
    const std::string log = (dir / "log.txt").string();
    // Kill as soon as each of these appears: the DO run's step-10 checkpoint (2 steps left, to be
    // resumed), the DO run finished, the qdo run's step-10 checkpoint.
    const std::vector<fs::path> kill_when = {out / "runs" / "do" / "checkpoint.h5", out / "runs" / "do" / "DONE",
                                             out / "runs" / "qdo_L2" / "checkpoint.h5"};
    int kills = 0;
    const auto t0 = std::chrono::steady_clock::now();
    for (const fs::path& when : kill_when) {
      CAPTURE(when.string());
      Child c(sweep_args(ref.cfg.string(), out.string()), log);
      while (c.running() && !fs::exists(when)) std::this_thread::sleep_for(std::chrono::milliseconds(1));
      if (c.running()) {
        c.kill9();
        ++kills;
      } else {
        CHECK(c.exit_code() == 0);  // finished before the kill point: nothing to kill
      }
    }
    Child last(sweep_args(ref.cfg.string(), out.string()), log);
    const int code = last.exit_code();
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    INFO(slurp(log));
    REQUIRE(code == 0);
    CHECK(kills >= 2);
    MESSAGE(kills << " kills, then the completing run: " << seconds << " s in all (one uninterrupted sweep: " << ref.seconds << " s); "
                  << temp_files(out) << " temporary file(s) left by the kills (ignored)");
    CHECK(sweep_table_values(out) == ref.values);
    for (const char* run : {"do", "qdo_L2"}) {
      const ResumeState st = load_resume_state((out / "runs" / run).string());
      CHECK(st.state.step == 12);
      CHECK(st.log_rows.size() == 12);  // one log row per step, none lost or repeated by the kills
    }
    fs::remove_all(dir);
  }

  TEST_CASE("`qdo sweep` with other --epochs on a finished sweep folder: exit 2 naming the field, nothing deleted or rewritten") {
    const ReferenceSweep& ref = reference_sweep();
    const auto dir = temp_dir("stress_sweep_opts");
    const fs::path out = dir / "sweep";
    fs::copy(ref.out, out, fs::copy_options::recursive);
    const auto before = folder_listing(out);
    const std::string log = (dir / "log.txt").string();
    Child c(sweep_args(ref.cfg.string(), out.string(), "5"), log);
    const int code = c.exit_code();
    const std::string text = slurp(log);
    CAPTURE(text);
    CHECK(code == 2);
    CHECK(has(text, "design.epochs: stored 4, given 5"));
    CHECK(has(text, (out / "runs" / "do" / "config.json").string()));
    CHECK(folder_listing(out) == before);  // every file still there, same size, same time
    fs::remove_all(dir);
  }
}
