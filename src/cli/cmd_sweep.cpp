// qdo sweep-psf and qdo sweep.
#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>

#include "cli.hpp"
#include "qdo/run_folder.hpp"
#include "qdo/error.hpp"
#include "qdo/io.hpp"
#include "qdo/run.hpp"
#include "qdo/sweep.hpp"

namespace fs = std::filesystem;
using namespace qdo;
using namespace qdo::cli;

namespace qdo::cli {
namespace {


}  // namespace

int cmd_sweep_psf(const Args& a) {
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
  for (const auto& l : split_list(a.get("levels"))) {
    PsfSweepVariant v;
    v.quantizer.levels = parse_int("--levels", l, 2, 65536);
    if (!seen_levels.insert(v.quantizer.levels).second)
      reject("--levels", a.get("levels"), "distinct level counts (" + l + " appears twice)");
    v.quantizer.placement = pl;
    v.label = "L" + l;
    o.variants.push_back(v);
  }
  if (a.has("adaptive-from")) {
    const std::string run = a.get("adaptive-from");
    const DesignRunOptions ro = read_run_config(run);
    if (ro.design.mode != DesignMode::QDOA) reject("--adaptive-from", run, "a qdo+a run (it is " + to_string(ro.design.mode) + ")");
    const std::size_t L = std::size_t(ro.design.quantizer.levels);
    const DesignState st = load_checkpoint(RunFolder(run).checkpoint_path(),
                                           parameter_count(ro.design.parameterization, ro.cfg.n), L);
    PsfSweepVariant v;
    v.quantizer = ro.design.quantizer;
    v.quantizer.offsets = st.offsets;
    v.label = "L" + std::to_string(L) + "-adaptive";
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

int cmd_sweep(const Args& a) {
  GridOptions g;
  Args b = a;
  b.opt["out"] = "(per run)";
  b.opt["mode"] = "do";
  g.base = design_options(b);  // qdo design's options; levels and mode are set per cell
  const auto grids = a.multi.find("grid");
  std::set<std::string> axes;
  for (const auto& spec : grids == a.multi.end() ? std::vector<std::string>{} : grids->second) {
    const auto eq = spec.find('=');
    if (eq == std::string::npos) reject("--grid", spec, "AXIS=V1,V2,... with AXIS levels, mode, encoder or decoder");
    const std::string axis = spec.substr(0, eq);
    if (axis != "levels" && axis != "mode" && axis != "encoder" && axis != "decoder")
      reject("--grid", axis, "levels, mode, encoder or decoder");
    if (!axes.insert(axis).second) reject("--grid", spec, "each axis once (" + axis + " is given twice)");
    std::vector<std::string> vals = split_list(spec.substr(eq + 1));
    // A decoder spec holds commas of its own (resunet:depth=4,root=16): a key=value item after a
    // spec with parameters belongs to it.
    if (axis == "decoder") {
      std::vector<std::string> joined;
      for (const auto& v : vals) {
        if (!joined.empty() && v.find('=') != std::string::npos && v.find(':') == std::string::npos &&
            joined.back().find(':') != std::string::npos)
          joined.back() += "," + v;
        else
          joined.push_back(v);
      }
      vals = joined;
    }
    if (vals.empty()) reject("--grid", spec, "at least one value after " + axis + "=");
    std::set<std::string> distinct(vals.begin(), vals.end());
    if (distinct.size() != vals.size()) reject("--grid", spec, "distinct values on the " + axis + " axis");
    if (axis == "levels") {
      g.levels.clear();
      for (const auto& v : vals) g.levels.push_back(parse_int("--grid levels", v, 2, 256));
    } else if (axis == "mode") {
      g.modes = vals;
    } else if (axis == "encoder") {
      g.encoders = vals;
    } else if (axis == "decoder") {
      g.decoders.clear();
      for (const auto& v : vals) g.decoders.push_back(decoder_spec_from_string(v));
    } else {
      reject("--grid", axis, "levels, mode, encoder or decoder");
    }
  }
  g.finetune_steps = std::size_t(parse_int("--finetune-steps", a.get("finetune-steps", "100"), 1, 100000000));
  g.test_data = split_list(a.get("test-data"));
  g.eval_synthetic_scenes = std::size_t(parse_int("--eval-scenes", a.get("eval-scenes"), 1, 10000));
  // An option no cell of this grid uses is refused, naming where it acts (as qdo design does for
  // its one run); one that some cells use applies to those.
  {
    const bool levels_trained = std::any_of(g.modes.begin(), g.modes.end(), [](const std::string& m) { return m == "qdo+a" || m == "qdo+m"; });
    const bool network = g.decoders.empty() ? g.base.decoder.network()
                                            : std::any_of(g.decoders.begin(), g.decoders.end(), [](const DecoderSpec& d) { return d.network(); });
    const bool finetune_net = network && std::find(g.modes.begin(), g.modes.end(), "do-finetune") != g.modes.end();
    const bool psf_target = g.base.objective == Objective::PsfTarget;
    const bool wiener = !psf_target;
    const struct {
      const char* option;
      bool used;
      const char* where;
    } rules[] = {
        {"beta", levels_trained, "a grid with mode qdo+a or qdo+m"},
        {"lr-offsets", levels_trained, "a grid with mode qdo+a or qdo+m"},
        {"lr-decoder", network, "a grid with a network decoder"},
        {"gamma", network, "a grid with a network decoder"},
        {"finetune-steps", finetune_net, "a grid with mode do-finetune and a network decoder"},
        {"target", psf_target, "--objective psf-target"},
        {"wiener-on", wiener, "the Wiener objectives"},
    };
    for (const auto& r : rules)
      if (a.has(r.option) && !r.used)
        reject(std::string("--") + r.option, a.get(r.option), std::string("an option of ") + r.where + "; no cell of this grid uses it: leave it out");
  }
  g.out = out_dir(a);
  g.quiet = false;
  Runtime rt(a.get("device"));
  const auto t0 = std::chrono::steady_clock::now();
  const auto cells = run_grid(rt, g);
  std::printf("%-7s %-9s %9s %8s %8s %8s %10s\n", "levels", "mode", "PSNR", "SSIM", "RMSE", "ERGAS", "dev [nm]");
  for (const auto& c : cells)
    std::printf("%-7s %-9s %9.2f %8.4f %8.4f %8.2f %10.2f\n",
                c.levels == 0 ? "full" : c.levels < 0 ? "n/a" : std::to_string(c.levels).c_str(), c.mode.c_str(),
                c.mean.psnr, c.mean.ssim, c.mean.rmse, c.mean.ergas, c.deviation_nm);
  std::printf("%.0f s; wrote %s/ (runs/ cells/ table1.md table1.csv table2.md table2.csv psnr_vs_levels.png)\n", seconds_since(t0),
              g.out.c_str());
  return 0;
}

}  // namespace qdo::cli
