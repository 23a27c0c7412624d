// Fabrication errors: perturbation of a design's heights by mask-wise etch-depth errors, overlay,
// edge blur and height noise (perturbed_heights), and the Monte Carlo tolerance analysis of a
// design run (tolerance_analysis: metrics as qdo eval, tolerance.csv/json/md and figures).
// API and conventions: include/qdo/fab/fab.hpp.
#include "qdo/design/run_folder.hpp"
#include "qdo/fab/fab.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <memory>
#include <sstream>

#include "qdo/design/design_run.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/figure.hpp"
#include "qdo/data/io.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/decode/testset.hpp"
#include "qdo/decode/wiener.hpp"
#include "fab/fab_internal.hpp"

namespace fs = std::filesystem;
using nlohmann::json;

namespace qdo::fab {

namespace {

// 1-D box-cell shift of rows (axis 1) or columns (axis 0) of a size x size map by s cells
// (continuous): out(x) = (1 - f) in(x - q) + f in(x - q - 1), q = floor(s), f = s - q; zero outside.
std::vector<double> shift_axis(const std::vector<double>& in, std::size_t size, double s, int axis) {
  if (s == 0.0) return in;
  const double qf = std::floor(s), f = s - qf;
  const long q = long(qf);
  std::vector<double> out(in.size(), 0.0);
  for (std::size_t a = 0; a < size; ++a)
    for (std::size_t b = 0; b < size; ++b) {
      const long src0 = long(b) - q, src1 = src0 - 1;
      double v = 0;
      auto at = [&](long k) {
        if (k < 0 || k >= long(size)) return 0.0;
        return axis == 1 ? in[a * size + std::size_t(k)] : in[std::size_t(k) * size + a];
      };
      v = (1.0 - f) * at(src0) + f * at(src1);
      if (axis == 1) out[a * size + b] = v;
      else out[b * size + a] = v;
    }
  return out;
}

std::vector<double> gaussian_blur(const std::vector<double>& in, std::size_t size, double sigma_cells) {
  if (!(sigma_cells > 0)) return in;
  const long r = long(std::ceil(3.0 * sigma_cells));
  std::vector<double> k(std::size_t(2 * r + 1));
  double sum = 0;
  for (long t = -r; t <= r; ++t) sum += k[std::size_t(t + r)] = std::exp(-0.5 * double(t * t) / (sigma_cells * sigma_cells));
  for (double& v : k) v /= sum;
  std::vector<double> tmp(in.size(), 0.0), out(in.size(), 0.0);
  const long S = long(size);
  for (long y = 0; y < S; ++y)
    for (long x = 0; x < S; ++x) {
      double v = 0;
      for (long t = -r; t <= r; ++t)
        if (x - t >= 0 && x - t < S) v += k[std::size_t(t + r)] * in[std::size_t(y * S + x - t)];
      tmp[std::size_t(y * S + x)] = v;
    }
  for (long y = 0; y < S; ++y)
    for (long x = 0; x < S; ++x) {
      double v = 0;
      for (long t = -r; t <= r; ++t)
        if (y - t >= 0 && y - t < S) v += k[std::size_t(t + r)] * tmp[std::size_t((y - t) * S + x)];
      out[std::size_t(y * S + x)] = v;
    }
  return out;
}

}  // namespace

Map2D perturbed_heights(const MaskPlan& plan, const Map2D& design_height_m, const Perturbation& pt, std::size_t oversample) {
  const std::size_t n = plan.n, K = plan.masks.size();
  if (design_height_m.rows != n || design_height_m.cols != n) reject("design heights", design_height_m.rows, "the plan's N = " + to_str(n));
  if (oversample < 1 || oversample > 16) reject("oversample", oversample, "in [1, 16]");
  for (const auto* v : {&pt.depth_error_m, &pt.shift_x_m, &pt.shift_y_m})
    if (!v->empty() && v->size() != K) reject("perturbation size", v->size(), "one value per mask (" + to_str(K) + ") or none");
  if (pt.edge_blur_m < 0 || pt.height_noise_m < 0) reject("edge blur / height noise", "< 0", ">= 0");
  auto get = [](const std::vector<double>& v, std::size_t m) { return v.empty() ? 0.0 : v[m]; };
  Map2D h = design_height_m;
  const std::size_t F = oversample, M = n * F;
  const double fine_pitch = plan.pitch_m / double(F);
  std::vector<double> de(n * n, 0.0);  // change of the etch depth, area-averaged per DOE pixel
  bool changed = false;
  for (std::size_t m = 0; m < K; ++m) {
    const Mask& mk = plan.masks[m];
    const double eps = get(pt.depth_error_m, m), sx = get(pt.shift_x_m, m), sy = get(pt.shift_y_m, m);
    const bool geometric = sx != 0.0 || sy != 0.0 || pt.edge_blur_m > 0;
    if (!geometric && eps == 0.0) continue;
    changed = true;
    if (!geometric) {  // depth error alone: the open region gets eps more etch
      for (std::size_t i = 0; i < n * n; ++i)
        if (mk.drawn[i]) de[i] += eps;
      continue;
    }
    // The open region on the fine grid, shifted and blurred (area fractions), then area-averaged.
    std::vector<double> fine(M * M, 0.0);
    for (std::size_t y = 0; y < M; ++y)
      for (std::size_t x = 0; x < M; ++x) fine[y * M + x] = mk.drawn[(y / F) * n + x / F] ? 1.0 : 0.0;
    fine = shift_axis(fine, M, sx / fine_pitch, 1);
    fine = shift_axis(fine, M, sy / fine_pitch, 0);
    fine = gaussian_blur(fine, M, pt.edge_blur_m / fine_pitch);
    const double inv = 1.0 / double(F * F), depth = mk.etch_depth_m + eps;
    for (std::size_t i = 0; i < n; ++i)
      for (std::size_t j = 0; j < n; ++j) {
        double a = 0;
        for (std::size_t u = 0; u < F; ++u)
          for (std::size_t v = 0; v < F; ++v) a += fine[(i * F + u) * M + j * F + v];
        a *= inv;
        de[i * n + j] += depth * a - mk.etch_depth_m * (mk.drawn[i * n + j] ? 1.0 : 0.0);
      }
  }
  if (changed)
    for (std::size_t i = 0; i < n * n; ++i) h.data[i] -= de[i];
  if (pt.height_noise_m > 0)
    for (std::size_t i = 0; i < n * n; ++i) h.data[i] += pt.height_noise_m * sym_uniform(pt.noise_seed, 7, i);
  const double lo = *std::min_element(h.data.begin(), h.data.end());
  if (lo < 0)
    for (double& v : h.data) v -= lo;  // a constant height: a constant phase, the PSF is unchanged
  const double cap = 2.0 * plan.h_max_m;
  for (double& v : h.data) v = std::min(v, cap);
  return h;
}

namespace {

// The reconstruction pipeline of qdo eval (src/evaluate/eval.cpp), step for step, so the metrics agree
// exactly: the same test patches, noise draws, Wiener decoder and averaging order.
class Evaluator {
 public:
  Evaluator(Runtime& rt, const DesignRunOptions& o, const ToleranceOptions& t, const std::string& run)
      : o_(o), sim_(rt, o.cfg, t.precision), camera_(rt, o.cfg) {
    const SystemConfig& cfg = o.cfg;
    s_ = cfg.sensor_size_px();
    prior_ = RunFolder(run).prior(s_);
    sigma_ = t.noise_sigma >= 0 ? t.noise_sigma : o.decoder_noise_sigma;
    srf_ = sensor_response(cfg);
    patches_ = testset::patches(cfg, s_, t.data, t.data_format, t.synthetic_scenes, o.design.seed);
  }
  RealStack psf(const Map2D& h) {
    sim_.set_heights(h);
    sim_.compute_psf();
    return sim_.psf_sensor();
  }
  std::unique_ptr<WienerDecoder> decoder(const RealStack& psf) const {
    return std::make_unique<WienerDecoder>(wiener::psf_to_otf(psf, s_, s_), srf_, prior_, sigma_);
  }
  Metrics metrics(const RealStack& psf_actual, const WienerDecoder& dec) {
    return testset::evaluate(camera_, psf_actual, patches_, dec, sigma_, o_.design.seed).mean;
  }
  std::size_t patches() const { return patches_.size(); }
  double sigma() const { return sigma_; }

 private:
  const DesignRunOptions& o_;
  Simulator sim_;
  testset::PatchCamera camera_;
  std::size_t s_ = 0;
  wiener::SpectralPrior prior_;
  double sigma_ = 0;
  Eigen::MatrixXd srf_;
  std::vector<testset::Patch> patches_;
};

const char* kMetricNames[6] = {"psnr_db", "psnr_h_db", "ssim", "rmse", "ergas", "sam_rad"};
double metric(const Metrics& m, int k) {
  switch (k) {
    case 0: return m.psnr;
    case 1: return m.psnr_hyper;
    case 2: return m.ssim;
    case 3: return m.rmse;
    case 4: return m.ergas;
    default: return m.sam_rad;
  }
}
bool higher_is_better(int k) { return k <= 2; }

Stat stat_of(const std::vector<double>& v) {
  Stat s;
  if (v.empty()) return s;
  s.min = *std::min_element(v.begin(), v.end());
  s.max = *std::max_element(v.begin(), v.end());
  for (double x : v) s.mean += x / double(v.size());
  if (v.size() > 1) {
    double q = 0;
    for (double x : v) q += (x - s.mean) * (x - s.mean);
    s.std = std::sqrt(q / double(v.size() - 1));
  }
  return s;
}

std::string fixed(double v, int digits) {
  char b[64];
  std::snprintf(b, sizeof b, "%.*f", digits, v);
  return b;
}

// PSNR per trial for every scenario (x = 1, 2, ... in the summary's order): every trial as a
// point, the calibrated decoder left of the scenario's x and the nominal decoder right of it,
// the mean with its [min, max] as error bars, and the nominal design's PSNR dashed.
void write_strip_chart(const std::string& path, const std::string& run, const ToleranceResult& r) {
  LinePlot lp;
  lp.title = "PSNR under fabrication errors: " + run;
  lp.y_label = "PSNR (dB)";
  lp.x_label = "scenario:";
  lp.hlines = {r.nominal.psnr};
  PlotSeries cal{"calibrated decoder, each trial", {}, {}, {}, {}, true}, nom{"nominal decoder, each trial", {}, {}, {}, {}, true};
  PlotSeries cal_m{"calibrated decoder, mean [min, max]", {}, {}, {}, {}, true}, nom_m{"nominal decoder, mean [min, max]", {}, {}, {}, {}, true};
  for (std::size_t k = 0; k < r.summary.size(); ++k) {
    const double x = double(k + 1);
    lp.x_label += " " + to_str(k + 1) + " " + r.summary[k].scenario;
    for (const auto& t : r.trials) {
      if (t.scenario != r.summary[k].scenario) continue;
      cal.x.push_back(x - 0.2);
      cal.y.push_back(t.calibrated.psnr);
      nom.x.push_back(x + 0.2);
      nom.y.push_back(t.nominal_decoder.psnr);
    }
    const Stat& c = r.summary[k].calibrated.at("psnr_db");
    const Stat& n = r.summary[k].nominal_decoder.at("psnr_db");
    cal_m.x.push_back(x - 0.1);
    cal_m.y.push_back(c.mean);
    cal_m.y_low.push_back(c.min);
    cal_m.y_high.push_back(c.max);
    nom_m.x.push_back(x + 0.1);
    nom_m.y.push_back(n.mean);
    nom_m.y_low.push_back(n.min);
    nom_m.y_high.push_back(n.max);
  }
  lp.title += " (dashed: the nominal design)";
  for (const PlotSeries* ps : {&cal, &nom, &cal_m, &nom_m})
    if (!ps->x.empty()) lp.series.push_back(*ps);
  if (!lp.series.empty()) write_line_plot(path, lp);
}

}  // namespace

ToleranceResult tolerance_analysis(Runtime& rt, const ToleranceOptions& t) {
  const RunFolder folder(t.run);
  if (!fs::is_regular_file(folder.config_path())) reject("run", t.run, "a run folder written by qdo design (config.json missing)");
  for (const auto& [name, v] : {std::pair<const char*, double>{"etch_depth_error", t.etch_depth_error_m}, {"overlay", t.overlay_m},
                                {"edge_blur", t.edge_blur_m}, {"height_noise", t.height_noise_m}})
    if (!(v >= 0) || !std::isfinite(v)) reject(name, v, "finite and >= 0");
  if (t.trials < 1 || t.trials > 100000) reject("trials", t.trials, "in [1, 100000]");
  if (t.oversample < 1 || t.oversample > 16) reject("oversample", t.oversample, "in [1, 16]");
  const DesignRunOptions o = folder.config();
  const Design fab = folder.design();
  if (fab.height_m.rows != o.cfg.n) reject("run", t.run, "design.h5 on the configuration's N x N grid");
  Constraints c;
  c.min_feature_um = 0;                       // analyse whatever the design is,
  c.max_height_nm = 2 * o.cfg.h_max_m() * 1e9;  // up to the simulator's height range
  ToleranceResult res;
  std::string scheme_note;
  res.plan = plan_masks_named(fab, o.cfg, t.scheme, c, scheme_note);
  const MaskPlan& plan = res.plan;
  const std::size_t K = plan.masks.size();
  const bool single_write = plan.scheme == Scheme::Greyscale;  // one exposure: no overlay between layers

  Evaluator ev(rt, o, t, t.run);
  const RealStack psf0 = ev.psf(fab.height_m);
  const auto dec0 = ev.decoder(psf0);
  res.nominal = ev.metrics(psf0, *dec0);
  double psf0_norm = 0;
  for (double v : psf0.data) psf0_norm += v * v;
  psf0_norm = std::sqrt(psf0_norm);

  struct Scenario {
    std::string name;
    bool depth, overlay, blur, noise;
  };
  std::vector<Scenario> scenarios = {{"all", true, true, true, true}};
  const bool active[4] = {t.etch_depth_error_m > 0, t.overlay_m > 0 && !single_write && K > 1, t.edge_blur_m > 0, t.height_noise_m > 0};
  const int n_active = int(active[0]) + int(active[1]) + int(active[2]) + int(active[3]);
  if (t.per_source && n_active > 1) {
    if (active[0]) scenarios.push_back({"etch depth", true, false, false, false});
    if (active[1]) scenarios.push_back({"overlay", false, true, false, false});
    if (active[2]) scenarios.push_back({"edge blur", false, false, true, false});
    if (active[3]) scenarios.push_back({"height noise", false, false, false, true});
  }
  Map2D worst_dh;
  RealStack worst_psf;
  std::vector<H5Dataset> psf_sets;
  if (t.save_psfs && !t.out.empty())
    psf_sets.push_back({"/psf_nominal", {psf0.planes, psf0.rows, psf0.cols}, psf0.data, {{"pitch_m", o.cfg.sensor_pitch_m}}, {}});
  double worst_psnr = std::numeric_limits<double>::infinity();
  const std::size_t total = scenarios.size() * t.trials;
  std::size_t done = 0;
  for (std::size_t k = 0; k < t.trials; ++k) {
    // Draws of trial k (independent of the scenario).
    std::vector<double> dep, sx, sy;
    draw_trial_errors(t.seed, k, plan, t.etch_depth_error_m, t.overlay_m, dep, sx, sy);
    const std::uint64_t noise_seed = splitmix64(t.seed ^ splitmix64(k + 0x51ED));
    for (const auto& sc : scenarios) {
      Perturbation pt;
      pt.depth_error_m = sc.depth ? dep : std::vector<double>(K, 0.0);
      pt.shift_x_m = sc.overlay ? sx : std::vector<double>(K, 0.0);
      pt.shift_y_m = sc.overlay ? sy : std::vector<double>(K, 0.0);
      pt.edge_blur_m = sc.blur ? t.edge_blur_m : 0.0;
      pt.height_noise_m = sc.noise ? t.height_noise_m : 0.0;
      pt.noise_seed = noise_seed;
      const Map2D h = perturbed_heights(plan, fab.height_m, pt, t.oversample);
      Trial tr;
      tr.scenario = sc.name;
      tr.index = k;
      tr.depth_error_m = pt.depth_error_m;
      tr.shift_x_m = pt.shift_x_m;
      tr.shift_y_m = pt.shift_y_m;
      // RMS of the height change, after removing the constant offset (a constant only adds a phase).
      double mean_d = 0;
      for (std::size_t i = 0; i < h.data.size(); ++i) mean_d += (h.data[i] - fab.height_m.data[i]) / double(h.data.size());
      double q = 0;
      for (std::size_t i = 0; i < h.data.size(); ++i) {
        const double dd = h.data[i] - fab.height_m.data[i] - mean_d;
        q += dd * dd / double(h.data.size());
      }
      tr.height_rms_change_m = std::sqrt(q);
      const RealStack psf = ev.psf(h);
      double dn = 0;
      for (std::size_t i = 0; i < psf.data.size(); ++i) dn += (psf.data[i] - psf0.data[i]) * (psf.data[i] - psf0.data[i]);
      tr.psf_rel_change = std::sqrt(dn) / psf0_norm;
      tr.calibrated = ev.metrics(psf, *ev.decoder(psf));
      tr.nominal_decoder = ev.metrics(psf, *dec0);
      if (sc.name == "all" && tr.calibrated.psnr < worst_psnr) {
        worst_psnr = tr.calibrated.psnr;
        worst_dh = Map2D(h.rows, h.cols);
        for (std::size_t i = 0; i < h.data.size(); ++i) worst_dh.data[i] = (h.data[i] - fab.height_m.data[i] - mean_d) * 1e9;
        worst_psf = psf;
      }
      if (t.save_psfs && !t.out.empty()) {
        std::string tag = sc.name;
        for (char& ch : tag)
          if (ch == ' ') ch = '_';
        psf_sets.push_back({"/psf_" + tag + "_" + std::to_string(k), {psf.planes, psf.rows, psf.cols}, psf.data, {}, {}});
      }
      res.trials.push_back(tr);
      ++done;
      if (!t.quiet)
        std::fprintf(stderr, "[tolerance] %zu/%zu  %-12s trial %zu  PSNR %.2f dB (nominal decoder %.2f dB)\n", done, total,
                     sc.name.c_str(), k, tr.calibrated.psnr, tr.nominal_decoder.psnr);
    }
  }
  for (const auto& sc : scenarios) {
    ScenarioSummary s;
    s.scenario = sc.name;
    for (int mi = 0; mi < 6; ++mi) {
      std::vector<double> a, b;
      for (const auto& tr : res.trials)
        if (tr.scenario == sc.name) {
          a.push_back(metric(tr.calibrated, mi));
          b.push_back(metric(tr.nominal_decoder, mi));
        }
      s.trials = a.size();
      s.calibrated[kMetricNames[mi]] = stat_of(a);
      s.nominal_decoder[kMetricNames[mi]] = stat_of(b);
    }
    res.summary.push_back(s);
  }
  if (t.out.empty()) return res;

  // Files.
  const fs::path dir(t.out);
  make_output_dir(t.out, "out");
  auto list = [](const std::vector<double>& v, double scale) {
    std::ostringstream s;
    s.precision(6);
    for (std::size_t i = 0; i < v.size(); ++i) s << (i ? ";" : "") << v[i] * scale;
    return s.str();
  };
  CsvText csv({"scenario", "trial", "psnr_db", "psnr_h_db", "ssim", "rmse", "ergas", "sam_rad", "nomdec_psnr_db", "nomdec_psnr_h_db",
               "nomdec_ssim", "nomdec_rmse", "nomdec_ergas", "nomdec_sam_rad", "height_rms_change_nm", "psf_rel_change",
               "depth_errors_nm", "overlay_x_um", "overlay_y_um"});
  for (const auto& tr : res.trials) {
    std::vector<std::string> row{tr.scenario, std::to_string(tr.index)};
    for (int mi = 0; mi < 6; ++mi) row.push_back(csv_number(metric(tr.calibrated, mi), 8));
    for (int mi = 0; mi < 6; ++mi) row.push_back(csv_number(metric(tr.nominal_decoder, mi), 8));
    for (const std::string& v : {csv_number(tr.height_rms_change_m * 1e9, 8), csv_number(tr.psf_rel_change, 8), list(tr.depth_error_m, 1e9),
                                 list(tr.shift_x_m, 1e6), list(tr.shift_y_m, 1e6)})
      row.push_back(v);
    csv.row(row);
  }
  write_text_atomic((dir / "tolerance.csv").string(), csv.str());
  json j;
  j["run"] = t.run;
  j["scheme"] = to_string(plan.scheme);
  j["scheme_note"] = scheme_note;
  j["masks"] = json::array();
  for (const auto& mk : plan.masks) j["masks"].push_back({{"layer", mk.layer}, {"etch_depth_nm", mk.etch_depth_m * 1e9}});
  j["options"] = {{"etch_depth_error_nm", t.etch_depth_error_m * 1e9}, {"overlay_um", t.overlay_m * 1e6},
                  {"edge_blur_um", t.edge_blur_m * 1e6},          {"height_noise_nm", t.height_noise_m * 1e9},
                  {"trials", t.trials},                          {"seed", t.seed},
                  {"oversample", t.oversample},                  {"test_patches", ev.patches()},
                  {"noise_sigma", ev.sigma()},                   {"precision", to_string(t.precision)}};
  j["model"] = {
      {"etch_depth", "per mask, uniform in [-S, S], added to the mask's etch depth"},
      {"overlay", single_write ? "none: one greyscale write" : "per mask after the first (which defines the alignment marks), per axis, uniform in [-S, S]"},
      {"edge_blur", "Gaussian of sigma S on each mask's open region (sloped / rounded edges), deterministic"},
      {"height_noise", "per DOE pixel, uniform in [-S, S]"},
      {"grid", "masks rendered oversample x finer (area fractions), etch composed there and area-averaged back to the DOE pitch"},
      {"decoders", "calibrated: Wiener decoder rebuilt for the fabricated PSF; nominal_decoder: the nominal design's decoder"},
      {"metrics", "as qdo eval (metrics.json conventions), mean over test scenes"}};
  auto metrics_json = [](const Metrics& m) {
    return json{{"psnr_db", m.psnr}, {"psnr_h_db", m.psnr_hyper}, {"ssim", m.ssim}, {"rmse", m.rmse}, {"ergas", m.ergas}, {"sam_rad", m.sam_rad}};
  };
  j["nominal"] = metrics_json(res.nominal);
  j["scenarios"] = json::array();
  for (const auto& s : res.summary) {
    json sj;
    sj["scenario"] = s.scenario;
    sj["trials"] = s.trials;
    for (const auto* which : {&s.calibrated, &s.nominal_decoder}) {
      json mj;
      for (int mi = 0; mi < 6; ++mi) {
        const Stat& st = which->at(kMetricNames[mi]);
        mj[kMetricNames[mi]] = {{"mean", st.mean}, {"std", st.std}, {"min", st.min}, {"max", st.max},
                                {"worst", higher_is_better(mi) ? st.min : st.max},
                                {"mean_change", st.mean - metric(res.nominal, mi)}};
      }
      sj[which == &s.calibrated ? "calibrated" : "nominal_decoder"] = mj;
    }
    j["scenarios"].push_back(sj);
  }
  write_text_atomic((dir / "tolerance.json").string(), j.dump(2) + "\n");
  write_strip_chart((dir / "psnr_by_scenario.png").string(), fs::path(t.run).filename().string(), res);
  if (!psf_sets.empty()) {
    const auto wl = o.cfg.wavelengths_nm();
    psf_sets.push_back({"/wavelengths_nm", {wl.size()}, wl, {}, {{"units", "nm"}}});
    h5_write((dir / "psfs.h5").string(), psf_sets, {{"run", t.run}, {"content", "sensor PSF stacks (bands x S x S) per trial"}});
  }
  if (!worst_dh.data.empty()) {
    write_height_figure((dir / "worst_height_error.png").string(), "Height error of the worst trial (lowest PSNR)", worst_dh,
                        o.cfg.pitch_m, "height error (nm)");
    write_psf_figure((dir / "worst_psf.png").string(), "PSF stack of the worst trial (lowest PSNR)", worst_psf, o.cfg.wavelengths_nm(),
                     o.cfg.sensor_pitch_m, std::min<std::size_t>(worst_psf.rows, 96));
  }
  std::ostringstream md;
  md << "# Tolerance analysis\n\nRun `" << t.run << "`, scheme " << to_string(plan.scheme) << " (" << scheme_note << "), " << K
     << " mask layer(s); " << t.trials << " trials per scenario, seed " << t.seed << ", oversampling " << t.oversample << "x, "
     << ev.patches() << " test patches.\n\n";
  md << "Errors: etch depth ±" << t.etch_depth_error_m * 1e9 << " nm per mask (uniform), overlay ±" << t.overlay_m * 1e6
     << " um per mask and axis (uniform; mask 1 is the reference" << (single_write ? "; none for a single greyscale write" : "")
     << "), edge blur sigma " << t.edge_blur_m * 1e6 << " um, height noise ±" << t.height_noise_m * 1e9 << " nm per pixel.\n\n";
  md << "Nominal design: PSNR " << fixed(res.nominal.psnr, 3) << " dB, SSIM " << fixed(res.nominal.ssim, 4) << ", RMSE "
     << fixed(res.nominal.rmse, 5) << ", ERGAS " << fixed(res.nominal.ergas, 3) << ", SAM " << fixed(res.nominal.sam_rad, 4) << " rad.\n\n";
  md << "| scenario | trials | PSNR mean (dB) | std | worst | change of mean | SSIM mean | worst | PSNR mean, nominal decoder | worst |\n"
     << "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n";
  for (const auto& s : res.summary) {
    const Stat& p = s.calibrated.at("psnr_db");
    const Stat& q = s.calibrated.at("ssim");
    const Stat& pn = s.nominal_decoder.at("psnr_db");
    md << "| " << s.scenario << " | " << s.trials << " | " << fixed(p.mean, 3) << " | " << fixed(p.std, 3) << " | " << fixed(p.min, 3)
       << " | " << fixed(p.mean - res.nominal.psnr, 3) << " | " << fixed(q.mean, 4) << " | " << fixed(q.min, 4) << " | "
       << fixed(pn.mean, 3) << " | " << fixed(pn.min, 3) << " |\n";
  }
  md << "\n\"Calibrated\": the Wiener decoder is rebuilt for the fabricated DOE's PSF (as after a PSF calibration); \"nominal decoder\": "
        "the decoder of the nominal design is used unchanged. Files: tolerance.csv (one row per trial), tolerance.json (summaries), "
        "psnr_by_scenario.png (per scenario: blue dots calibrated, red dots nominal decoder, black bars the means, dashed grey "
        "line the nominal design), worst_height_error.png (height change of the worst combined trial, nm), worst_psf.png.\n";
  write_text_atomic((dir / "tolerance.md").string(), md.str());
  return res;
}

}  // namespace qdo::fab
