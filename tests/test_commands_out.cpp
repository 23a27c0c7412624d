// Every command's --out folder under one rule (suite "commands"; claim_output_dir, io.hpp): a
// new or empty folder becomes the command's (marked .qdo-out); the command's own
// folder takes its reruns; a folder qdo did not make, or another command made, that holds anything
// is refused, exit 2, naming what is there, before any work and with nothing changed on disk,
// unless --into-existing.
#include <chrono>
#include <filesystem>
#include <fstream>
#include <set>
#include <string>
#include <thread>

#include "commands_common.hpp"
#include "stress_common.hpp"  // Child: a qdo process the test can signal

using namespace qdo;
using namespace qdo::test;
using namespace qdo::test::commands_suite;
namespace fs = std::filesystem;

namespace {

std::set<std::string> entries(const fs::path& d) {
  std::set<std::string> out;
  for (const auto& e : fs::directory_iterator(d)) out.insert(e.path().filename().string());
  return out;
}

}  // namespace

TEST_SUITE("commands") {
  TEST_CASE("--out: a user's folder is refused by every command, naming what is there, with nothing changed; --into-existing writes into it") {
    const auto dir = temp_dir("cmd_out_rule");
    const fs::path user = dir / "user";
    fs::create_directories(user);
    std::ofstream(user / "design.h5") << "a user's design";
    std::ofstream(user / "log.csv") << "a user's log";
    std::ofstream(user / "table1.md") << "a user's table";
    const std::set<std::string> before = entries(user);
    const std::string small = " --epochs 2 --steps-per-epoch 1 --t0 0.5 --t1 1.5 --synthetic-scenes 3";
    const std::vector<std::string> commands = {
        "psf " + cfg_arg() + " --design flat",
        "simulate " + cfg_arg() + " --design flat",
        "image " + cfg_arg() + " --design flat",
        "design " + cfg_arg() + " --mode do --levels 2" + small,
        "sweep " + cfg_arg() + " --grid levels=2 --grid mode=do" + small + " --eval-scenes 1",
        "sweep-psf " + cfg_arg() + " --design flat --levels 2,4",
        "calibrate " + cfg_arg() + " --frames nowhere --darks nowhere",
        "eval " + shared_run().dir.string(),
        "export " + shared_run().dir.string(),
        "tolerance " + shared_run().dir.string() + " --trials 1 --no-per-source --synthetic-scenes 1",
        "demo --preset small --levels 2 --epochs 2 --steps-per-epoch 1",
    };
    REQUIRE(shared_run().result.code == 0);
    for (const std::string& c : commands) {
      CAPTURE(c);
      const Run r = qdo_run(c + " --out " + user.string());
      CAPTURE(r.out);
      CHECK(r.code == 2);
      CHECK(r.out.find("a folder qdo did not make, holding design.h5, log.csv, table1.md") != std::string::npos);
      CHECK(r.out.find("--into-existing") != std::string::npos);
      CHECK(entries(user) == before);
      CHECK(slurp(user / "design.h5") == "a user's design");
    }
    // With --into-existing the command writes there (its own files replaced, the others kept), and
    // the folder is then the command's: a rerun needs no flag.
    const Run psf = qdo_run("psf " + cfg_arg() + " --design flat --into-existing --out " + user.string());
    CAPTURE(psf.out);
    REQUIRE(psf.code == 0);
    CHECK(slurp(user / "log.csv") == "a user's log");
    CHECK(fs::exists(user / "psf.h5"));
    CHECK(fs::exists(user / ".qdo-out"));
    CHECK(qdo_run("psf " + cfg_arg() + " --design flat --out " + user.string()).code == 0);
    fs::remove_all(dir);
  }

  TEST_CASE("--out: a command's own folder takes its reruns; another command's folder is refused; a failure leaves no marker") {
    const auto dir = temp_dir("cmd_out_owner");
    const fs::path p = dir / "psf";
    REQUIRE(qdo_run("psf " + cfg_arg() + " --design flat --out " + p.string()).code == 0);
    CHECK(slurp(p / ".qdo-out").find("\"command\": \"psf\"") != std::string::npos);
    CHECK(qdo_run("psf " + cfg_arg() + " --design lens:500 --out " + p.string()).code == 0);  // rerun: replaced
    // qdo simulate would replace psf.h5 in qdo psf's folder: refused, naming the command that made it.
    const std::string psf_before = slurp(p / "psf.h5");
    const Run sim = qdo_run("simulate " + cfg_arg() + " --design flat --out " + p.string());
    CAPTURE(sim.out);
    CHECK(sim.code == 2);
    CHECK(sim.out.find("a folder `qdo psf` made") != std::string::npos);
    CHECK(slurp(p / "psf.h5") == psf_before);
    // A design run folder is design's: eval into it is refused (eval writes its own folder).
    const Run ev = qdo_run("eval " + shared_run().dir.string() + " --out " + shared_run().dir.string());
    CAPTURE(ev.out);
    CHECK(ev.code == 2);
    CHECK(ev.out.find("a folder `qdo design` made") != std::string::npos);
    // An empty folder given to a command that then fails stays empty: the marker goes with the
    // command's other outputs.
    const fs::path empty = dir / "empty";
    fs::create_directories(empty);
    const Run bad = qdo_run("psf " + cfg_arg() + " --design " + (dir / "missing.h5").string() + " --out " + empty.string());
    CHECK(bad.code == 2);
    CHECK(fs::is_empty(empty));
    // A folder the command creates and then fails in is removed again.
    CHECK(qdo_run("psf " + cfg_arg() + " --design " + (dir / "missing.h5").string() + " --out " + (dir / "new").string()).code == 2);
    CHECK_FALSE(fs::exists(dir / "new"));
    fs::remove_all(dir);
  }

  TEST_CASE("--out: SIGTERM or SIGINT mid-command leaves no folder it created, keeps an earlier run's files and a run's checkpoint") {
    // A Ctrl-C or a kill (Slurm's time limit) left the folder a command created, holding
    // .qdo-out.tmp-PID. The process discards what it staged, as a failure does, and dies of the signal.
    const auto dir = temp_dir("out_signal");
    const std::string qdo = QDO_QDO_BINARY, log = (dir / "log.txt").string();
    // Waits until `p` exists (at most 120 s), then signals the child; returns how it ended.
    auto interrupt = [&](stress_suite::Child& child, const fs::path& p, int sig) {
      for (int t = 0; t < 24000 && child.running() && !fs::exists(p); ++t) std::this_thread::sleep_for(std::chrono::milliseconds(5));
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
      const bool was_running = child.running();
      if (was_running) ::kill(child.pid(), sig);
      const int st = child.wait();
      return was_running && WIFSIGNALED(st) && WTERMSIG(st) == sig;
    };
    for (const int sig : {SIGTERM, SIGINT}) {
      CAPTURE(sig);
      const fs::path out = dir / ("sim_" + std::to_string(sig));
      stress_suite::Child child({qdo, "simulate", "--preset", "paper", "--design", "lens:550", "--out", out.string()}, log);
      const bool interrupted = interrupt(child, out, sig);
      REQUIRE_MESSAGE(interrupted, slurp(log));  // the paper preset's simulate takes seconds: the signal lands inside it
      CHECK_FALSE(fs::exists(out));
    }
    // A rerun into the command's own folder, interrupted: the earlier outputs stay as they were,
    // no temporary file remains.
    const fs::path again = dir / "again";
    REQUIRE(qdo_run("simulate --preset paper --design lens:550 --out " + again.string()).code == 0);
    const std::set<std::string> before = entries(again);
    const std::string psf_before = slurp(again / "psf.h5");
    {
      stress_suite::Child child({qdo, "simulate", "--preset", "paper", "--design", "lens:550", "--out", again.string()}, log);
      std::this_thread::sleep_for(std::chrono::milliseconds(400));
      if (child.running()) ::kill(child.pid(), SIGTERM);
      child.wait();
    }
    CHECK(entries(again) == before);
    CHECK(slurp(again / "psf.h5") == psf_before);
    // A training run stopped by SIGTERM keeps its folder and its checkpoint.
    const fs::path run = dir / "run";
    {
      stress_suite::Child child({qdo, "design", "--config", tiny_config_file().string(), "--recipe", "qdo", "--epochs", "400",
                                 "--steps-per-epoch", "10", "--checkpoint-every", "1", "--out", run.string()},
                                log);
      CHECK(interrupt(child, run / "checkpoint.h5", SIGTERM));
    }
    CHECK(fs::exists(run / "checkpoint.h5"));
    for (const auto& name : entries(run)) CHECK(name.find(".tmp-") == std::string::npos);
    CHECK(h5_has((run / "checkpoint.h5").string(), "/w"));  // whole (written, then renamed), so a --resume reads it
    fs::remove_all(dir);
  }
}
