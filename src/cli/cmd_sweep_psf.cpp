// qdo sweep-psf: PSF quality against the number of levels for one design (sweep.hpp).
#include <algorithm>
#include <cstdlib>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>

#include "cli.hpp"
#include "options.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/design/design_run.hpp"
#include "qdo/data/io.hpp"
#include "qdo/runtime/mpi.hpp"
#include "qdo/design/run.hpp"
#include "qdo/evaluate/sweep.hpp"

namespace fs = std::filesystem;
using namespace qdo;
using namespace qdo::cli;

namespace qdo::cli {

static int cmd_sweep_psf(const Args& a) {
  PsfSweepOptions o;
  const std::string design = a.get("design");
  if (design.empty()) reject("--design", "(missing)", "a design .h5 file or a run folder");
  if (fs::is_directory(design)) {
    if (a.has("preset") || a.has("config")) reject("--preset", "(given)", "omitted with a run folder (its config.json is used)");
    o.cfg = read_run_config(design).cfg;
    o.design_full_m = RunFolder(design).design_full().height_m;
  } else {
    o.cfg = load_config(a);
    o.design_full_m = load_design(o.cfg, design);
  }
  const Placement pl = placement_from_string(a.get("placement"));
  std::set<int> seen_levels;
  for (const auto& l : split_items(a.get("levels"))) {
    PsfSweepVariant v;
    v.quantizer.levels = parse_int("--levels", l, 2, 65536);
    if (!seen_levels.insert(v.quantizer.levels).second)
      reject("--levels", a.get("levels"), "distinct level counts (" + l + " appears twice)");
    v.quantizer.placement = pl;
    v.label = "L" + l;
    o.variants.push_back(v);
  }
  if (a.has("adaptive-from")) {
    const PsfSweepVariant v = adaptive_psf_sweep_variant(a.get("adaptive-from"), "--adaptive-from");
    o.variants.push_back(v);
  }
  o.precision = precision_from_string(a.get("precision"));
  o.max_designs_per_pass = std::size_t(parse_int("--designs-per-pass", a.get("designs-per-pass"), 0, 1000));
  o.out = out_dir(a);
  Runtime rt(a.get("device"));
  const auto t0 = std::chrono::steady_clock::now();
  const auto rows = sweep_psf(rt, o);
  std::printf("%-14s %7s %12s %12s %12s %12s %14s\n", "variant", "levels", "dev [nm]", "rel L2", "peak ratio", "EE80 [um]", "outside win.");
  for (const auto& r : rows) {
    auto mean = [](const std::vector<double>& v) {
      double s = 0;
      for (double x : v) s += x;
      return s / double(v.size());
    };
    std::printf("%-14s %7d %12.3f %12.4f %12.4f %12.2f %14.4f\n", r.label.c_str(), r.levels, r.deviation_nm, mean(r.rel_l2),
                mean(r.peak_ratio), mean(r.ee80_um), mean(r.energy_outside));
  }
  std::printf("(means over %zu bands) %.1f s; wrote %s/ (sweep.csv sweep.json psf.h5 psf_*.png *_vs_variant.png)\n", o.cfg.bands,
              seconds_since(t0), o.out.c_str());
  return 0;
}

namespace {
// qdo sweep-psf: its entry in the command table (help order 190).
const RegisterCommand registered_sweep_psf(190, [] {
  using namespace opts;
  CommandSpec c{"sweep-psf", "PSF quality against the number of levels for one design", "", "",
                   {opt("design", "a design .h5 file or a run folder"),
                    opt("levels", "level counts, comma-separated integers in [2, 65536]", "2,4,8,16,32"), placement(),
                    opt("adaptive-from", "also the adaptive levels of this qdo+a run folder"), preset(), config(), precision(), device(),
                    opt("designs-per-pass", "designs per device pass, an integer in [0, 1000] (0: automatic)", "0"), out_dir_opt()},
                   cmd_sweep_psf, true};
  return c;
});
}  // namespace

}  // namespace qdo::cli
