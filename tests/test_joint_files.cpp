// Joint training's files (suite "joint"): a network run deletes only the network states it
// recorded as its own (issue 31, class 2): the state a checkpoint named, with its checksum, when
// the checkpoint rotation drops it. A user's step_*.pt in RUN/network, a state replaced since it
// was recorded, and everything behind a symlinked RUN/network stay.
#include <filesystem>
#include <fstream>
#include <set>
#include <string>

#include "common.hpp"
#include "joint_common.hpp"
#include "qdo/design_run.hpp"
#include "qdo/run.hpp"

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
}
