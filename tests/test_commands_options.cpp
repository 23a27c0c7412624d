// Options checked at parse time (suite "commands"): every refusal
// (a value out of range, an option given twice or doing nothing in the run, a grid that cannot
// mean anything) exits 2 naming the option, the value and what is allowed, before any work and
// with no --out folder made. And messages that name what is wrong and where.
#include <filesystem>
#include <string>

#include "commands_common.hpp"
#include "qdo/data/io.hpp"

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
        {design + " --t0 1 --t1 1e300", "--t1", "[0, 1000000] epochs"},
        {design + " --lr 0.01 --lr 0.02", "--lr", "given once"},
        {design + " --decoder resunet:depth=8,root=1024", "--decoder", "at most 4096 channels"},
        // Options that would do nothing in this run (they were ignored silently).
        {design + " --beta 0.1", "--beta", "an option of --mode qdo+a or qdo+m"},
        {design + " --lr-offsets 0.1", "--lr-offsets", "an option of --mode qdo+a or qdo+m"},
        {design + " --lr-decoder 0.01", "--lr-decoder", "an option of a network --decoder"},
        {design + " --target lens:500", "--target", "an option of --objective psf-target"},
        {design + " --finetune-steps 5", "--finetune-steps", "an option of --mode do-finetune"},
        {design + " --objective psf-target --wiener-on cpu", "--wiener-on", "an option of the Wiener objectives"},
        {"tolerance " + shared_run().dir.string() + " --etch-depth-error-nm 1e9", "--etch-depth-error-nm", "[0, 10000] nm"},
        {"image " + cfg_arg() + " --design flat --tolerance 5", "--tolerance", "[0, 1]"},
        {"sweep-psf " + cfg_arg() + " --design flat --levels 4,4", "--levels", "4 appears twice"},
        {"sweep " + cfg_arg() + " --grid levels=", "--grid", "at least one value after levels="},
        {"sweep " + cfg_arg() + " --grid levels=2 --grid levels=4", "--grid", "levels is given twice"},
        {"sweep " + cfg_arg() + " --grid levels=2,2", "--grid", "distinct values"},
        {"sweep " + cfg_arg() + " --grid levels=2 --grid mode=do,qdo --beta 0.1", "--beta", "no cell of this grid uses it"},
        {"sweep " + cfg_arg() + " --grid levels=2 --grid mode=do --lr-decoder 0.01", "--lr-decoder", "a grid with a network decoder"},
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

  TEST_CASE("messages name the file, the scene or the setting that is wrong, and say what is wrong") {
    const auto dir = temp_dir("cmd_messages");
    const SystemConfig c = tiny();
    // A design file with a height out of range: the file is named (it was height_m[5][5] alone).
    Design d;
    d.height_m = Map2D(c.n, c.n, 0.5 * c.h_max_m());
    d.height_m(5, 5) = 5 * c.h_max_m();
    d.pitch_m = c.pitch_m;
    const std::string bad = (dir / "bad_design.h5").string();
    write_design(bad, d);
    const Run psf = qdo_run("psf " + cfg_arg() + " --design " + bad + " --out " + (dir / "p").string());
    CAPTURE(psf.out);
    CHECK(psf.code == 2);
    CHECK(psf.out.find("bad_design.h5") != std::string::npos);
    CHECK(psf.out.find("/height_m[5][5]") != std::string::npos);
    // A test scene with an all-zero band: eval names the scene (it said "truth band 1 mean = 0").
    RealStack cube = random_cube(c.bands, 40, 40, 3);
    for (std::size_t i = 0; i < cube.plane_size(); ++i) cube.plane(1)[i] = 0;
    write_cube((dir / "dark_band.h5").string(), cube, c.wavelengths_nm());
    REQUIRE(shared_run().result.code == 0);
    const Run ev = qdo_run("eval " + shared_run().dir.string() + " --data " + (dir / "dark_band.h5").string() + " --out " +
                           (dir / "e").string());
    CAPTURE(ev.out);
    CHECK(ev.code == 2);
    CHECK(ev.out.find("test scene 'dark_band") != std::string::npos);
    CHECK(ev.out.find("truth band 1 mean") != std::string::npos);
#ifdef QDO_WITH_TORCH
    // QDO_TORCH_THREADS out of range is the user's setting, not a plugin that did not load.
    const Run th = qdo_run("design " + cfg_arg() + " --mode do --levels 2 --decoder resunet:depth=2,root=4 --epochs 2 --steps-per-epoch 1 "
                           "--out " + (dir / "t").string(), "QDO_TORCH_THREADS=0");
    CAPTURE(th.out);
    CHECK(th.code == 2);
    CHECK(th.out.find("QDO_TORCH_THREADS") != std::string::npos);
    CHECK(th.out.find("an integer from 1 to 1024") != std::string::npos);
    CHECK(th.out.find("did not load") == std::string::npos);
#endif
    fs::remove_all(dir);
  }
}
