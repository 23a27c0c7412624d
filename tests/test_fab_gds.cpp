// From design to fab, the masks: GDSII writer/reader, polygon merging, mask schemes and their
// round trip (own reader and KLayout when installed), constraint errors.
#include <cstdlib>
#include <fstream>
#include <map>
#include <set>
#include <sstream>

#include <nlohmann/json.hpp>

#include "common.hpp"
#include "fab_common.hpp"
#include "qdo/design/design_run.hpp"
#include "qdo/evaluate/eval.hpp"
#include "qdo/design/gradcheck.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/fab/fab.hpp"
#include "qdo/fab/gds.hpp"
#include "qdo/data/io.hpp"

using namespace qdo;
using namespace qdo::test;
using namespace qdo::test::fab_suite;

namespace {

std::vector<std::uint8_t> random_mask(std::size_t n, unsigned seed, int density_pct) {
  std::mt19937_64 rng(seed);
  std::vector<std::uint8_t> m(n * n);
  for (auto& v : m) v = int(rng() % 100) < density_pct ? 1 : 0;
  return m;
}

int run_shell(const std::string& cmd, std::string* out = nullptr) {
  const auto dir = temp_dir("fab_sh");
  const std::string log = (dir / "log.txt").string();
  const int status = std::system((cmd + " > " + log + " 2>&1").c_str());
  if (out) *out = slurp(log);
  std::filesystem::remove_all(dir);
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

// KLayout on PATH (QDO_SKIP_KLAYOUT=1 pretends it is not, to exercise the skip).
bool have_klayout() {
  if (const char* e = std::getenv("QDO_SKIP_KLAYOUT"); e && std::string(e) == "1") return false;
  return std::system("command -v klayout > /dev/null 2>&1") == 0;
}

// Asks KLayout (batch mode, one start for all files) for every layer of each GDSII file: shape
// count, merged area (nm^2), the number of self-overlapping ("strange") polygons, and the pixels
// whose centre lies inside the layer's region.
struct KLayer {
  std::size_t shapes = 0, strange = 0;
  double area_nm2 = 0;
  std::set<std::size_t> pixels;
};
struct KFile {
  double dbu_um = 0;
  std::map<int, KLayer> layers;
};
std::vector<KFile> klayout_layers(const std::vector<std::string>& gds, std::size_t n, std::int64_t pitch, std::int64_t org) {
  const auto dir = temp_dir("fab_klayout");
  const std::string script = (dir / "probe.py").string(), list = (dir / "files.txt").string();
  {
    std::ofstream lf(list);
    for (std::size_t k = 0; k < gds.size(); ++k) lf << gds[k] << " " << (dir / ("out" + std::to_string(k) + ".txt")).string() << "\n";
  }
  std::ofstream(script) << R"(import pya
N = int(n); P = int(pitch); O = int(org)
centres = pya.Region()
for i in range(N):
    for j in range(N):
        cx = O + j * P + P // 2
        cy = O + i * P + P // 2
        centres.insert(pya.Box(cx - 1, cy - 1, cx + 1, cy + 1))
for line in open(files):
    gds, out = line.split()
    ly = pya.Layout()
    ly.read(gds)
    top = ly.top_cell()
    with open(out, "w") as f:
        f.write("dbu %.12g\n" % ly.dbu)
        for li in ly.layer_indexes():
            info = ly.get_info(li)
            reg = pya.Region(top.begin_shapes_rec(li))
            pix = []
            for poly in centres.inside(reg).each():
                c = poly.bbox().center()
                pix.append(str(((c.y - O) // P) * N + (c.x - O) // P))
            f.write("layer %d %d %d %d %s\n" % (info.layer, top.shapes(li).size(), reg.area(),
                                                reg.strange_polygon_check().count(), " ".join(pix)))
)";
  const std::string cmd = "klayout -b -rd files=" + list + " -rd n=" + std::to_string(n) + " -rd pitch=" + std::to_string(pitch) +
                          " -rd org=" + std::to_string(org) + " -r " + script;
  std::string log;
  REQUIRE_MESSAGE(run_shell(cmd, &log) == 0, log);
  std::vector<KFile> files;
  for (std::size_t k = 0; k < gds.size(); ++k) {
    KFile kf;
    std::istringstream in(slurp(dir / ("out" + std::to_string(k) + ".txt")));
    std::string line;
    while (std::getline(in, line)) {
      std::istringstream ls(line);
      std::string tag;
      ls >> tag;
      if (tag == "dbu") {
        ls >> kf.dbu_um;
        continue;
      }
      int layer = 0;
      KLayer kl;
      ls >> layer >> kl.shapes >> kl.area_nm2 >> kl.strange;
      std::size_t p = 0;
      while (ls >> p) kl.pixels.insert(p);
      kf.layers[layer] = kl;
    }
    files.push_back(kf);
  }
  std::filesystem::remove_all(dir);
  return files;
}

}  // namespace

TEST_SUITE("fab") {
  TEST_CASE("GDSII 8-byte reals and a written stream read back") {
    CHECK(gds::encode_real(1.0) == 0x4110000000000000ull);
    CHECK(gds::encode_real(-2.0) == 0xC120000000000000ull);
    CHECK(gds::encode_real(0.0) == 0ull);
    for (double v : {1e-3, 1e-9, 0.5, 1.0 / 3.0, 12345.678, -7.25e-7, 1e-30, 3e40}) CHECK(gds::decode_real(gds::encode_real(v)) == v);
    // The UNITS words most tools write (mantissa truncated from the decimal value).
    CHECK(gds::decode_real(0x3E4189374BC6A7EFull) == doctest::Approx(1e-3).epsilon(1e-15));
    CHECK(gds::decode_real(0x3944B82FA09B5A51ull) == doctest::Approx(1e-9).epsilon(1e-15));

    gds::Library lib;
    lib.name = "T";
    lib.timestamp[0] = 2024;
    lib.timestamp[1] = 1;
    lib.timestamp[2] = 2;
    lib.boundaries.push_back({3, 0, {{0, 0}, {10, 0}, {10, 5}, {0, 5}, {0, 0}}});
    lib.boundaries.push_back({7, 2, {{-2000000000, -5}, {2000000000, -5}, {0, 9}, {-2000000000, -5}}});
    const auto bytes = gds::encode(lib);
    REQUIRE(bytes.size() % 2 == 0);
    CHECK(bytes[0] == 0x00);
    CHECK(bytes[1] == 0x06);  // HEADER: 6 bytes
    CHECK(bytes[2] == 0x00);  // record type HEADER
    CHECK(bytes[4] == 0x02);
    CHECK(bytes[5] == 0x58);  // version 600
    const gds::Library back = gds::decode(bytes, "memory");
    CHECK(back.name == "T");
    CHECK(back.structure == "DOE");
    CHECK(back.db_in_user_units == 1e-3);
    CHECK(back.db_in_metres == 1e-9);
    REQUIRE(back.boundaries.size() == 2);
    for (std::size_t k = 0; k < 2; ++k) {
      CHECK(back.boundaries[k].layer == lib.boundaries[k].layer);
      CHECK(back.boundaries[k].datatype == lib.boundaries[k].datatype);
      CHECK(back.boundaries[k].points == lib.boundaries[k].points);
    }
    // Broken streams and boundaries are named.
    std::vector<std::uint8_t> cut(bytes.begin(), bytes.end() - 6);
    CHECK_THROWS_WITH_AS(gds::decode(cut, "cut.gds"), doctest::Contains("cut.gds"), InputError);
    gds::Library open = lib;
    open.boundaries[0].points.pop_back();
    CHECK_THROWS_WITH_AS(gds::encode(open), doctest::Contains("closed"), InputError);
    gds::Library big = lib;
    big.boundaries[0].points.assign(8192, {0, 0});
    CHECK_THROWS_WITH_AS(gds::encode(big), doctest::Contains("8191"), InputError);
    gds::Library far = lib;
    far.boundaries[0].points = {{0, 0}, {std::int64_t(1) << 32, 0}, {0, 1}, {0, 0}};
    CHECK_THROWS_WITH_AS(gds::encode(far), doctest::Contains("int32"), InputError);
  }

  TEST_CASE("merged polygons: simple, within the point limit, exact pixel coverage") {
    for (unsigned seed = 1; seed <= 6; ++seed)
      for (int density : {15, 50, 85}) {
        CAPTURE(seed);
        CAPTURE(density);
        const std::size_t n = 40;
        const auto mask = random_mask(n, seed, density);
        const std::size_t max_points = seed % 2 ? gds::kMaxBoundaryPoints : 13;  // small limit: forces splits
        const auto polys = gds::merge_pixels(mask, n, n, max_points);
        double area = 0;
        for (const auto& p : polys) {
          REQUIRE(p.size() >= 5);
          CHECK(p.size() <= max_points);
          CHECK(p.front() == p.back());
          CHECK(gds::is_simple(p));
          CHECK(gds::signed_area(p) > 0);
          area += gds::signed_area(p);
        }
        CHECK(area == double(std::count(mask.begin(), mask.end(), std::uint8_t(1))));
        CHECK(gds::rasterize(polys, n, n) == mask);
        // Merging pays: far fewer polygons than pixel runs.
        std::size_t runs = 0;
        for (std::size_t i = 0; i < n; ++i)
          for (std::size_t j = 0; j < n; ++j) runs += mask[i * n + j] && (j == 0 || !mask[i * n + j - 1]);
        CHECK(polys.size() <= runs);
      }
    // A full block is one rectangle; a ring (a region with a hole) splits into hole-free polygons.
    std::vector<std::uint8_t> block(64, 1);
    CHECK(gds::merge_pixels(block, 8, 8).size() == 1);
    std::vector<std::uint8_t> ring(64, 1);
    for (std::size_t i = 2; i < 6; ++i)
      for (std::size_t j = 2; j < 6; ++j) ring[i * 8 + j] = 0;
    const auto rp = gds::merge_pixels(ring, 8, 8);
    CHECK(rp.size() == 2);
    CHECK(gds::rasterize(rp, 8, 8) == ring);
    // A tall staircase under the 8191-point limit is split, still exact.
    const std::size_t tall = 5000;
    std::vector<std::uint8_t> stairs(tall * 4, 0);
    for (std::size_t i = 0; i < tall; ++i)
      for (std::size_t j = 0; j <= (i % 2) + 1; ++j) stairs[i * 4 + j] = 1;
    const auto sp = gds::merge_pixels(stairs, tall, 4);
    CHECK(sp.size() >= 2);
    for (const auto& p : sp) CHECK(p.size() <= gds::kMaxBoundaryPoints);
    CHECK(gds::rasterize(sp, tall, 4) == stairs);
  }

  TEST_CASE("export round trip is exact for 2, 4, 8 and 16 levels in every scheme") {
    const SystemConfig cfg = tiny_config(32, 3);
    const auto dir = temp_dir("fab_export");
    const bool klayout = have_klayout();
    struct Case {
      std::string dir;
      Design design;
      fab::MaskPlan plan;
    };
    std::vector<Case> cases;
    for (int L : {2, 4, 8, 16})
      for (fab::Scheme s : {fab::Scheme::Binary, fab::Scheme::Nested, fab::Scheme::Greyscale}) {
        CAPTURE(L);
        CAPTURE(fab::to_string(s));
        const Design d = level_design(cfg, L, unsigned(L) * 7 + 1);
        fab::ExportOptions o;
        o.scheme = s;
        o.out = (dir / (fab::to_string(s) + std::to_string(L))).string();
        o.provenance = {{"test", "round trip"}};
        const fab::ExportResult r = fab::export_design(d, cfg, o);
        const std::size_t expect_masks = s == fab::Scheme::Binary ? std::size_t(std::log2(L) + 0.5)
                                         : s == fab::Scheme::Nested ? std::size_t(L - 1) : std::size_t(L);
        CHECK(r.plan.masks.size() == expect_masks);
        if (s == fab::Scheme::Binary) {
          CHECK(r.plan.method == "index-coded");
          for (std::size_t j = 0; j < r.plan.masks.size(); ++j)  // depths d, 2d, 4d, ...
            CHECK(r.plan.masks[j].etch_depth_m == doctest::Approx(double(1 << j) * cfg.h_max_m() / (L - 1)).epsilon(1e-12));
        }
        // The project's reader, from the files alone.
        const fab::Reconstruction rec = fab::reconstruct_export(o.out);
        CHECK(rec.level_of_pixel == r.plan.level_of_pixel);
        double worst = 0;
        for (std::size_t i = 0; i < rec.height_m.data.size(); ++i)
          worst = std::max(worst, std::fabs(rec.height_m.data[i] - d.height_m.data[i]));
        CHECK(worst < 1e-18);  // 1e-9 nm: float rounding of the depth sums only
        for (const char* f : {"masks.gds", "manifest.json", "manifest.md", "heights_from_masks.png", "mask_L1.png"})
          CHECK(std::filesystem::exists(std::filesystem::path(o.out) / f));
        // Polygon areas match the pixel counts, layer by layer.
        const gds::Library lib = gds::read(o.out + "/masks.gds");
        const double p2 = cfg.pitch_m * 1e9 * cfg.pitch_m * 1e9;
        for (const auto& mk : r.plan.masks) {
          double area = 0;
          for (const auto& b : lib.boundaries)
            if (b.layer == mk.layer) {
              CHECK(b.points.size() <= gds::kMaxBoundaryPoints);
              area += gds::signed_area(b.points);
            }
          CHECK(area == double(mk.pixels) * p2);
        }
        cases.push_back({o.out, d, r.plan});
      }
    // An independent reader: KLayout in batch mode reads every file; its pixel coverage rebuilds
    // the height map.
    if (skip_unless(klayout, "klayout not on PATH: the independent-reader check (apt-get install klayout)")) {
      std::vector<std::string> files;
      for (const auto& c : cases) files.push_back(c.dir + "/masks.gds");
      const std::int64_t pitch = std::llround(cfg.pitch_m * 1e9), org = -std::int64_t(cfg.n / 2) * pitch - pitch / 2;
      const double p2 = double(pitch) * double(pitch);
      const auto kfiles = klayout_layers(files, cfg.n, pitch, org);
      REQUIRE(kfiles.size() == cases.size());
      for (std::size_t c = 0; c < cases.size(); ++c) {
        CAPTURE(cases[c].dir);
        const auto& layers = kfiles[c].layers;
        const auto& plan = cases[c].plan;
        CHECK(kfiles[c].dbu_um == doctest::Approx(1e-3));
        CHECK(layers.count(fab::kMarkLayer) == 1);
        CHECK(layers.count(fab::kApertureLayer) == 1);
        std::vector<std::vector<std::uint8_t>> drawn;
        for (const auto& mk : plan.masks) {
          const auto it = layers.find(mk.layer);
          std::vector<std::uint8_t> bits(cfg.n * cfg.n, 0);
          REQUIRE(it != layers.end());
          CHECK(it->second.strange == 0);
          CHECK(it->second.area_nm2 == double(mk.pixels) * p2);
          for (std::size_t pix : it->second.pixels) bits[pix] = 1;
          drawn.push_back(bits);
        }
        const fab::Reconstruction kr = fab::reconstruct(plan, drawn);
        CHECK(kr.level_of_pixel == plan.level_of_pixel);
        double kw = 0;
        for (std::size_t i = 0; i < kr.height_m.data.size(); ++i)
          kw = std::max(kw, std::fabs(kr.height_m.data[i] - cases[c].design.height_m.data[i]));
        CHECK(kw < 1e-18);
      }
    }
    // Wrapped levels are multiples of h_max / L: index-coded binary masks below the top level.
    Quantizer w;
    w.levels = 8;
    w.placement = Placement::Wrapped;
    const Design dw = level_design(cfg, 8, 99, w.level_heights_m(cfg.h_max_m()));
    fab::ExportOptions ow;
    ow.out = (dir / "wrapped").string();
    const auto rw = fab::export_design(dw, cfg, ow);
    CHECK(rw.plan.masks.size() == 3);
    CHECK(rw.plan.top_m == doctest::Approx(cfg.h_max_m() * 7.0 / 8.0));
    // The manifest says what the fab needs.
    const nlohmann::json j = nlohmann::json::parse(slurp(std::filesystem::path(ow.out) / "manifest.json"));
    CHECK(j["scheme"] == "binary");
    CHECK(j["material"] == cfg.material);
    CHECK(j["levels"].size() == 8);
    CHECK(j["masks"].size() == 3);
    CHECK(j["masks"][0]["polygons"].get<int>() > 0);
    CHECK(j["check"]["level_map_identical"] == true);
    CHECK(j["gds"]["database_unit_m"] == 1e-9);
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("constraint violations are errors naming the level, the scheme limit or the region; nothing is written") {
    const SystemConfig cfg = tiny_config(32, 3);
    const auto dir = temp_dir("fab_constraints");
    const double hm = cfg.h_max_m();
    fab::ExportOptions o;
    o.out = (dir / "out").string();
    // Free per-level heights (QDO+A-like) with binary-coded masks.
    const Design qa = level_design(cfg, 4, 5, {0.0, 0.30 * hm, 0.71 * hm, 0.98 * hm});
    CHECK_THROWS_WITH_AS(fab::export_design(qa, cfg, o), doctest::Contains("level 0"), InputError);
    CHECK_THROWS_WITH_AS(fab::export_design(qa, cfg, o), doctest::Contains("--scheme nested"), InputError);
    o.scheme = fab::Scheme::Nested;  // ... which nested masks make: three free steps
    const auto rn = fab::export_design(qa, cfg, o);
    CHECK(rn.plan.masks.size() == 3);
    CHECK(rn.plan.masks[0].etch_depth_m == doctest::Approx(0.27 * hm));
    std::filesystem::remove_all(o.out);
    // Too many levels for the scheme.
    const Design d32 = level_design(cfg, 32, 6);
    for (fab::Scheme s : {fab::Scheme::Binary, fab::Scheme::Nested}) {
      o.scheme = s;
      CHECK_THROWS_WITH_AS(fab::export_design(d32, cfg, o), doctest::Contains("allows at most 16"), InputError);
    }
    o.scheme = fab::Scheme::Greyscale;
    CHECK(fab::export_design(d32, cfg, o).plan.masks.size() == 32);
    std::filesystem::remove_all(o.out);
    o.constraints.max_levels = 8;
    CHECK_THROWS_WITH_AS(fab::export_design(d32, cfg, o), doctest::Contains("--max-levels"), InputError);
    o.constraints = {};
    // Features below the minimum size: the mask, its layer and the pixel region are named.
    o.scheme = fab::Scheme::Binary;
    o.constraints.min_feature_um = 10;  // 3 pixels at 4 um
    const Design d4 = level_design(cfg, 4, 7);
    CHECK_THROWS_WITH_AS(fab::export_design(d4, cfg, o), doctest::Contains("minimum feature size 10 um"), InputError);
    CHECK_THROWS_WITH_AS(fab::export_design(d4, cfg, o), doctest::Contains("pixel (row"), InputError);
    // A single-pixel gap in a mask is named too.
    {
      Design g = level_design(cfg, 2, 1);
      for (double& v : g.height_m.data) v = g.levels_m[0];
      for (std::size_t i = 4; i < 20; ++i) g.height_m(i, 10) = g.levels_m[1];  // a 1-pixel-wide unetched line
      o.constraints.min_feature_um = 6;
      CHECK_THROWS_WITH_AS(fab::export_design(g, cfg, o), doctest::Contains("gaps between drawn features"), InputError);
      CHECK_THROWS_WITH_AS(fab::export_design(g, cfg, o), doctest::Contains("pixel (row 4, col 10)"), InputError);
    }
    o.constraints = {};
    // Heights outside the etchable range.
    const Design high = level_design(cfg, 4, 8, {0.0, 0.4 * hm, 0.8 * hm, 1.2 * hm});
    CHECK_THROWS_WITH_AS(fab::export_design(high, cfg, o), doctest::Contains("level 3"), InputError);
    CHECK_THROWS_WITH_AS(fab::export_design(high, cfg, o), doctest::Contains("etchable range"), InputError);
    o.constraints.max_height_nm = 1.3 * hm * 1e9;  // a thicker relief layer makes it possible (nested)
    o.scheme = fab::Scheme::Nested;
    CHECK_NOTHROW(fab::export_design(high, cfg, o));
    std::filesystem::remove_all(o.out);
    o.constraints = {};
    // Heights that are no level; a pitch off the 1 nm grid.
    Design odd = d4;
    odd.height_m(3, 5) += 7e-9;
    CHECK_THROWS_WITH_AS(fab::export_design(odd, cfg, o), doctest::Contains("pixel (row 3, col 5)"), InputError);
    SystemConfig c3 = cfg;
    c3.pitch_m = 4.0005e-6;
    CHECK_THROWS_WITH_AS(fab::export_design(d4, c3, o), doctest::Contains("pitch_m"), InputError);
    CHECK_FALSE(std::filesystem::exists(o.out));  // every check runs before anything is written

    // The command line: exit code 2 and the message.
    const std::string cfg_path = (dir / "cfg.json").string(), design_path = (dir / "qa.h5").string();
    write_text_atomic(cfg_path, config_to_json_text(cfg));
    write_design(design_path, qa);
    std::string out;
    const int rc = run_shell(std::string(QDO_QDO_BINARY) + " export " + design_path + " --config " + cfg_path + " --scheme binary --out " +
                                 (dir / "cli").string(),
                             &out);
    CHECK(rc == 2);
    CHECK(out.find("level 0") != std::string::npos);
    CHECK(run_shell(std::string(QDO_QDO_BINARY) + " export " + design_path + " --config " + cfg_path + " --scheme nested --out " +
                    (dir / "cli").string(),
                    &out) == 0);
    CHECK(out.find("nested scheme") != std::string::npos);
    std::filesystem::remove_all(dir);
  }
}
