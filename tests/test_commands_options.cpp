// Options checked at parse time (suite "commands"; issue 31, classes 12, 14, 15): every refusal
// exits 2 naming the option, the value and what is allowed, before any work and with no --out
// folder made.
#include <filesystem>
#include <string>

#include "commands_common.hpp"

using namespace qdo;
using namespace qdo::test;
using namespace qdo::test::commands_suite;
namespace fs = std::filesystem;

TEST_SUITE("commands") {
  TEST_CASE("options out of range, given twice, or grids that cannot mean anything are refused before any work") {
    const auto dir = temp_dir("cmd_options");
    const std::string out = (dir / "out").string();
    struct Case {
      std::string args, named, allowed;
    };
    const std::string design = "design " + cfg_arg() + " --mode do --levels 2 --epochs 2 --steps-per-epoch 1";
    const Case cases[] = {
        {design + " --lr 1e300", "--lr", "a number in [0, 1]"},
        {design + " --lr -0.1", "--lr", "a number in [0, 1]"},
        {design + " --height-noise-nm 1e30", "--height-noise-nm", "[0, 10000] nm"},
        {design + " --noise-sigma 1e155", "--noise-sigma", "[0, 10]"},
        {design + " --decay 0", "--decay", "(0, 1]"},
        {design + " --lr 0.01 --lr 0.02", "--lr", "given once"},
        {design + " --decoder resunet:depth=8,root=1024", "--decoder", "at most 4096 channels"},
        {"tolerance " + shared_run().dir.string() + " --etch-depth-error-nm 1e9", "--etch-depth-error-nm", "[0, 10000] nm"},
        {"image " + cfg_arg() + " --design flat --tolerance 5", "--tolerance", "[0, 1]"},
        {"sweep-psf " + cfg_arg() + " --design flat --levels 4,4", "--levels", "4 appears twice"},
        {"sweep " + cfg_arg() + " --grid levels=", "--grid", "at least one value after levels="},
        {"sweep " + cfg_arg() + " --grid levels=2 --grid levels=4", "--grid", "levels is given twice"},
        {"sweep " + cfg_arg() + " --grid levels=2,2", "--grid", "distinct values"},
        // A decoder spec's own commas: two equal specs, so read as two values (not four).
        {"sweep " + cfg_arg() + " --grid decoder=resunet:depth=2,root=4,resunet:depth=2,root=4", "--grid", "distinct values"},
    };
    REQUIRE(shared_run().result.code == 0);
    for (const Case& c : cases) {
      CAPTURE(c.args);
      const Run r = qdo_run(c.args + " --out " + out);
      CAPTURE(r.out);
      CHECK(r.code == 2);
      CHECK(r.out.find(c.named) != std::string::npos);
      CHECK(r.out.find(c.allowed) != std::string::npos);
      CHECK_FALSE(fs::exists(out));
    }
    // The same spec written once parses: the grid runs that decoder (refused later only for want of
    // LibTorch in a build without it, never for the spec).
    const Run ok = qdo_run("sweep " + cfg_arg() + " --grid decoder=wiener,resunet:depth=2,root=4 --grid levels=2,2 --out " + out);
    CHECK(ok.code == 2);
    CHECK(ok.out.find("distinct values on the levels axis") != std::string::npos);
    fs::remove_all(dir);
  }
}
