// The tables and figures of `qdo sweep` from its finished cells: table1 (PSNR, SSIM, RMSE, ERGAS),
// table2 (quantization deviation), comparisons (the paper's comparisons as paired differences
// with 95 % intervals, sweep_stats.hpp) and the figures. With a seed axis, table1 and table2 give
// mean ± sd over seeds, and table1_seeds.csv every seed's row.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "evaluate/sweep_internal.hpp"
#include "qdo/runtime/hash.hpp"
#include "qdo/data/figure.hpp"
#include "qdo/data/io.hpp"
#include "qdo/design/run.hpp"
#include "qdo/evaluate/sweep_stats.hpp"

namespace fs = std::filesystem;

namespace qdo::sweep_detail {

namespace {

std::string levels_label(int levels) { return levels == 0 ? "full" : levels < 0 ? "n/a" : std::to_string(levels); }

std::string fmt(const char* f, double v) {
  if (!std::isfinite(v)) return "–";
  char buf[64];
  std::snprintf(buf, sizeof buf, f, v);
  return buf;
}

// The mode label's decoder part ("" or "@spec") and its base mode.
std::pair<std::string, std::string> split_label(const std::string& mode) {
  const auto at = mode.find('@');
  return at == std::string::npos ? std::make_pair(mode, std::string()) : std::make_pair(mode.substr(0, at), mode.substr(at));
}

}  // namespace

void write_grid_tables(const fs::path& out, const std::vector<GridCell>& cells, bool seed_axis) {
  // Rows: (levels, mode) in the order of first appearance (the plan's order of its first seed).
  std::vector<std::pair<int, std::string>> rows;
  std::map<std::pair<int, std::string>, std::vector<const GridCell*>> by_row;
  for (const auto& c : cells) {
    const auto key = std::make_pair(c.levels, c.mode);
    if (!by_row.count(key)) rows.push_back(key);
    by_row[key].push_back(&c);
  }
  std::ostringstream t1, t2;
  if (!seed_axis) {
    t1 << "| levels | mode | PSNR [dB] | SSIM | RMSE | ERGAS |\n|---|---|---|---|---|---|\n";
    t2 << "| levels | mode | deviation [nm] | ring deviation [nm] |\n|---|---|---|---|\n";
  } else {
    t1 << "| levels | mode | seeds | PSNR [dB] | SSIM | RMSE | ERGAS |\n|---|---|---|---|---|---|---|\n";
    t2 << "| levels | mode | seeds | deviation [nm] | ring deviation [nm] |\n|---|---|---|---|---|\n";
  }
  CsvText t1csv(seed_axis ? std::vector<std::string>{"levels", "mode", "seeds", "psnr_db", "psnr_db_sd", "ssim", "ssim_sd", "rmse", "rmse_sd",
                                                     "ergas", "ergas_sd", "psnr_h_db", "sam_rad", "inputs"}
                          : std::vector<std::string>{"levels", "mode", "psnr_db", "ssim", "rmse", "ergas", "psnr_h_db", "sam_rad", "inputs"});
  CsvText t2csv(seed_axis ? std::vector<std::string>{"levels", "mode", "seeds", "deviation_nm", "deviation_nm_sd", "deviation_rings_nm",
                                                     "deviation_rings_nm_sd", "inputs"}
                          : std::vector<std::string>{"levels", "mode", "deviation_nm", "deviation_rings_nm", "inputs"});
  CsvText seeds_csv({"seed", "levels", "mode", "psnr_db", "ssim", "rmse", "ergas", "psnr_h_db", "sam_rad", "deviation_nm", "inputs"});
  for (const auto& key : rows) {
    const auto& cs = by_row[key];
    const std::string lv = levels_label(key.first);
    const bool deviation = key.first > 0 && key.second != "fresnel";
    if (!seed_axis) {
      const GridCell& c = *cs.front();
      t1 << "| " << lv << " | " << c.mode << " | " << fmt("%.2f", c.mean.psnr) << " | " << fmt("%.4f", c.mean.ssim) << " | "
         << fmt("%.4f", c.mean.rmse) << " | " << fmt("%.2f", c.mean.ergas) << " |\n";
      t1csv.row({lv, c.mode, csv_number(c.mean.psnr), csv_number(c.mean.ssim), csv_number(c.mean.rmse), csv_number(c.mean.ergas),
                 csv_number(c.mean.psnr_hyper), csv_number(c.mean.sam_rad), c.inputs});
      if (deviation) {
        t2 << "| " << c.levels << " | " << c.mode << " | " << fmt("%.3f", c.deviation_nm) << " | "
           << (std::isfinite(c.deviation_rings_nm) ? fmt("%.3f", c.deviation_rings_nm) : std::string("–")) << " |\n";
        t2csv.row({std::to_string(c.levels), c.mode, csv_number(c.deviation_nm), csv_number(c.deviation_rings_nm), c.inputs});
      }
      continue;
    }
    std::vector<double> psnr, ssim, rmse, ergas, psnr_h, sam, dev, dev_rings;
    Fnv1a64 h;  // the row's inputs: its cells' inputs, in seed order
    for (const GridCell* c : cs) {
      psnr.push_back(c->mean.psnr);
      ssim.push_back(c->mean.ssim);
      rmse.push_back(c->mean.rmse);
      ergas.push_back(c->mean.ergas);
      psnr_h.push_back(c->mean.psnr_hyper);
      sam.push_back(c->mean.sam_rad);
      dev.push_back(c->deviation_nm);
      dev_rings.push_back(c->deviation_rings_nm);
      h.add(c->inputs);
      seeds_csv.row({std::to_string(c->seed), lv, c->mode, csv_number(c->mean.psnr), csv_number(c->mean.ssim), csv_number(c->mean.rmse),
                     csv_number(c->mean.ergas), csv_number(c->mean.psnr_hyper), csv_number(c->mean.sam_rad), csv_number(c->deviation_nm),
                     c->inputs});
    }
    const MeanInterval P = mean_interval(psnr), S = mean_interval(ssim), R = mean_interval(rmse), E = mean_interval(ergas),
                       D = mean_interval(dev);
    const std::string n = std::to_string(cs.size());
    auto pm = [](const MeanInterval& m, const char* f) { return fmt(f, m.mean) + " ± " + fmt(f, m.sd); };
    t1 << "| " << lv << " | " << key.second << " | " << n << " | " << pm(P, "%.2f") << " | " << pm(S, "%.4f") << " | " << pm(R, "%.4f")
       << " | " << pm(E, "%.2f") << " |\n";
    t1csv.row({lv, key.second, n, csv_number(P.mean), csv_number(P.sd), csv_number(S.mean), csv_number(S.sd), csv_number(R.mean),
               csv_number(R.sd), csv_number(E.mean), csv_number(E.sd), csv_number(mean_interval(psnr_h).mean),
               csv_number(mean_interval(sam).mean), h.hex()});
    if (deviation) {
      const bool rings = std::all_of(dev_rings.begin(), dev_rings.end(), [](double v) { return std::isfinite(v); });
      MeanInterval DR;
      DR.mean = DR.sd = NAN;
      if (rings) DR = mean_interval(dev_rings);
      t2 << "| " << key.first << " | " << key.second << " | " << n << " | " << pm(D, "%.3f") << " | "
         << (rings ? pm(DR, "%.3f") : std::string("–")) << " |\n";
      t2csv.row({std::to_string(key.first), key.second, n, csv_number(D.mean), csv_number(D.sd), csv_number(DR.mean), csv_number(DR.sd),
                 h.hex()});
    }
  }
  if (seed_axis) t1 << "\nmean ± sample standard deviation over seeds (each seed's value: its cell's mean over the test scenes)\n";
  write_text_atomic((out / "table1.md").string(), t1.str());
  write_text_atomic((out / "table1.csv").string(), t1csv.str());
  write_text_atomic((out / "table2.md").string(), t2.str());
  write_text_atomic((out / "table2.csv").string(), t2csv.str());
  if (seed_axis) write_text_atomic((out / "table1_seeds.csv").string(), seeds_csv.str());

  // The paper's comparisons per decoder: QDO+A - DO, QDO+A - DO-finetune (the Wiener decoder's
  // do-refit where the grid has no do-finetune), QDO - DO; paired by seed and test scene.
  std::vector<SceneScore> scores;
  std::vector<std::string> modes;
  for (const auto& c : cells) {
    if (std::find(modes.begin(), modes.end(), c.mode) == modes.end()) modes.push_back(c.mode);
    for (const auto& r : c.scenes) scores.push_back({c.mode, c.levels, c.seed, r.scene, r.psnr, r.ssim});
  }
  auto has = [&](const std::string& m) { return std::find(modes.begin(), modes.end(), m) != modes.end(); };
  std::vector<std::pair<std::string, std::string>> comparisons;
  for (const auto& m : modes) {
    const auto [base, dec] = split_label(m);
    if (base != "qdo+a" && base != "qdo") continue;
    if (base == "qdo+a") {
      if (has("do" + dec)) comparisons.push_back({m, "do" + dec});
      if (has("do-finetune" + dec)) comparisons.push_back({m, "do-finetune" + dec});
      else if (has("do-refit" + dec)) comparisons.push_back({m, "do-refit" + dec});
    } else if (has("do" + dec)) {
      comparisons.push_back({m, "do" + dec});
    }
  }
  // qdo+a's comparisons first, then qdo's.
  std::stable_sort(comparisons.begin(), comparisons.end(),
                   [](const auto& x, const auto& y) { return (split_label(x.first).first == "qdo+a") > (split_label(y.first).first == "qdo+a"); });
  const std::vector<PairedDifference> diffs = paired_differences(scores, comparisons);
  std::ostringstream cm;
  cm << "| levels | comparison | seeds | pairs | ΔPSNR [dB] | 95 % interval (seed, scene pairs) | 95 % interval (over seeds) | ΔSSIM | 95 % interval |\n"
        "|---|---|---|---|---|---|---|---|---|\n";
  CsvText cmcsv({"levels", "a", "b", "seeds", "pairs", "dpsnr_db", "dpsnr_db_lo", "dpsnr_db_hi", "dpsnr_db_seeds_lo", "dpsnr_db_seeds_hi",
                 "dssim", "dssim_lo", "dssim_hi"});
  auto ci = [](const MeanInterval& m, const char* f) {
    return std::isfinite(m.half_width) ? "[" + fmt(f, m.lo()) + ", " + fmt(f, m.hi()) + "]" : std::string("–");
  };
  for (const auto& d : diffs) {
    cm << "| " << levels_label(d.levels) << " | " << d.a << " − " << d.b << " | " << d.seeds << " | " << d.psnr_db.n << " | "
       << fmt("%+.2f", d.psnr_db.mean) << " | " << ci(d.psnr_db, "%+.2f") << " | " << ci(d.psnr_db_seeds, "%+.2f") << " | "
       << fmt("%+.4f", d.ssim.mean) << " | " << ci(d.ssim, "%+.4f") << " |\n";
    cmcsv.row({levels_label(d.levels), d.a, d.b, std::to_string(d.seeds), std::to_string(d.psnr_db.n), csv_number(d.psnr_db.mean),
               csv_number(d.psnr_db.lo()), csv_number(d.psnr_db.hi()), csv_number(d.psnr_db_seeds.lo()), csv_number(d.psnr_db_seeds.hi()),
               csv_number(d.ssim.mean), csv_number(d.ssim.lo()), csv_number(d.ssim.hi())});
  }
  cm << "\nDifferences a − b paired by seed and test scene (PSNR and SSIM of each scene, as `qdo eval`'s per_scene rows); "
        "95 % Student t intervals over the (seed, scene) pairs, and over the seeds' mean differences (seeds − 1 degrees of "
        "freedom: the one to read when the scenes of a seed are correlated). differences.svg draws them with their labels "
        "and axis (differences.png the same without text, top to bottom in this order: dot the mean, thick bar the pair interval, "
        "thin grey bar the seed interval, grey line 0 dB).\n";
  write_text_atomic((out / "comparisons.md").string(), cm.str());
  write_text_atomic((out / "comparisons.csv").string(), cmcsv.str());
  if (!diffs.empty()) write_difference_figure((out / "differences.png").string(), diffs);

  // PSNR against levels, one series per mode: the mean over seeds and its 95 % interval.
  LinePlot lp;
  lp.title = "Test PSNR against the number of levels, mean and 95 % interval over seeds";
  lp.x_label = "height levels L";
  lp.y_label = "PSNR (dB)";
  lp.log_x = true;
  for (const auto& [L, m] : rows) {
    if (L <= 0) continue;
    const auto it = by_row.find({L, m});
    if (it == by_row.end()) continue;
    std::vector<double> v;
    for (const GridCell* c : it->second) v.push_back(c->mean.psnr);
    const MeanInterval mi = mean_interval(v);
    const std::string mode = m;  // a structured binding cannot be captured (C++17)
    auto s = std::find_if(lp.series.begin(), lp.series.end(), [&](const PlotSeries& p) { return p.label == mode; });
    if (s == lp.series.end()) {
      lp.series.push_back(PlotSeries{m, {}, {}, {}, {}, false});
      s = lp.series.end() - 1;
    }
    s->x.push_back(double(L));
    s->y.push_back(mi.mean);
    s->y_low.push_back(mi.n > 1 ? mi.lo() : mi.mean);
    s->y_high.push_back(mi.n > 1 ? mi.hi() : mi.mean);
  }
  for (PlotSeries& ps : lp.series) ps.points_only = ps.x.size() == 1;
  if (!lp.series.empty()) write_line_plot((out / "psnr_vs_levels.png").string(), lp);
}

}  // namespace qdo::sweep_detail
