// `qdo sweep-psf` (sweep.hpp): PSF quality against the number of levels for one design, every
// variant's PSF stack computed in batched device passes.
#include "qdo/evaluate/sweep.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <functional>
#include <sstream>

#include "qdo/runtime/error.hpp"
#include "qdo/data/figure.hpp"
#include "qdo/data/io.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/design/run.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/physics/simulator.hpp"

namespace fs = std::filesystem;

namespace qdo {

double encircled_energy_radius(const RealStack& psf, std::size_t plane, double fraction, double pitch_m) {
  const std::size_t s = psf.rows;
  std::vector<std::pair<double, double>> rv;  // (radius in pixels, energy)
  double total = 0;
  for (std::size_t y = 0; y < s; ++y)
    for (std::size_t x = 0; x < psf.cols; ++x) {
      const double dy = double(y) - double(s / 2), dx = double(x) - double(psf.cols / 2);
      rv.push_back({std::sqrt(dy * dy + dx * dx), psf(plane, y, x)});
      total += psf(plane, y, x);
    }
  if (!(total > 0)) return 0;
  std::sort(rv.begin(), rv.end());
  double acc = 0, prev_r = 0, prev_acc = 0;
  for (const auto& [r, e] : rv) {
    acc += e / total;
    if (acc >= fraction) {
      const double t = acc > prev_acc ? (fraction - prev_acc) / (acc - prev_acc) : 1.0;
      return (prev_r + t * (r - prev_r)) * pitch_m;
    }
    prev_r = r;
    prev_acc = acc;
  }
  return rv.back().first * pitch_m;
}

std::vector<PsfSweepRow> sweep_psf(Runtime& rt, const PsfSweepOptions& o) {
  o.cfg.validate();
  if (o.design_full_m.rows != o.cfg.n || o.design_full_m.cols != o.cfg.n)
    reject("design", to_str(o.design_full_m.rows) + " x " + to_str(o.design_full_m.cols), "N x N = " + to_str(o.cfg.n));
  for (const auto& v : o.variants) v.quantizer.validate();
  const double hmax = o.cfg.h_max_m();
  // Height maps: the reference first, then every variant.
  std::vector<Map2D> maps{o.design_full_m};
  std::vector<std::string> labels{"full"};
  std::vector<int> levels{0};
  for (const auto& v : o.variants) {
    maps.push_back(quantize_heights(o.design_full_m, hmax, v.quantizer));
    labels.push_back(v.label);
    levels.push_back(v.quantizer.levels);
  }
  // How many designs fit one pass: the field buffer (designs x bands x M x M complex).
  const auto g = PropagationGeometry::from_config(o.cfg);
  const std::size_t per_design = o.cfg.bands * g.m * g.m * 2 * real_size(o.precision);
  std::size_t per_pass = o.max_designs_per_pass;
  if (per_pass == 0) per_pass = std::max<std::size_t>(1, rt.info().max_alloc_bytes / per_design);
  per_pass = std::min(per_pass, maps.size());
  const std::size_t bands = o.cfg.bands;
  std::vector<RealStack> psfs(maps.size());
  std::vector<std::vector<double>> outside(maps.size());
  for (std::size_t first = 0; first < maps.size(); first += per_pass) {
    const std::size_t count = std::min(per_pass, maps.size() - first);
    Simulator sim(rt, o.cfg, o.precision, count);
    sim.set_heights_batch(std::vector<Map2D>(maps.begin() + long(first), maps.begin() + long(first + count)));
    sim.compute_psf();
    const RealStack all = sim.psf_sensor();
    for (std::size_t d = 0; d < count; ++d) {
      RealStack p(bands, all.rows, all.cols);
      std::copy(all.plane(d * bands), all.plane(d * bands) + p.size(), p.data.begin());
      psfs[first + d] = std::move(p);
      for (std::size_t b = 0; b < bands; ++b) outside[first + d].push_back(sim.sampling().bands[d * bands + b].energy_outside_window);
    }
  }
  std::vector<PsfSweepRow> rows;
  const RealStack& ref = psfs[0];
  for (std::size_t k = 0; k < maps.size(); ++k) {
    PsfSweepRow r;
    r.label = labels[k];
    r.levels = levels[k];
    r.deviation_nm = quantization_deviation_m(maps[k], maps[0]) * 1e9;
    r.energy_outside = outside[k];
    for (std::size_t b = 0; b < bands; ++b) {
      double num = 0, den = 0, pk = 0, pk0 = 0;
      for (std::size_t i = 0; i < ref.plane_size(); ++i) {
        const double a = psfs[k].plane(b)[i], c = ref.plane(b)[i];
        num += (a - c) * (a - c);
        den += c * c;
        pk = std::max(pk, a);
        pk0 = std::max(pk0, c);
      }
      r.rel_l2.push_back(den > 0 ? std::sqrt(num / den) : 0.0);
      r.peak_ratio.push_back(pk0 > 0 ? pk / pk0 : 0.0);
      r.ee80_um.push_back(encircled_energy_radius(psfs[k], b, 0.8, o.cfg.sensor_pitch_m) * 1e6);
    }
    rows.push_back(r);
  }
  if (!o.out.empty()) {
    fs::create_directories(o.out);
    const auto wl = o.cfg.wavelengths_nm();
    CsvText csv({"variant", "levels", "deviation_nm", "wavelength_nm", "rel_l2", "peak_ratio", "ee80_um", "energy_outside_window"});
    nlohmann::json j = nlohmann::json::array();
    std::vector<H5Dataset> h5;
    auto mean = [](const std::vector<double>& v) {
      double s = 0;
      for (double x : v) s += x;
      return v.empty() ? 0.0 : s / double(v.size());
    };
    for (std::size_t k = 0; k < rows.size(); ++k) {
      const auto& r = rows[k];
      for (std::size_t b = 0; b < bands; ++b)
        csv.row({r.label, std::to_string(r.levels), csv_number(r.deviation_nm, 8), csv_number(wl[b], 8), csv_number(r.rel_l2[b], 8),
                 csv_number(r.peak_ratio[b], 8), csv_number(r.ee80_um[b], 8), csv_number(r.energy_outside[b], 8)});
      j.push_back({{"variant", r.label},
                   {"levels", r.levels},
                   {"deviation_nm", r.deviation_nm},
                   {"mean_rel_l2", mean(r.rel_l2)},
                   {"mean_peak_ratio", mean(r.peak_ratio)},
                   {"mean_ee80_um", mean(r.ee80_um)},
                   {"rel_l2", r.rel_l2},
                   {"peak_ratio", r.peak_ratio},
                   {"ee80_um", r.ee80_um},
                   {"energy_outside_window", r.energy_outside}});
      h5.push_back({"/psf_" + r.label, {bands, psfs[k].rows, psfs[k].cols}, psfs[k].data, {{"pitch_m", o.cfg.sensor_pitch_m}}, {}});
      write_psf_figure((fs::path(o.out) / ("psf_" + r.label + ".png")).string(),
                       "PSF stack, " + (r.levels ? r.label + " (" + to_str(r.levels) + " levels)" : std::string("full precision")),
                       psfs[k], wl, o.cfg.sensor_pitch_m, std::min<std::size_t>(psfs[k].rows, 96));
    }
    h5.push_back({"/wavelengths_nm", {bands}, wl, {}, {{"units", "nm"}}});
    h5_write((fs::path(o.out) / "psf.h5").string(), h5, {{"config", config_to_json_text(o.cfg)}});
    write_text_atomic((fs::path(o.out) / "sweep.csv").string(), csv.str());
    write_text_atomic((fs::path(o.out) / "sweep.json").string(), j.dump(2) + "\n");
    // Each metric (mean over bands) against the number of levels: one series per kind of variant
    // (its label without the leading "L<levels>"), the full-precision reference as a dashed line.
    auto metric_plot = [&](const std::string& file, const std::string& what, const std::string& y_label,
                           const std::function<double(const PsfSweepRow&)>& value, bool reference_line) {
      LinePlot lp;
      lp.title = what + " against the number of levels (mean over " + to_str(bands) + " bands)";
      lp.x_label = "height levels L";
      lp.y_label = y_label;
      lp.log_x = true;
      for (std::size_t k = 1; k < rows.size(); ++k) {
        std::string kind = rows[k].label;
        const std::string prefix = "L" + to_str(rows[k].levels);
        if (kind.rfind(prefix, 0) == 0) kind = kind.substr(prefix.size());
        while (!kind.empty() && (kind[0] == '_' || kind[0] == '-')) kind.erase(0, 1);
        if (kind.empty()) kind = "uniform";
        auto it = std::find_if(lp.series.begin(), lp.series.end(), [&](const PlotSeries& ps) { return ps.label == kind; });
        if (it == lp.series.end()) {
          lp.series.push_back(PlotSeries{kind, {}, {}, {}, {}, false});
          it = lp.series.end() - 1;
        }
        it->x.push_back(double(rows[k].levels));
        it->y.push_back(value(rows[k]));
      }
      for (PlotSeries& ps : lp.series) ps.points_only = ps.x.size() == 1;
      if (reference_line) lp.hlines.push_back(value(rows.front()));
      if (!lp.series.empty()) write_line_plot((fs::path(o.out) / file).string(), lp);
    };
    metric_plot("rel_l2_vs_variant.png", "PSF error ||P_L - P_full|| / ||P_full||", "relative L2 error",
                [&](const PsfSweepRow& r) { return mean(r.rel_l2); }, false);
    metric_plot("peak_ratio_vs_variant.png", "PSF peak against full precision (dashed)", "peak / full-precision peak",
                [&](const PsfSweepRow& r) { return mean(r.peak_ratio); }, true);
    metric_plot("ee80_vs_variant.png", "80 % encircled-energy radius (full precision dashed)", "radius (µm)",
                [&](const PsfSweepRow& r) { return mean(r.ee80_um); }, true);
  }
  return rows;
}

PsfSweepVariant adaptive_psf_sweep_variant(const std::string& run, const std::string& argument) {
  const DesignRunOptions ro = read_run_config(run);
  if (ro.design.mode != DesignMode::QDOA) reject(argument, run, "a qdo+a run (it is " + to_string(ro.design.mode) + ")");
  const std::size_t L = std::size_t(ro.design.quantizer.levels);
  const DesignState st = load_checkpoint(RunFolder(run).checkpoint_path(), parameter_count(ro.design.parameterization, ro.cfg.n), L,
                                         false, ro.design.quantizer.pin_top);
  PsfSweepVariant v;
  v.quantizer = ro.design.quantizer;
  v.quantizer.offsets = st.offsets;
  v.label = "L" + std::to_string(L) + "-adaptive";
  return v;
}

}  // namespace qdo
