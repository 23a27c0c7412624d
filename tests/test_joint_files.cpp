// Joint training's files (suite "joint"): a network run deletes only the network states it
// recorded as its own: the state a checkpoint named, with its checksum, when
// the checkpoint rotation drops it. A user's step_*.pt in RUN/network, a state replaced since it
// was recorded, and everything behind a symlinked RUN/network stay. A checkpoint belongs to its
// run, a resumed log has no gap, and a do-finetune starts only from a finished do run.
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <set>
#include <string>

#include "common.hpp"
#include "joint_common.hpp"
#include "qdo/design/design_run.hpp"
#include "qdo/decode/network_decoder.hpp"
#include "qdo/decode/decoder_spec.hpp"
#include "qdo/design/run.hpp"

using namespace qdo;
using namespace qdo::test;
namespace fs = std::filesystem;

namespace {

std::set<std::string> names_in(const fs::path& d) {
  std::set<std::string> out;
  for (const auto& e : fs::directory_iterator(d)) out.insert(e.path().filename().string());
  return out;
}

void put(const fs::path& p, const std::string& text) {
  std::ofstream f(p, std::ios::binary);
  f << text;
}

}  // namespace

TEST_SUITE("joint") {
  TEST_CASE("a network run deletes only the network states its checkpoints recorded, never a user's file") {
    const AffineFactory fake;
    const auto dir = temp_dir("joint_files");
    // 1. A user's files in RUN/network, one with the name pattern of a state the run writes
    //    later and then drops (step 2: checkpoints at 2, 4, 6; step 2's is dropped at step 6).
    const fs::path run = dir / "run";
    fs::create_directories(run / "network");
    put(run / "network" / "step_00000099.pt", "a user's file");
    put(run / "network" / "notes.txt", "a user's notes");
    CHECK(run_design(runtime(), net_run(run.string(), DesignMode::QDOA), false).steps_done == 6);
    CHECK(names_in(run / "network") ==
          std::set<std::string>{"notes.txt", "step_00000099.pt", "step_00000004.pt", "step_00000006.pt"});
    CHECK(slurp((run / "network" / "step_00000099.pt").string()) == "a user's file");

    // 2. A state replaced after the checkpoint recorded it (the user's copy now): kept. The run is
    //    stopped at step 3 (checkpoints 2 and 3), step 2's file replaced, then resumed: the
    //    rotation at step 4 drops step 2's record, but the bytes are no longer the recorded ones.
    const fs::path b = dir / "b";
    DesignRunOptions first = net_run(b.string(), DesignMode::QDOA);
    first.max_steps = 3;
    CHECK(run_design(runtime(), first, false).steps_done == 3);
    put(b / "network" / "step_00000002.pt", "replaced by the user");
    CHECK(run_design(runtime(), net_run(b.string(), DesignMode::QDOA), true).steps_done == 6);
    CHECK(names_in(b / "network") == std::set<std::string>{"step_00000002.pt", "step_00000004.pt", "step_00000006.pt"});
    CHECK(slurp((b / "network" / "step_00000002.pt").string()) == "replaced by the user");

    // 3. RUN/network a symlink to a user's folder: states are written there, nothing is deleted.
    const fs::path c = dir / "c", elsewhere = dir / "users_folder";
    fs::create_directories(elsewhere);
    fs::create_directories(c);
    fs::create_directory_symlink(elsewhere, c / "network");
    put(elsewhere / "step_00000001.pt", "a user's file");
    CHECK(run_design(runtime(), net_run(c.string(), DesignMode::QDOA), false).steps_done == 6);
    CHECK(names_in(elsewhere) ==
          std::set<std::string>{"step_00000001.pt", "step_00000002.pt", "step_00000004.pt", "step_00000006.pt"});
    CHECK(fs::is_symlink(c / "network"));
    fs::remove_all(dir);
  }

  TEST_CASE("a checkpoint belongs to its run, a log has no gap, a do-finetune starts from a finished do run") {
    const AffineFactory fake;
    const auto dir = temp_dir("joint_belongs");
    // A network run's checkpoint copied into a Wiener run folder: --resume refused, nothing written.
    const fs::path net = dir / "net", wien = dir / "wiener";
    DesignRunOptions n = net_run(net.string(), DesignMode::QDOA);
    n.max_steps = 2;
    REQUIRE(run_design(runtime(), n, false).steps_done == 2);
    DesignRunOptions w = net_run(wien.string(), DesignMode::QDOA);
    w.decoder = DecoderSpec{};
    w.objective = Objective::Wiener;
    w.max_steps = 2;
    REQUIRE(run_design(runtime(), w, false).steps_done == 2);
    fs::copy_file(net / "checkpoint.h5", wien / "checkpoint.h5", fs::copy_options::overwrite_existing);
    const std::string ckpt_before = slurp((wien / "checkpoint.h5").string()), log_before = slurp((wien / "log.csv").string());
    std::string msg = input_error_of([&] { run_design(runtime(), w, true); });
    CHECK(msg.find("a network run's checkpoint") != std::string::npos);
    CHECK(slurp((wien / "checkpoint.h5").string()) == ckpt_before);
    CHECK(slurp((wien / "log.csv").string()) == log_before);
    // A log cut short before --resume: refused naming the missing steps, instead of a log with a gap.
    const std::string log = slurp((net / "log.csv").string());
    const std::size_t last_row = log.rfind('\n', log.size() - 2);
    std::ofstream(net / "log.csv", std::ios::trunc) << log.substr(0, last_row + 1);  // drops step 1's row
    msg = input_error_of([&] { run_design(runtime(), net_run(net.string(), DesignMode::QDOA), true); });
    CHECK(msg.find("log.csv") != std::string::npos);
    CHECK(msg.find("ends at step 0 but the checkpoint is at step 2") != std::string::npos);
    // A row missing in the middle, or repeated: refused too.
    std::ofstream(net / "log.csv", std::ios::trunc) << log.substr(0, log.find('\n') + 1) << log.substr(log.find('\n', log.find('\n') + 1) + 1);
    msg = input_error_of([&] { run_design(runtime(), net_run(net.string(), DesignMode::QDOA), true); });
    CHECK(msg.find("is step 1 where step 0 was expected") != std::string::npos);
    std::ofstream(net / "log.csv", std::ios::trunc) << log;  // restored: the resume goes on
    CHECK(run_design(runtime(), net_run(net.string(), DesignMode::QDOA), true).steps_done == 6);

    // do-finetune from an unfinished do run, or from another do-finetune run: refused, naming why.
    const fs::path d = dir / "do";
    DesignRunOptions o = net_run(d.string(), DesignMode::DO);
    o.max_steps = 3;
    REQUIRE(run_design(runtime(), o, false).steps_done == 3);
    DesignRunOptions f = net_run((dir / "ft").string(), DesignMode::DO);
    f.finetune_from = d.string();
    f.design.quantizer.levels = 2;
    f.epochs = 1;
    f.design.steps_per_epoch = 2;
    f.design.t0_epochs = 0;
    f.design.t1_epochs = 1;
    msg = input_error_of([&] { run_design(runtime(), f, false); });
    CHECK(msg.find("a finished network do run (its checkpoint is at step 3 of 6") != std::string::npos);
    CHECK_FALSE(fs::exists(dir / "ft" / "checkpoint.h5"));
    REQUIRE(run_design(runtime(), net_run(d.string(), DesignMode::DO), true).steps_done == 6);
    REQUIRE(run_design(runtime(), f, false).steps_done == 2);
    DesignRunOptions f2 = f;
    f2.out = (dir / "ft2").string();
    f2.finetune_from = f.out;
    msg = input_error_of([&] { run_design(runtime(), f2, false); });
    CHECK(msg.find("it is itself a do-finetune run") != std::string::npos);
    fs::remove_all(dir);
  }

  TEST_CASE("a network run records its thread count; a resume with another count says so") {
    const AffineFactory fake;
    const auto dir = temp_dir("joint_threads");
    const char* saved = std::getenv("QDO_TORCH_THREADS");
    const std::string restore = saved ? saved : "";
    ::setenv("QDO_TORCH_THREADS", "3", 1);
    DesignRunOptions o = net_run((dir / "run").string(), DesignMode::QDOA);
    o.max_steps = 2;
    REQUIRE(run_design(runtime(), o, false).steps_done == 2);
    CHECK(slurp((dir / "run" / "split.json").string()).find("\"threads\": 3") != std::string::npos);
    o.max_steps = 4;
    const DesignRunResult same = run_design(runtime(), o, true);  // the same count: nothing to note
    CHECK(same.steps_done == 4);
    CHECK(same.notes.empty());
    ::setenv("QDO_TORCH_THREADS", "5", 1);
    o.max_steps = -1;
    const DesignRunResult other = run_design(runtime(), o, true);
    CHECK(other.steps_done == 6);
    REQUIRE(other.notes.size() == 1);
    CHECK(other.notes[0].find("trained with 3 LibTorch threads and resumes with 5") != std::string::npos);
    CHECK(other.notes[0].find("QDO_TORCH_THREADS=3") != std::string::npos);
    ::setenv("QDO_TORCH_THREADS", "0", 1);  // out of range: the setting is named
    CHECK_THROWS_WITH_AS(network_threads(), doctest::Contains("QDO_TORCH_THREADS"), InputError);
    if (saved)
      ::setenv("QDO_TORCH_THREADS", restore.c_str(), 1);
    else
      ::unsetenv("QDO_TORCH_THREADS");
    fs::remove_all(dir);
  }
}
