// `qdo eval`: reconstruction of test scenes through a run's design with a decoder of the registry
// (eval.hpp).
#include "qdo/evaluate/eval.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <random>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>

#include "qdo/decode/decoder_registry.hpp"
#include "qdo/design/design_run.hpp"
#include "qdo/physics/psf_source.hpp"
#include "qdo/physics/radial.hpp"
#include "qdo/data/cube_views.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/runtime/embedded.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/figure.hpp"
#include "qdo/data/io.hpp"
#include "qdo/decode/network_decoder.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/design/run.hpp"
#include "qdo/design/psf_spec.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/data/scenes.hpp"
#include "qdo/decode/testset.hpp"

namespace fs = std::filesystem;

namespace qdo {
namespace {

RealStack side_by_side(const RealStack& a, const RealStack& b) {
  const std::size_t gap = 4;
  RealStack out(a.planes, a.rows, a.cols * 2 + gap, 0.0);
  for (std::size_t c = 0; c < a.planes; ++c)
    for (std::size_t y = 0; y < a.rows; ++y)
      for (std::size_t x = 0; x < a.cols; ++x) {
        out(c, y, x) = a(c, y, x);
        out(c, y, a.cols + gap + x) = b(c, y, x);
      }
  return out;
}

}  // namespace

DecoderFit decoder_fit_from_string(const std::string& s, const std::string& argument) {
  if (s == "matched") return DecoderFit::Matched;
  if (s == "mismatch") return DecoderFit::Mismatch;
  reject(argument, s, "matched or mismatch");
}

std::string to_string(DecoderFit f) { return f == DecoderFit::Mismatch ? "mismatch" : "matched"; }

EvalResult evaluate_run(Runtime& rt, const EvalOptions& given) {
  const RunFolder folder(given.run);
  const DesignRunOptions o = folder.config();
  EvalOptions e = given;
  (void)psf_spec_from_options(e.psf_file, e.design_file, "psf", "design", "the camera as built is one of them");  // both: refused first
  // A run fine-tuned for the camera as built is evaluated through that camera by default.
  if (e.psf_file.empty() && e.design_file.empty() && e.levels == 0 && !e.full_precision) {
    e.psf_file = o.finetune_psf;
    e.design_file = o.finetune_design;
  }
  // Its network was trained for that PSF: matched needs it to be the one evaluated.
  const bool asbuilt_run = !o.finetune_psf.empty() || !o.finetune_design.empty();
  const bool own_asbuilt = asbuilt_run && e.psf_file == o.finetune_psf && e.design_file == o.finetune_design;
  if (e.out.empty()) reject("out", "(missing)", "an output folder");
  const SystemConfig& cfg = o.cfg;
  const DecoderSpec spec = e.decoder_kind ? *e.decoder_kind : o.decoder;
  const DecoderEntry entry = decoder_entry(spec.kind_name());
  // A decoder trained with the optics is the run's own, and cannot be refit in closed form:
  // `matched` needs the evaluated design to be the one it was trained with (the run's own design;
  // H_f for full and for do at full precision; a do-finetune run's quantized DOE); `mismatch`
  // evaluates it as trained, measured through the evaluated design (a network do run at its
  // levels: the paper's DO).
  if (entry.trained && spec != o.decoder)
    reject("decoder_kind", spec.to_string(), "the run's own decoder (" + o.decoder.to_string() + "): " + entry.name + " is trained with the optics");
  if ((!e.psf_file.empty() || !e.design_file.empty()) && (e.levels > 0 || e.full_precision))
    reject(e.levels > 0 ? "levels" : "full_precision", e.levels > 0 ? to_str(e.levels) : std::string("true"),
           "not with a PSF file or a fitted design (" + (e.psf_file.empty() ? "design = " + e.design_file : "psf = " + e.psf_file) +
               "): it is the camera as built, no heights are chosen");
  if (entry.trained && asbuilt_run && !own_asbuilt && e.decoder == DecoderFit::Matched)
    reject("decoder", "matched",
           "mismatch for this run: its network was fine-tuned for " +
               (o.finetune_psf.empty() ? "the fitted design " + o.finetune_design : "the PSF file " + o.finetune_psf) +
               ", not the PSF evaluated");
  if (entry.trained && !own_asbuilt && !e.design_file.empty() && e.decoder == DecoderFit::Matched)
    reject("decoder", "matched",
           "mismatch with a fitted design for this network run: its network cannot be refit for the design's PSF in closed form "
           "(fine-tune it: qdo design --mode do-finetune --from RUN --design FILE)");
  if (entry.trained && !own_asbuilt && !e.psf_file.empty() && e.decoder == DecoderFit::Matched)
    reject("decoder", "matched",
           "mismatch with a PSF file for this network run: its network cannot be refit for the file's PSF in closed form "
           "(mismatch evaluates it as trained, measured through the file's PSF)");
  if (entry.trained && !own_asbuilt && e.decoder == DecoderFit::Matched && !e.full_precision &&
      (e.levels > 0 || (o.design.mode == DesignMode::DO && o.finetune_from.empty())))
    reject("decoder", "matched",
           "mismatch for this network run: its network was trained for " +
               std::string(!o.finetune_from.empty()                 ? "the run's quantized DOE (a do-finetune run)"
                           : o.design.mode == DesignMode::DO ? "the full-precision design H_f"
                                                             : "the run's own design") +
               ", and a network cannot be refit in closed form (--decoder mismatch evaluates it through the " +
               (e.levels > 0 ? "re-quantized" : "quantized") + " DOE, the paper's DO; a do-finetune run retrains it for that DOE)");
  const Design full = folder.design_full();
  const Design fab = folder.design();
  const std::size_t s = cfg.sensor_size_px();
  const wiener::SpectralPrior prior = folder.prior(s);
  // The camera evaluated (psf_spec.hpp), read and checked against the run's configuration before
  // any work: a PSF file, a fitted design, or the run's own heights (quantized, full precision or
  // re-quantized to other levels).
  Map2D h_run = e.full_precision ? full.height_m : fab.height_m;
  if (e.levels > 0 && !e.full_precision) {
    Quantizer q;
    q.levels = e.levels;
    q.placement = e.placement;
    h_run = quantize_heights(full.height_m, cfg.h_max_m(), q);
  }
  const PsfInput psf_in =
      read_psf_input(psf_spec_from_options(e.psf_file, e.design_file, "psf", "design", "the camera as built is one of them"), cfg, &h_run);
  const RealStack& psf_file = psf_in.stack;
  const Map2D& h_eval = psf_in.from_file() ? h_run : psf_in.heights;
  const double sigma = e.noise_sigma >= 0 ? e.noise_sigma : o.decoder_noise_sigma;

  // Test scenes as S x S patches (non-overlapping), tagged with their scene name.
  const std::vector<testset::Patch> patches =
      testset::patches(cfg, s, e.data, e.data_format, e.synthetic_scenes, o.design.seed);
  make_output_dir(e.out, "out");

  Simulator sim(rt, cfg, e.precision);
  RealStack psf_eval = psf_file;
  // The run's fabrication noise on the measured PSF (height_noise_at_test, the release's test):
  // one seeded draw of +-height_noise_m per pixel, a camera as one fabrication made it; the
  // decoder (matched or mismatch) is built without it, as a trained one knows no draw.
  const bool noisy = o.height_noise_at_test && o.design.height_noise_m > 0 && e.psf_file.empty();
  RealStack psf_nominal;
  if (e.psf_file.empty()) {
    sim.set_heights(h_eval);
    sim.compute_psf();
    psf_eval = sim.psf_sensor();
    psf_nominal = psf_eval;
  }
  if (noisy) {
    Map2D h_noisy = h_eval;
    std::mt19937_64 rng(o.design.seed * 0x9E3779B97F4A7C15ull + 0xE7A1ull);
    std::uniform_real_distribution<double> u(-o.design.height_noise_m, o.design.height_noise_m);
    for (double& v : h_noisy.data) v = std::min(2 * cfg.h_max_m(), std::max(0.0, v + u(rng)));
    sim.set_heights(h_noisy);
    sim.compute_psf();
    psf_eval = sim.psf_sensor();
  }
  RealStack psf_dec = noisy ? psf_nominal : psf_eval;
  if (e.decoder == DecoderFit::Mismatch) {
    sim.set_heights(full.height_m);
    sim.compute_psf();
    psf_dec = sim.psf_sensor();
  }
  testset::PatchCamera camera(rt, cfg);
  DecoderInputs in;
  in.spec = spec;
  in.psf = psf_dec;
  in.srf = sensor_response(cfg);
  in.prior = prior;
  in.noise_sigma = sigma;
  in.run_network = [&e] { return load_run_network(e.run); };
  const std::unique_ptr<Decoder> dec = make_decoder(in);
  const std::string imaging = dec->description().empty() ? "decoder " + spec.to_string() : dec->description();
  const std::string psf_used = psf_in.spec.kind != PsfSpec::Kind::Run ? psf_in.describe()
                               : e.full_precision                      ? "the run's full-precision design (simulated)"
                               : e.levels > 0           ? "the run's design re-quantized to " + to_str(e.levels) + " levels (simulated)"
                                                        : "the run's design (simulated)";

  EvalResult res;
  res.deviation_nm = quantization_deviation_m(h_eval, full.height_m) * 1e9;
  {
    const std::vector<double> rq = ring_heights_of_map(h_eval), rf = ring_heights_of_map(full.height_m);
    double sum = 0;
    for (std::size_t i = 0; i < rq.size(); ++i) sum += std::fabs(rq[i] - rf[i]);
    res.deviation_rings_nm = rq.empty() ? 0.0 : sum / double(rq.size()) * 1e9;
  }
  std::vector<H5Dataset> recon;
  const auto wl = cfg.wavelengths_nm();
  std::vector<std::pair<std::size_t, std::size_t>> px = e.pixels;
  if (px.empty()) px.push_back({s / 2, s / 2});
  for (const auto& [py, pxx] : px)
    if (py >= s || pxx >= s) reject("pixels", to_str(py) + ":" + to_str(pxx), "inside the " + to_str(s) + " x " + to_str(s) + " patch");
  auto keep = [&](std::size_t k, const RealStack& xh) {  // the first `renders` patches: data and figures
    if (k >= e.renders) return;
    const RealStack& x = patches[k].cube;
    const std::string& scene = patches[k].scene;
    const std::string tag = std::to_string(k);
    recon.push_back({"/truth_" + tag, {x.planes, x.rows, x.cols}, x.data, {}, {{"scene", scene}}});
    recon.push_back({"/recon_" + tag, {xh.planes, xh.rows, xh.cols}, xh.data, {}, {{"scene", scene}}});
    write_rgb_png((fs::path(e.out) / ("render_" + tag + ".png")).string(), side_by_side(render_srgb(x, wl), render_srgb(xh, wl)));
    std::vector<std::vector<double>> curves;
    for (const auto& [py, pxx] : px) {
      std::vector<double> t, r2;
      for (std::size_t b = 0; b < x.planes; ++b) {
        t.push_back(x(b, py, pxx));
        r2.push_back(xh(b, py, pxx));
      }
      curves.push_back(t);
      curves.push_back(r2);
    }
    // Every chosen pixel: the true spectrum (line) and the reconstruction (points), against wavelength.
    LinePlot lp;
    lp.title = "Spectra of test patch " + tag + " (" + fs::path(scene).filename().string() + ")";
    lp.x_label = "wavelength (nm)";
    lp.y_label = "radiance (scene units, 1 = full scale)";
    for (std::size_t q = 0; q < px.size(); ++q) {
      const std::string at = "pixel " + to_str(px[q].first) + ":" + to_str(px[q].second);
      lp.series.push_back(PlotSeries{at + " truth", wl, curves[2 * q], {}, {}, false});
      lp.series.push_back(PlotSeries{at + " reconstruction", wl, curves[2 * q + 1], {}, {}, true});
    }
    write_line_plot((fs::path(e.out) / ("spectra_" + tag + ".png")).string(), lp);
  };
  const testset::Evaluation ev = testset::evaluate(camera, psf_eval, patches, *dec, sigma, o.design.seed, keep);
  const auto& per_patch = ev.per_patch;
  recon.push_back({"/wavelengths_nm", {wl.size()}, wl, {}, {{"units", "nm"}}});
  h5_write((fs::path(e.out) / "reconstructions.h5").string(), recon,
           {{"run", e.run}, {"decoder", to_string(e.decoder)}, {"decoder_kind", spec.to_string()},
            {"psf", psf_used}});
  CsvText csv({"scene", "patches", "psnr_db", "psnr_h_db", "ssim", "rmse", "ergas", "sam_rad"});
  auto row_of = [](const std::string& scene, const testset::Scores& m) {
    EvalRow r;
    r.scene = scene;
    r.psnr = m.psnr;
    r.psnr_hyper = m.psnr_hyper;
    r.ssim = m.ssim;
    r.rmse = m.rmse;
    r.ergas = m.ergas;
    r.sam_rad = m.sam_rad;
    return r;
  };
  for (const auto& [name, m] : ev.per_scene) {
    const std::string& scene = name;  // C++17 lambdas cannot capture a structured binding (clang refuses)
    const auto count = std::count_if(per_patch.begin(), per_patch.end(), [&scene](const auto& p) { return p.first == scene; });
    res.rows.push_back(row_of(name, m));
    csv.row({name, std::to_string(count), csv_number(m.psnr), csv_number(m.psnr_hyper), csv_number(m.ssim), csv_number(m.rmse),
             csv_number(m.ergas), csv_number(m.sam_rad)});
  }
  res.mean = row_of("mean", ev.mean);
  write_text_atomic((fs::path(e.out) / "metrics.csv").string(), csv.str());
  nlohmann::json j;
  j["run"] = e.run;
  j["decoder"] = to_string(e.decoder);
  j["decoder_kind"] = spec.to_string();
  j["levels"] = e.full_precision ? 0 : e.levels > 0 ? e.levels : o.design.quantizer.levels;
  j["full_precision"] = e.full_precision;
  j["requantized"] = e.levels > 0;
  j["noise_sigma"] = sigma;
  j["psf"] = psf_used;  // the PSF the scenes were measured through (and a matched Wiener decoder built for)
  j["scenes"] = res.rows.size();
  j["patches"] = patches.size();
  j["deviation_nm"] = res.deviation_nm;
  // Table 2 as the release logs it: over the ring profile of a radial design (each ring once).
  j["deviation_rings_nm"] = res.deviation_rings_nm;
  j["height_noise_at_test_nm"] = noisy ? o.design.height_noise_m * 1e9 : 0.0;
  nlohmann::json per_scene = nlohmann::json::array();  // the sweep's paired comparisons read it
  for (const EvalRow& r : res.rows)
    per_scene.push_back({{"scene", r.scene}, {"psnr_db", r.psnr}, {"psnr_h_db", r.psnr_hyper}, {"ssim", r.ssim},
                         {"rmse", r.rmse},   {"ergas", r.ergas},  {"sam_rad", r.sam_rad}});
  j["per_scene"] = per_scene;
  j["mean"] = {{"psnr_db", res.mean.psnr},       {"psnr_h_db", res.mean.psnr_hyper}, {"ssim", res.mean.ssim},
               {"rmse", res.mean.rmse},          {"ergas", res.mean.ergas},          {"sam_rad", res.mean.sam_rad}};
  j["conventions"] = {{"psnr_db", "whole cube, peak 1 (release psnr_metric)"},
                      {"psnr_h_db", "per band, peak = band max of the truth, averaged (release psnr_hyper_metric)"},
                      {"ssim", "Gaussian 11x11, sigma 1.5, K1 0.01, K2 0.03, range 1, valid positions, mean over bands"},
                      {"rmse", "whole cube"},
                      {"ergas", "100 sqrt(mean_b MSE_b / mu_b^2), ratio 1"},
                      {"sam_rad", "mean spectral angle, radians"},
                      {"imaging", std::string("circular per-band convolution on the S x S patch grid, Gaussian noise sigma, ") +
                                      imaging +
                                      ", output clipped to [0, 1]"}};
  write_text_atomic((fs::path(e.out) / "metrics.json").string(), j.dump(2) + "\n");
  return res;
}

}  // namespace qdo
