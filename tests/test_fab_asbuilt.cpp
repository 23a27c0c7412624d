// The camera as built (fab.hpp: fabricate; `qdo fabricate`), suite "fab": no error is the design
// bit for bit; the draws are qdo tolerance's (same streams); the realised level heights follow the
// depth errors of the masks over each level; the relief offset is qdo fit's shift; z moves by the
// assembly error; truth.json states the true values in qdo fit's names; bad values exit 2.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>

#include "commands_common.hpp"
#include "common.hpp"
#include "fab_common.hpp"
#include "qdo/fab/fab.hpp"
#include "qdo/asbuilt/fit.hpp"
#include "qdo/data/io.hpp"

using namespace qdo;
using namespace qdo::test;
using namespace qdo::test::fab_suite;
using namespace qdo::test::commands_suite;
namespace fs = std::filesystem;

TEST_SUITE("fab") {
  TEST_CASE("fabricate: no error is the design; depth errors move the levels they etch; offset and z as stated") {
    const SystemConfig cfg = tiny_config(32, 3);
    const Design d = level_design(cfg, 4, 11);
    fab::AsBuiltOptions none;
    none.etch_depth_error_m = 0;
    none.overlay_m = 0;
    const fab::AsBuiltCamera c0 = fab::fabricate(d, cfg, none);
    CHECK(c0.design.height_m.data == d.height_m.data);
    CHECK(c0.cfg.sensor_distance_m == cfg.sensor_distance_m);
    CHECK(c0.design.levels_m.empty());
    for (std::size_t l = 0; l < c0.level_height_m.size(); ++l) CHECK(c0.level_height_m[l] == c0.plan.levels[l].height_m);

    // Depth errors only: every level's realised height is its design height minus the errors of
    // the masks open over it (plus one common lift when level 0 would go below 0).
    fab::AsBuiltOptions dep = none;
    dep.etch_depth_error_m = 20e-9;
    dep.seed = 5;
    dep.trial = 2;
    const fab::AsBuiltCamera c1 = fab::fabricate(d, cfg, dep);
    REQUIRE(c1.depth_error_m.size() == c1.plan.masks.size());
    double any = 0;
    for (double e : c1.depth_error_m) {
      CHECK(std::abs(e) <= 20e-9);
      any += std::abs(e);
    }
    CHECK(any > 1e-9);  // the draw is not all zeros
    // The fabricated relief shows them: away from mask edges (no overlay here) each level's pixels
    // sit at the realised height plus one common lift (relief kept >= 0).
    std::vector<double> lift_seen;
    for (std::size_t i = 0; i < c1.design.height_m.data.size(); ++i) {
      const std::int32_t l = c1.plan.level_of_pixel[i];
      REQUIRE(l >= 0);
      lift_seen.push_back(c1.design.height_m.data[i] - c1.level_height_m[std::size_t(l)]);
    }
    const auto [lo, hi] = std::minmax_element(lift_seen.begin(), lift_seen.end());
    CHECK(*hi - *lo < 1e-15);
    CHECK(*lo >= -1e-15);
    double moved = 0;
    for (std::size_t l = 0; l < c1.level_height_m.size(); ++l) moved += std::abs(c1.level_height_m[l] - c1.plan.levels[l].height_m);
    CHECK(moved > 1e-9);
    // Same draws as qdo tolerance's trial: another trial or seed draws differently.
    dep.trial = 3;
    CHECK(fab::fabricate(d, cfg, dep).depth_error_m != c1.depth_error_m);

    // Offset: the relief moved by (dx, dy) exactly, as qdo fit's model moves it: the whole pixels
    // (round(1.5) = 2, round(-0.25) = 0) in the map, every pixel on its level, the rest as the
    // optical axis moved the other way (+0.5 and +0.25 px) with the area-weighted aperture; z by the
    // assembly error.
    fab::AsBuiltOptions off = none;
    off.offset_x_m = 1.5 * cfg.pitch_m;
    off.offset_y_m = -0.25 * cfg.pitch_m;
    off.sensor_distance_error_m = 1e-4;
    const fab::AsBuiltCamera c2 = fab::fabricate(d, cfg, off);
    for (std::size_t i = 0; i < cfg.n; ++i)
      for (std::size_t j = 0; j < cfg.n; ++j) CHECK(c2.design.height_m(i, j) == (j >= 2 ? d.height_m(i, j - 2) : 0.0));
    CHECK(c2.cfg.aperture_edge == ApertureEdge::Area);
    CHECK(c2.cfg.aperture_offset_x_m == doctest::Approx(0.5 * cfg.pitch_m).epsilon(1e-12));
    CHECK(c2.cfg.aperture_offset_y_m == doctest::Approx(0.25 * cfg.pitch_m).epsilon(1e-12));
    CHECK(2 * cfg.pitch_m - c2.cfg.aperture_offset_x_m == doctest::Approx(off.offset_x_m).epsilon(1e-12));
    CHECK(c2.cfg.sensor_distance_m == doctest::Approx(cfg.sensor_distance_m + 1e-4).epsilon(1e-12));

    // Refusals name the option.
    fab::AsBuiltOptions bad = none;
    bad.sensor_distance_error_m = -2 * cfg.sensor_distance_m;
    CHECK_THROWS_WITH_AS(fab::fabricate(d, cfg, bad), doctest::Contains("sensor_distance_error_m"), InputError);
    // An error that takes the sensor to the DOE (-12.5 mm on a 12.5 mm camera wrote 1.7e-18 m) or
    // beyond half the distance is no assembly error.
    for (const double f : {-1.0, -0.6, 0.6}) {
      bad.sensor_distance_error_m = f * cfg.sensor_distance_m;
      CHECK_THROWS_WITH_AS(fab::fabricate(d, cfg, bad), doctest::Contains("at most half the DOE-sensor distance"), InputError);
    }
    bad.sensor_distance_error_m = -0.5 * cfg.sensor_distance_m;
    CHECK(fab::fabricate(d, cfg, bad).cfg.sensor_distance_m == doctest::Approx(0.5 * cfg.sensor_distance_m));
    // ... and a configuration with the sensor on the DOE is refused wherever it is read.
    SystemConfig touching = cfg;
    touching.sensor_distance_m = 1.73e-18;
    CHECK_THROWS_WITH_AS(touching.validate(), doctest::Contains("sensor_distance_m"), InputError);
    bad = none;
    bad.offset_x_m = double(cfg.n) * cfg.pitch_m;
    CHECK_THROWS_WITH_AS(fab::fabricate(d, cfg, bad), doctest::Contains("offset_x_m"), InputError);
  }

  TEST_CASE("qdo fabricate writes the as-built design, config and truth; qdo psf takes them; bad values exit 2") {
    const ScratchDir tmp("fabricate");
    const SystemConfig cfg = tiny();
    const Design d = level_design(cfg, 4, 3);
    const std::string design = (tmp.dir / "d.h5").string();
    write_design(design, d);
    const std::string out = (tmp.dir / "cam").string();
    const Run r = qdo_run("fabricate " + design + " " + cfg_arg() + " --seed 4 --offset-um 2,-1 --sensor-distance-error-um 50 --out " + out);
    INFO(r.out);
    REQUIRE(r.code == 0);
    for (const char* f : {"design.h5", "config.json", "truth.json", "heights.png", "height_error.png"}) CHECK(fs::exists(fs::path(out) / f));
    const nlohmann::json t = read_json(fs::path(out) / "truth.json");
    CHECK(t.at("fit_parameters").at("dx").get<double>() == doctest::Approx(2e-6));
    CHECK(t.at("fit_parameters").at("dy").get<double>() == doctest::Approx(-1e-6));
    CHECK(t.at("fit_parameters").at("z").get<double>() == doctest::Approx(cfg.sensor_distance_m + 50e-6));
    CHECK(t.at("fit_parameters").contains("level3"));
    const SystemConfig built = config_from_json_file((fs::path(out) / "config.json").string());
    CHECK(built.sensor_distance_m == doctest::Approx(cfg.sensor_distance_m + 50e-6));
    const Run psf = qdo_run("psf --config " + out + "/config.json --design " + out + "/design.h5 --out " + (tmp.dir / "psf").string());
    INFO(psf.out);
    CHECK(psf.code == 0);

    const Run bad = qdo_run("fabricate " + design + " " + cfg_arg() + " --offset-um 2 --out " + (tmp.dir / "bad").string());
    CHECK(bad.code == 2);
    CHECK(bad.out.find("--offset-um") != std::string::npos);
    CHECK(!fs::exists(tmp.dir / "bad"));
    const Run bad2 = qdo_run("fabricate " + design + " " + cfg_arg() + " --sensor-distance-error-um -1e6 --out " + (tmp.dir / "bad2").string());
    CHECK(bad2.code == 2);
    CHECK(bad2.out.find("sensor_distance_error_m") != std::string::npos);
    CHECK(!fs::exists(tmp.dir / "bad2"));
  }
}
