// Training scenes, from scene to batch: patch positions (the paper's 9 crops), augmentation by
// the dihedral group D4, and the PatchSampler (deterministic by seed, bounded LRU cache).
#include <doctest/doctest.h>

#include <algorithm>
#include <cstdint>
#include <set>
#include <string>
#include <vector>

#include "common.hpp"
#include "datasets_common.hpp"
#include "qdo/data/datasets.hpp"
#include "qdo/runtime/error.hpp"

namespace fs = std::filesystem;
using namespace qdo;
using namespace qdo::test::datasets_suite;

TEST_SUITE("datasets") {
  TEST_CASE("patches: counts, positions, the paper's 9 crops cover the corners") {
    CHECK(patch_starts(1392, 512, 440) == std::vector<std::size_t>{0, 440, 880});
    CHECK(patch_starts(10, 4, 3) == std::vector<std::size_t>{0, 3, 6});
    CHECK(patch_starts(7, 4, 2) == std::vector<std::size_t>{0, 2, 3});  // last aligned to the edge
    CHECK(patch_starts(4, 4, 9) == std::vector<std::size_t>{0});
    CHECK_THROWS_AS(patch_starts(3, 4, 1), InputError);
    CHECK_THROWS_AS(patch_starts(8, 4, 0), InputError);

    const RealStack small = random_stack(2, 10, 7, 5);
    const std::vector<RealStack> p = extract_patches(small, 4, 3);
    const std::vector<PatchOrigin> o = patch_origins(10, 7, 4, 3);
    REQUIRE(p.size() == 6);  // rows 0, 3, 6 x cols 0, 3
    REQUIRE(o.size() == 6);
    CHECK(o[5] == PatchOrigin{6, 3});
    for (std::size_t k = 0; k < p.size(); ++k)
      for (std::size_t b = 0; b < 2; ++b)
        for (std::size_t y = 0; y < 4; ++y)
          for (std::size_t x = 0; x < 4; ++x) REQUIRE(p[k](b, y, x) == small(b, o[k].y + y, o[k].x + x));
    CHECK(input_error([&] { extract_patches(small, 8, 2); }).find("patch size") != std::string::npos);

    // ICVL-sized scene: 9 crops of 512 from 1392 x 1300.
    RealStack scene(1, 1392, 1300);
    for (std::size_t y = 0; y < 1392; ++y)
      for (std::size_t x = 0; x < 1300; ++x) scene(0, y, x) = static_cast<double>(y * 1300 + x);
    const std::vector<PatchOrigin> g = grid_origins(1392, 1300, 512, 3);
    REQUIRE(g.size() == 9);
    CHECK(g[0] == PatchOrigin{0, 0});
    CHECK(g[1] == PatchOrigin{0, 394});
    CHECK(g[4] == PatchOrigin{440, 394});
    CHECK(g[8] == PatchOrigin{880, 788});
    const std::vector<RealStack> nine = paper_crops(scene, 512);
    REQUIRE(nine.size() == 9);
    CHECK(nine[0](0, 0, 0) == scene(0, 0, 0));
    CHECK(nine[2](0, 0, 511) == scene(0, 0, 1299));
    CHECK(nine[6](0, 511, 0) == scene(0, 1391, 0));
    CHECK(nine[8](0, 511, 511) == scene(0, 1391, 1299));
    // Together the 9 crops cover every pixel.
    std::vector<char> covered(1392 * 1300, 0);
    for (const PatchOrigin& q : g)
      for (std::size_t y = 0; y < 512; ++y)
        for (std::size_t x = 0; x < 512; ++x) covered[(q.y + y) * 1300 + q.x + x] = 1;
    CHECK(std::count(covered.begin(), covered.end(), 1) == 1392 * 1300);
  }

  TEST_CASE("augmentation is the dihedral group D4") {
    RealStack m(1, 2, 2);
    m.data = {1, 2, 3, 4};
    CHECK(augment(m, 1).data == std::vector<double>{2, 4, 1, 3});  // quarter turn counter-clockwise
    CHECK(augment(m, 2).data == std::vector<double>{4, 3, 2, 1});
    CHECK(augment(m, 4).data == std::vector<double>{2, 1, 4, 3});  // left-right mirror

    const RealStack c = random_stack(3, 6, 6, 11);
    std::vector<RealStack> all;
    for (int g = 0; g < 8; ++g) {
      all.push_back(augment(c, g));
      CHECK(same(augment(all.back(), augment_inverse(g)), c));
    }
    for (int a = 0; a < 8; ++a)
      for (int b = a + 1; b < 8; ++b) CHECK_FALSE(same(all[static_cast<std::size_t>(a)], all[static_cast<std::size_t>(b)]));
    CHECK(same(all[0], c));
    // Closed under composition.
    for (int a = 0; a < 8; ++a)
      for (int b = 0; b < 8; ++b) {
        const RealStack ab = augment(all[static_cast<std::size_t>(a)], b);
        CHECK(std::any_of(all.begin(), all.end(), [&](const RealStack& r) { return same(r, ab); }));
      }
    // Non-square: odd quarter turns swap rows and cols.
    const RealStack r = random_stack(2, 3, 5, 12);
    for (int g = 0; g < 8; ++g) {
      const RealStack t = augment(r, g);
      CHECK(t.rows == (g % 2 ? 5u : 3u));
      CHECK(same(augment(t, augment_inverse(g)), r));
    }
    CHECK_THROWS_AS(augment(r, 8), InputError);
  }

  TEST_CASE("PatchSampler: deterministic by seed, bounded LRU cache, patches match their refs") {
    SystemConfig cfg = preset_config("paper");
    cfg.bands = 4;
    const SceneIndex idx = SceneIndex::synthetic(cfg, 5, 24, 9);
    PatchSamplerOptions opt;
    opt.patch_size = 16;
    opt.batch_size = 4;
    opt.cache_scenes = 2;
    PatchSampler a(idx, {0, 1, 2, 3, 4}, opt, 7), b(idx, {0, 1, 2, 3, 4}, opt, 7), c(idx, {0, 1, 2, 3, 4}, opt, 8);
    CHECK(a.patches_per_epoch() == 45);
    bool differ = false;
    std::set<int> codes;
    for (int step = 0; step < 12; ++step) {  // 48 patches: past one epoch
      const std::vector<RealStack> ba = a.next_batch(), bb = b.next_batch(), bc = c.next_batch();
      REQUIRE(ba.size() == 4);
      for (std::size_t k = 0; k < ba.size(); ++k) {
        CHECK(same(ba[k], bb[k]));
        if (!same(ba[k], bc[k])) differ = true;
        const PatchRef& r = a.last_refs()[k];
        codes.insert(r.code);
        CHECK(same(ba[k], augment(crop_patch(idx.load(r.scene), r.origin, 16), r.code)));
      }
      CHECK(a.cache().held() <= 2);
    }
    CHECK(differ);
    CHECK(codes.size() > 4);
    CHECK(a.epoch() == 2);
    CHECK(a.cache().loads() <= 5 + 2);  // each cube decoded once per epoch (+ the start of epoch 2)

    // An epoch visits every crop of every scene once.
    PatchSamplerOptions one = opt;
    one.batch_size = 1;
    one.augment = false;
    PatchSampler e(idx, {1, 3}, one, 3);
    std::set<std::tuple<std::size_t, std::size_t, std::size_t>> seen;
    for (int k = 0; k < 18; ++k) {
      e.next_batch();
      const PatchRef& r = e.last_refs()[0];
      CHECK(r.code == 0);
      seen.insert({r.scene, r.origin.y, r.origin.x});
    }
    CHECK(seen.size() == 18);
    CHECK(e.cache().loads() == 2);

    opt.patch_size = 32;
    CHECK(input_error([&] { PatchSampler(idx, {0}, opt, 1); }).find("synthetic:0") != std::string::npos);
  }
}
