// Training scenes, the index: SceneIndex finds scenes recursively, caches their shapes and
// splits them deterministically.
#include <doctest/doctest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <set>
#include <string>
#include <vector>

#include "common.hpp"
#include "datasets_common.hpp"
#include "qdo/data/datasets.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"

namespace fs = std::filesystem;
using namespace qdo;
using namespace qdo::test::datasets_suite;

TEST_SUITE("datasets") {
  TEST_CASE("SceneIndex finds scenes recursively, caches shapes and splits deterministically") {
    TempDir tmp("index");
    for (int k = 0; k < 11; ++k) {
      fs::create_directories(tmp / ("set" + std::to_string(k % 3)));
      write_cube(tmp / ("set" + std::to_string(k % 3) + "/s" + std::to_string(k) + ".h5"),
                 random_stack(3, 6 + static_cast<std::size_t>(k), 8, static_cast<std::uint64_t>(k)), {450, 550, 650});
    }
    write_png_folder(tmp / "cave/balloons_ms/balloons_ms", 3, 5, 6);
    { std::ofstream(tmp / "set0/readme.txt") << "not a scene"; }
    const SceneIndex idx({tmp.str()}, "auto", 3);
    REQUIRE(idx.size() == 12);
    CHECK(std::is_sorted(idx.entries().begin(), idx.entries().end(),
                         [](const SceneEntry& a, const SceneEntry& b) { return a.path < b.path; }));
    std::size_t png = 0;
    for (std::size_t i = 0; i < idx.size(); ++i) {
      if (idx[i].format == "cave-png") {
        ++png;
        CHECK(idx[i].shape == SceneShape{3, 5, 6});
      } else {
        CHECK(idx[i].format == "h5");
      }
      const RealStack c = idx.load(i);
      CHECK(idx[i].shape == SceneShape{c.planes, c.rows, c.cols});
    }
    CHECK(png == 1);
    // A single file is an index of one.
    CHECK(SceneIndex({idx[0].path}, "auto", 3).size() == 1);
    CHECK(input_error([&] { SceneIndex({tmp / "nothing_here"}, "auto", 3); }).find("nothing_here") != std::string::npos);

    // Splits: deterministic by seed, disjoint, covering, sized by the fractions.
    const SceneIndex icvl = SceneIndex::synthetic(preset_config("paper"), 201, 8, 0);
    const SceneSplit a = icvl.split(42, 0.83, 0.085), b = icvl.split(42, 0.83, 0.085), c = icvl.split(43, 0.83, 0.085);
    CHECK(a.train.size() == 167);
    CHECK(a.val.size() == 17);
    CHECK(a.test.size() == 17);
    CHECK(a.train == b.train);
    CHECK(a.val == b.val);
    CHECK(a.test == b.test);
    CHECK(a.train != c.train);
    std::set<std::size_t> all(a.train.begin(), a.train.end());
    all.insert(a.val.begin(), a.val.end());
    all.insert(a.test.begin(), a.test.end());
    CHECK(all.size() == 201);
    CHECK(*all.rbegin() == 200);
    const SceneSplit s = idx.split(1, 0.5, 0.25);
    CHECK(s.train.size() == 6);
    CHECK(s.val.size() == 3);
    CHECK(s.test.size() == 3);
    CHECK(input_error([&] { idx.split(1, 0.9, 0.2); }).find("train_frac + val_frac") != std::string::npos);
  }
}
