// The qdo commands end to end (doctest suite "commands"): every documented exit code, and a
// failed command leaves no output set, no folder it created and no temporary files; run as a
// user would (the qdo binary through the shell).
// The shared run and the tiny configuration are in commands_common.hpp.
#include <nlohmann/json.hpp>

#include <fstream>
#include <set>
#include <string>

#include "commands_common.hpp"
#include "qdo/data/io.hpp"

using namespace qdo;
using namespace qdo::test;
using namespace qdo::test::commands_suite;
namespace fs = std::filesystem;
using nlohmann::json;

TEST_SUITE("commands") {
  TEST_CASE("a failed command leaves no output set, no folder it created and no temporary files") {
    const auto dir = temp_dir("cmd_nopartial");
    // An unknown device: exit 2 or 4, and the --out folder (and its parent) it would have made are gone.
    const fs::path nested = dir / "new" / "out";
    Run r = qdo_run("simulate " + cfg_arg() + " --design flat --device no-such-device-xyz --out " + nested.string());
    CAPTURE(r.out);
    CHECK((r.code == 2 || r.code == 4));
    CHECK_FALSE(fs::exists(dir / "new"));
    // A failure after some outputs were computed: psf.png is taken by a folder, so the set cannot be
    // written whole; none of it is (sensor.h5, sensor.png, scene.png, psf.h5 would come first), no
    // *.tmp-* file stays, and the folder the user made is kept with only what was there.
    const fs::path out = dir / "out";
    fs::create_directories(out / "psf.png");
    std::ofstream(out / "mine.txt") << "keep";
    r = qdo_run("simulate " + cfg_arg() + " --design flat --out " + out.string());
    CAPTURE(r.out);
    CHECK(r.code == 2);
    CHECK(r.out.find("psf.png") != std::string::npos);
    std::set<std::string> left;
    for (const auto& e : fs::directory_iterator(out)) left.insert(e.path().filename().string());
    CHECK(left == std::set<std::string>{"mine.txt", "psf.png"});
    // qdo design: a bad option is refused before anything is read, computed or made.
    for (const std::string bad : {"--lr -1", "--decay -0.5", "--decay 1.5", "--beta -1", "--t0 50 --t1 40", "--height-noise-nm -3",
                                  "--init lens:abc", "--objective psf-target --target lens:1e999"}) {
      CAPTURE(bad);
      const fs::path run = dir / "run";
      r = qdo_run("design " + cfg_arg() + " --mode qdo+a --levels 4 --epochs 60 --synthetic-scenes 3 " + bad + " --out " + run.string());
      CAPTURE(r.out);
      CHECK(r.code == 2);
      CHECK(r.out.find("argument '") != std::string::npos);
      CHECK_FALSE(fs::exists(run));
    }
    fs::remove_all(dir);
  }

  TEST_CASE("documented exit codes: 0 ok, 2 bad input (an uncreatable --out too), 3 accuracy refusal, 4 device error") {
    const auto dir = temp_dir("cmd_codes");
    const std::string out = (dir / "out").string();
    // 0: help.
    const Run help = qdo_run("--help");
    CHECK(help.code == 0);
    CHECK(help.out.find("usage:") != std::string::npos);
    const Run devices = qdo_run("devices");
    CHECK(devices.code == 0);
    CHECK(devices.out.find("default: ") != std::string::npos);
    // 2: no command, an unknown command, an unknown option, a bad value, a missing --out.
    CHECK(qdo_run("").code == 2);
    const Run unk = qdo_run("frobnicate");
    CHECK(unk.code == 2);
    CHECK(unk.out.find("unknown command") != std::string::npos);
    CHECK(qdo_run("psf " + cfg_arg() + " --design flat --frob 1 --out " + out).code == 2);
    CHECK(qdo_run("psf " + cfg_arg() + " --design lens:-5 --out " + out).code == 2);
    CHECK(qdo_run("psf " + cfg_arg() + " --design flat").code == 2);
    CHECK_FALSE(fs::exists(out));  // nothing was written by any of these
    // An unknown --device is an input error too. (It is checked when the runtime starts, after the
    // output folder was created: the folder is left behind, empty.)
    const Run nodevice = qdo_run("psf " + cfg_arg() + " --design flat --device no-such-device-anywhere --out " + out);
    CHECK(nodevice.code == 2);
    CHECK(nodevice.out.find("no-such-device-anywhere") != std::string::npos);
    // 3: strict_sampling refuses an under-sampled transfer function. The tiny system keeps the paper's
    // sampling ratio, so its longer bands are under-sampled; a lens for 450 nm puts 0.8 % of the field
    // energy at 500 nm beyond the limit (1e-4 allowed).
    SystemConfig strict = tiny();
    strict.strict_sampling = true;
    std::ofstream(dir / "strict.json") << config_to_json_text(strict);
    const Run refused = qdo_run("psf --config " + (dir / "strict.json").string() + " --design lens:450 --out " + (dir / "strict").string());
    CAPTURE(refused.out);
    CHECK(refused.code == 3);
    CHECK(refused.out.find("refused") != std::string::npos);
    CHECK(refused.out.find("strict_sampling") != std::string::npos);
    // The same system without strict mode computes (and flags) it: exit 0.
    CHECK(qdo_run("psf " + cfg_arg() + " --design lens:450 --out " + (dir / "lax").string()).code == 0);
    // 4: a device error, here no OpenCL platform at all (an empty ICD vendor directory), on a command
    // that needs the device (test_cli checks the message for `qdo devices`).
    fs::create_directories(dir / "no_vendors");
    const Run nodev = qdo_run("psf " + cfg_arg() + " --design flat --out " + (dir / "nodev").string(),
                              "OCL_ICD_VENDORS=" + (dir / "no_vendors").string());
    CAPTURE(nodev.out);
    CHECK(nodev.code == 4);
    CHECK(nodev.out.find("device error") != std::string::npos);
    // 2 as well: an output folder that cannot be created (a regular file in its path) names --out.
    std::ofstream(dir / "a_file") << "x";
    const Run other = qdo_run("psf " + cfg_arg() + " --design flat --out " + (dir / "a_file" / "sub").string());
    CAPTURE(other.out);
    CHECK(other.code == 2);
    CHECK(other.out.find("argument '--out'") != std::string::npos);
    CHECK(other.out.find("a folder that can be created") != std::string::npos);
    // 5 (gradient check failed): see the gradcheck case.
    fs::remove_all(dir);
  }
}
