// `qdo reconstruct` (reconstruct.hpp): tiles through a run's decoder -> cube (the captures, step 1 to 4, are capture.cpp),
// sRGB render, spectra.
#include "qdo/asbuilt/reconstruct.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>

#include "qdo/decode/decoder_registry.hpp"
#include "qdo/decode/wiener_masked.hpp"
#include "qdo/physics/demosaic.hpp"
#include "qdo/design/design_run.hpp"
#include "qdo/runtime/embedded.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/figure.hpp"
#include "qdo/data/io.hpp"
#include "qdo/decode/network_decoder.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/psf_source.hpp"
#include "qdo/physics/raw_reference.hpp"
#include "qdo/design/run.hpp"
#include "qdo/design/psf_spec.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/data/scenes.hpp"
#include "qdo/physics/simulator.hpp"
#include "asbuilt/reconstruct_internal.hpp"

namespace fs = std::filesystem;

namespace qdo {
using namespace reconstruct_detail;

SystemConfig with_sensor(const SystemConfig& run_cfg, const std::string& sensor_file, bool trained_decoder,
                         std::vector<std::string>* overridden) {
  static const std::vector<std::string> keys = {"cfa", "black_level_dn", "bit_depth", "gain", "read_noise_sigma", "full_well_photons",
                                                "noise_seed", "camera", "srf_interpolate"};
  std::error_code ec;
  if (!std::filesystem::is_regular_file(sensor_file, ec)) reject("--sensor", sensor_file, "an existing JSON file of sensor keys");
  nlohmann::json given;
  try {
    std::ifstream in(sensor_file);
    given = nlohmann::json::parse(in);
  } catch (const nlohmann::json::exception& e) {
    throw InputError("--sensor '" + sensor_file + "': not valid JSON (" + e.what() + ")");
  }
  if (!given.is_object() || given.empty())
    throw InputError("--sensor '" + sensor_file + "': a JSON object of sensor keys, e.g. {\"cfa\": \"rggb\", \"bit_depth\": 12}");
  nlohmann::json merged = nlohmann::json::parse(config_to_json_text(run_cfg));
  for (const auto& [k, v] : given.items()) {
    if (std::find(keys.begin(), keys.end(), k) == keys.end()) {
      std::string allowed;
      for (const std::string& a : keys) allowed += (allowed.empty() ? "" : ", ") + a;
      throw InputError("--sensor '" + sensor_file + "': key '" + k + "' is not a sensor key (allowed: " + allowed +
                       "; the optics are the run's)");
    }
    if (trained_decoder && (k == "camera" || k == "srf_interpolate"))
      throw InputError("--sensor '" + sensor_file + "': key '" + k + "' changes the camera response, which this run's network was trained "
                       "with; fine-tune a run for that camera instead");
    merged[k] = v;
    if (overridden) overridden->push_back(k);
  }
  return config_from_json_text(merged.dump(), "--sensor '" + sensor_file + "' over the run's configuration");
}

// ---------------------------------------------------------------------------------------------
// The command.

ReconstructResult reconstruct(Runtime& rt, const ReconstructOptions& o) {
  using clock = std::chrono::steady_clock;
  if (o.out.empty()) reject("--out", "(missing)", "an output folder");
  const RunFolder folder(o.run);
  const DesignRunOptions ro = folder.config("--run");
  // The camera as built (psf_spec.hpp): --psf or --design, else the run's do-finetune target, else its design.
  const bool given = !o.psf_file.empty() || !o.design_file.empty();
  const PsfSpec spec = psf_spec_from_options(given ? o.psf_file : ro.finetune_psf, given ? o.design_file : ro.finetune_design, "--psf",
                                             "--design", "the camera as built is one of them");
  const DecoderEntry entry = decoder_entry(ro.decoder.kind_name());
  std::vector<std::string> sensor_keys;
  const SystemConfig cfg = o.sensor_file.empty() ? ro.cfg : with_sensor(ro.cfg, o.sensor_file, entry.trained, &sensor_keys);
  const std::size_t s = cfg.sensor_size_px();
  // A network is trained for one PSF and cannot be refit: only that one is accepted.
  if (entry.trained) {
    const bool own = o.psf_file == ro.finetune_psf && o.design_file == ro.finetune_design;
    if (!own && (!o.psf_file.empty() || !o.design_file.empty()))
      reject(o.psf_file.empty() ? "--design" : "--psf", o.psf_file.empty() ? o.design_file : o.psf_file,
             "no --psf or --design with this network run (its network was trained for " +
                 (!ro.finetune_psf.empty()      ? "the PSF file " + ro.finetune_psf
                  : !ro.finetune_design.empty() ? "the fitted design " + ro.finetune_design
                                                : std::string("its own design")) +
                 " and cannot be refit in closed form): fine-tune it for the camera as built first, qdo design --mode do-finetune "
                 "--from RUN --psf FILE (or --design FILE), and reconstruct with that run");
  }
  if ((o.noise_sigma_ml || o.noise_sigma_gcv) && ro.decoder.kind != DecoderSpec::Kind::Wiener)
    reject("--noise-sigma", o.noise_sigma_ml ? "ml" : "gcv",
           "a value or model for the " + ro.decoder.to_string() + " decoder (ml and gcv choose the Wiener decoder's sigma from the capture)");
  if (entry.trained && o.boundary_set && o.boundary != TileBoundary::Circular)
    reject("--boundary", to_string(o.boundary),
           "circular for this network run (its network was trained on circular " + to_str(s) + " x " + to_str(s) + " patches)");
  if (o.boundary_set && o.boundary == TileBoundary::Linear && ro.decoder.kind != DecoderSpec::Kind::Wiener &&
      ro.decoder.kind_name() != "cg")
    reject("--boundary", "linear", "mirror or circular for the " + ro.decoder.to_string() +
                                       " decoder (linear solves the Wiener decoder's objective, or cg's, by conjugate gradients)");
  // Default: the capture's own (linear) model for the Wiener decoder, mirror for another decoder
  // built from the PSF (cg's linear solve is its own slow iteration), circular for a network.
  const TileBoundary boundary = [&] {
    if (entry.trained) return TileBoundary::Circular;
    if (o.boundary_set) return o.boundary;
    return ro.decoder.kind == DecoderSpec::Kind::Wiener ? TileBoundary::Linear : TileBoundary::Mirror;
  }();
  if (boundary == TileBoundary::Linear && ro.decoder.kind == DecoderSpec::Kind::Wiener && !o.noise_sigma_model &&
      !o.noise_sigma_ml && !o.noise_sigma_gcv) {
    const double sigma_given = o.noise_sigma >= 0 ? o.noise_sigma : ro.decoder_noise_sigma;
    if (!(sigma_given > 0))
      reject(o.noise_sigma >= 0 ? "--noise-sigma" : "the run's decoder_noise_sigma", sigma_given,
             "> 0 with the linear boundary (its system is singular at 0): a sigma, model or ml, or --boundary mirror");
  }
  std::vector<std::pair<std::string, double>> secs;
  // Every input read and checked before any work.
  auto t = clock::now();
  const PsfInput psf_in = spec.kind == PsfSpec::Kind::Run ? [&] {
    const Map2D run_heights = folder.design().height_m;
    return read_psf_input(spec, cfg, &run_heights);
  }()
                                                          : read_psf_input(spec, cfg);
  const wiener::SpectralPrior prior = folder.prior(s);
  const CaptureFiles files = read_captures(cfg, o.capture);
  if (o.capture.crop) {
    const std::size_t rows = o.capture.crop_rows, cols = o.capture.crop_cols;
    if (rows < s || cols < s)
      reject("--crop", to_str(o.capture.crop_row) + "," + to_str(o.capture.crop_col) + "," + to_str(rows) + "," + to_str(cols),
             "a crop of at least the decoder's tile, " + to_str(s) + " x " + to_str(s) + " px");
  }
  const std::size_t img_rows = o.capture.crop ? o.capture.crop_rows : files.mean_dn.rows;
  const std::size_t img_cols = o.capture.crop ? o.capture.crop_cols : files.mean_dn.cols;
  if (img_rows < s || img_cols < s)
    throw InputError("file '" + o.capture.captures.front() + "': " + to_str(files.mean_dn.rows) + " x " + to_str(files.mean_dn.cols) +
                     " pixels" + (o.capture.crop ? " (cropped to " + to_str(img_rows) + " x " + to_str(img_cols) + ")" : std::string()) +
                     ", smaller than the decoder's tile of " + to_str(s) + " x " + to_str(s) + " px (the grid it was trained on)");
  const std::size_t overlap = o.overlap_px > 0 ? o.overlap_px : s / 4;
  if (overlap >= s) reject("--overlap", overlap, "below the decoder's tile of " + to_str(s) + " px");
  std::vector<SpectrumRegion> regions = o.regions;
  if (regions.empty()) regions.push_back({img_rows / 2, img_cols / 2, 1, 1, false});
  for (const SpectrumRegion& r : regions)
    if (r.row + r.rows > img_rows || r.col + r.cols > img_cols)
      reject(r.box ? "--boxes" : "--points", r.label(),
             "inside the reconstructed " + to_str(img_rows) + " x " + to_str(img_cols) + " image (after --crop)");
  if (cfg.cfa != Cfa::None) (void)demosaic_method_from_string(o.capture.demosaic, "--demosaic");  // the mosaic: read_captures
  secs.push_back({"read", seconds_since(t)});

  make_output_dir(o.out, "--out");
  const PreparedCapture cap = prepare_capture(rt, o.precision, cfg, o.capture, files);
  secs.push_back({"dark", cap.seconds_dark});
  secs.push_back({"demosaic", cap.seconds_demosaic});

  // The PSF the decoder is built for, then the decoder (the registry's, as `qdo eval` builds it).
  t = clock::now();
  ReconstructResult res;
  const RealStack psf = psf_stack(rt, cfg, o.precision, psf_in);
  res.psf = psf_in.describe(folder.design_path());
  DecoderInputs in;
  in.spec = ro.decoder;
  in.psf = psf;
  in.srf = sensor_response(cfg);
  in.prior = boundary == TileBoundary::Circular ? prior : regrid_prior(prior, 2 * s, 2 * s);
  // Linear: the same objective (prior, sigma) under the capture's own linear model on the 2S grid
  // (tiled.hpp): the Wiener decoder's in the measurement space, cg's by its own iterations.
  if (boundary == TileBoundary::Linear && ro.decoder.kind != DecoderSpec::Kind::Wiener) in.encoder = linear_tile_encoder(psf, in.srf, s);
  in.noise_sigma = o.noise_sigma >= 0 ? o.noise_sigma : ro.decoder_noise_sigma;
  double mean_signal = 0;  // the capture's mean, full-scale units before the exposure
  if (o.noise_sigma_model) {
    for (double v : cap.rgb.data) mean_signal += v;
    mean_signal /= double(std::max<std::size_t>(cap.rgb.data.size(), 1)) * cap.exposure_factor;
    const double lsb = cfg.bit_depth > 0 ? 1.0 / (std::ldexp(1.0, int(cfg.bit_depth)) - 1) : 0.0;
    const double shot = cfg.full_well_photons > 0 ? std::max(mean_signal, 0.0) / cfg.full_well_photons : 0.0;
    in.noise_sigma = cap.exposure_factor * std::sqrt(cfg.read_noise_sigma * cfg.read_noise_sigma + shot + lsb * lsb / 12 +
                                                     cap.demosaic_sigma * cap.demosaic_sigma);
  }
  wiener::SigmaSearch fitted_sigma;
  const bool search = o.noise_sigma_ml || o.noise_sigma_gcv;
  const char* search_name = o.noise_sigma_ml ? "ml" : "gcv";
  if (search) {
    // On the tiles themselves (circular, S x S, the prior's own grid): a mirror extension repeats
    // every value, which the likelihood would count twice.
    fitted_sigma = (o.noise_sigma_ml ? wiener::ml_noise_sigma : wiener::gcv_noise_sigma)(
        decoder_tiles(cap.rgb, s, overlap, TileBoundary::Circular), wiener::psf_to_otf(psf, s, s), in.srf, prior, 1e-4, 1.0, 49);
    in.noise_sigma = fitted_sigma.sigma;
    if (fitted_sigma.at_edge)
      res.notes.push_back(std::string("--noise-sigma ") + search_name + ": the search's best lies at the edge of its range (" +
                          to_str(fitted_sigma.sigmas.front()) + " .. " + to_str(fitted_sigma.sigmas.back()) + "): sigma " +
                          to_str(fitted_sigma.sigma));
  }
  const std::string run = o.run;
  in.run_network = [run] { return load_run_network(run); };
  const std::unique_ptr<Decoder> dec = boundary == TileBoundary::Linear && ro.decoder.kind == DecoderSpec::Kind::Wiener
                                           ? linear_tile_wiener(psf, in.srf, prior, in.noise_sigma, s)
                                           : make_decoder(in);
  res.decoder = dec->description().empty() ? "decoder " + ro.decoder.to_string() : dec->description();
  secs.push_back({"psf+decoder", seconds_since(t)});

  t = clock::now();
  const auto rs = tile_starts(cap.rgb.rows, s, overlap), cs = tile_starts(cap.rgb.cols, s, overlap);
  res.tiles = cap.rgb.rows == s && cap.rgb.cols == s ? 1 : rs.size() * cs.size();
  res.tile_px = s;
  const auto t_tiles = clock::now();
  res.cube = decode_tiled(
      *dec, cap.rgb, s, overlap,
      [&](std::size_t done, std::size_t total) {
        if (o.quiet) return;
        const double el = seconds_since(t_tiles);
        std::fprintf(stderr, "[reconstruct] tile %zu/%zu  %.2f s/tile  ETA %.1f s\n", done, total, el / double(done),
                     el / double(done) * double(total - done));
        std::fflush(stderr);
      },
      boundary);
  res.boundary = to_string(boundary);
  if (const auto* mw = dynamic_cast<const MaskedWienerDecoder*>(dec.get())) {
    const MaskedWienerDecoder::Stats st = mw->stats();
    res.solver_solves = st.solves;
    res.solver_max_iterations = st.max_iterations;
    res.solver_worst_residual = st.worst_residual;
    res.solver_converged = st.all_converged;
    if (!st.all_converged)
      res.notes.push_back("boundary linear: a tile's conjugate gradients stopped at " + to_str(st.max_iterations) +
                          " iterations with relative residual " + to_str(st.worst_residual) + " (tolerance " +
                          to_str(mw->options().tolerance) + ")");
  }
  for (double& v : res.cube.data) v = std::clamp(v, 0.0, 1.0);
  secs.push_back({"tiles", seconds_since(t)});

  const auto wl = cfg.wavelengths_nm();
  const fs::path dir(o.out);
  std::string caps, darks;
  for (const auto& c : o.capture.captures) caps += (caps.empty() ? "" : ";") + c;
  for (const auto& d : files.darks) darks += (darks.empty() ? "" : ";") + d;
  const std::string crop = o.capture.crop ? to_str(o.capture.crop_row) + "," + to_str(o.capture.crop_col) + "," +
                                                to_str(o.capture.crop_rows) + "," + to_str(o.capture.crop_cols)
                                          : std::string("none");
  t = clock::now();
  h5_write((dir / "cube.h5").string(),
           {{"/cube", {res.cube.planes, res.cube.rows, res.cube.cols}, {}, {}, {{"units", "radiance relative to full scale, clipped to [0, 1]"}},
             false, false, &res.cube.data},
            {"/wavelengths_nm", {wl.size()}, wl, {}, {{"units", "nm"}}}},
           {{"source", "qdo reconstruct"},
            {"run", o.run},
            {"decoder", res.decoder},
            {"psf", res.psf},
            {"captures", caps},
            {"darks", darks.empty() ? std::string("none (black level ") + to_str(cfg.black_level_dn) + " DN)" : darks},
            {"exposure", o.capture.exposure.to_string()},
            {"exposure_factor", to_str(cap.exposure_factor)},
            {"crop", crop},
            {"tiles", to_str(res.tiles) + " of " + to_str(s) + " x " + to_str(s) + " px, overlap " + to_str(overlap) + " px, boundary " +
                          res.boundary}});
  secs.push_back({"write cube", seconds_since(t)});
  t = clock::now();
  write_rgb_png((dir / "srgb.png").string(), render_srgb(res.cube, wl));
  secs.push_back({"srgb", seconds_since(t)});
  t = clock::now();
  const auto spectra = region_spectra(res.cube, regions);
  std::vector<std::string> header = {"wavelength_nm"};
  for (const auto& r : regions) header.push_back(r.label());
  CsvText csv(header);
  for (std::size_t b = 0; b < wl.size(); ++b) {
    std::vector<std::string> row = {csv_number(wl[b])};
    for (const auto& sp : spectra) row.push_back(csv_number(sp[b], 9));
    csv.row(row);
  }
  write_text_atomic((dir / "spectra.csv").string(), csv.str());
  LinePlot lp;
  lp.title = "Mean spectra of the regions: " + dir.filename().string();
  lp.x_label = "wavelength (nm)";
  lp.y_label = "reconstructed radiance (scene units)";
  for (std::size_t k = 0; k < spectra.size(); ++k) lp.series.push_back(PlotSeries{regions[k].label(), wl, spectra[k], {}, {}, false});
  write_line_plot((dir / "spectra.png").string(), lp);
  secs.push_back({"spectra", seconds_since(t)});

  res.exposure_factor = cap.exposure_factor;
  res.notes.insert(res.notes.begin(), files.notes.begin(), files.notes.end());
  res.seconds = secs;
  nlohmann::json j;
  j["run"] = o.run;
  j["decoder"] = res.decoder;
  j["psf"] = res.psf;
  j["captures"] = o.capture.captures;
  j["darks"] = files.darks;
  if (!files.whites.empty()) j["white"] = {{"frames", files.whites}, {"channel_gains_rgb", files.channel_gains}};
  j["saturated_values"] = files.saturated;
  j["notes"] = res.notes;
  j["white_level_dn"] = files.white_dn;
  j["exposure"] = o.capture.exposure.to_string();
  j["exposure_factor"] = cap.exposure_factor;
  j["crop"] = crop;
  j["demosaic"] = cfg.cfa == Cfa::None ? std::string("none (RGB captures)") : o.capture.demosaic;
  if (!o.sensor_file.empty()) {
    nlohmann::json sensor = {{"file", o.sensor_file}};
    const nlohmann::json full = nlohmann::json::parse(config_to_json_text(cfg));
    for (const std::string& k : sensor_keys) sensor["values"][k] = full.at(k);
    j["sensor"] = sensor;
  }
  j["image_rows_cols"] = {res.cube.rows, res.cube.cols};
  j["tiles"] = res.tiles;
  j["tile_px"] = s;
  j["overlap_px"] = overlap;
  j["boundary"] = res.boundary;
  if (res.solver_solves > 0)
    j["boundary_solver"] = {{"method", "conjugate gradients in the measurement space (MaskedWienerDecoder)"},
                            {"tiles", res.solver_solves},
                            {"max_iterations", res.solver_max_iterations},
                            {"worst_relative_residual", res.solver_worst_residual},
                            {"converged", res.solver_converged}};
  j["noise_sigma"] = in.noise_sigma;
  if (o.noise_sigma_model)
    j["noise_sigma_model"] = {{"mean_signal", mean_signal},
                              {"read_noise_sigma", cfg.read_noise_sigma},
                              {"full_well_photons", cfg.full_well_photons},
                              {"bit_depth", cfg.bit_depth},
                              {"exposure_factor", cap.exposure_factor},
                              {"demosaic_sigma", cap.demosaic_sigma},
                              {"formula", "exposure x sqrt(read^2 + mean_signal / full_well + (1 / (2^bits - 1))^2 / 12 + demosaic_sigma^2); "
                                          "demosaic_sigma: the capture's demosaic error estimated from itself (its demosaic sampled "
                                          "through the mosaic one column over and developed again; 0 for RGB captures)"}};
  if (search)
    j[std::string("noise_sigma_") + search_name] = {{"sigma", fitted_sigma.sigma},
                           {"sigma_range", {fitted_sigma.sigmas.front(), fitted_sigma.sigmas.back()}},
                           {"points", fitted_sigma.sigmas.size()},
                           {"at_edge", fitted_sigma.at_edge},
                           {"tiles", res.tiles},
                           {"method", o.noise_sigma_ml
                                          ? "the sigma of largest marginal likelihood of the capture's tiles (S x S, circular) under the "
                                            "Wiener decoder's model, Y(f) ~ CN(0, H W (A P A^H + sigma^2 I)): the best of log-spaced "
                                            "sigmas, refined by a parabola"
                                          : "generalised cross-validation of the Wiener filter over the capture's tiles (S x S, "
                                            "circular): the minimum over log-spaced sigmas of N |(I - T) Y|^2 / tr(I - T)^2, refined by "
                                            "a parabola"}};
  nlohmann::json st = nlohmann::json::object();
  for (const auto& [k, v] : secs) st[k] = v;
  j["seconds"] = st;
  std::vector<std::string> labels;
  for (const auto& r : regions) labels.push_back(r.label());
  j["regions"] = labels;
  write_text_atomic((dir / "reconstruct.json").string(), j.dump(2) + "\n");
  return res;
}

}  // namespace qdo
