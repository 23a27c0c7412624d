// qdo reconstruct's options read from text, and the reconstruction with its score and report
// (reconstruct.hpp).
#include "qdo/asbuilt/reconstruct.hpp"

#include "qdo/design/psf_spec.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/strprintf.hpp"
#include "qdo/runtime/util.hpp"

namespace qdo {

ReconstructRequest reconstruct_request_from_options(const TextOptions& a) {
  ReconstructRequest q;
  ReconstructOptions& o = q.options;
  if (!a.has("run")) reject("--run", "(missing)", "the run folder whose decoder reconstructs");
  o.run = a.get("run");
  o.sensor_file = a.get("sensor");
  o.capture.captures = a.all("capture");
  if (o.capture.captures.empty()) reject("--capture", "(missing)", "one or more 16-bit PNG captures of the scene");
  o.capture.darks_dir = a.get("darks");
  o.capture.white_dir = a.get("white");
  o.psf_file = a.get("psf");
  o.design_file = a.get("design");
  (void)psf_spec_from_options(o.psf_file, o.design_file, "--psf", "--design",
                              "the camera as built is one of them");  // both: refused
  o.capture.exposure = exposure_rule_from_string(a.get("exposure", "none"), "--exposure");
  if (a.has("crop")) {
    const auto v = split_items(a.get("crop"));
    if (v.size() != 4) reject("--crop", a.get("crop"), "ROW,COL,H,W (four integers)");
    o.capture.crop = true;
    o.capture.crop_row = std::size_t(parse_int("--crop", v[0], 0, 1 << 28));
    o.capture.crop_col = std::size_t(parse_int("--crop", v[1], 0, 1 << 28));
    o.capture.crop_rows = std::size_t(parse_int("--crop", v[2], 1, 1 << 28));
    o.capture.crop_cols = std::size_t(parse_int("--crop", v[3], 1, 1 << 28));
  }
  o.capture.demosaic = a.get("demosaic", "bilinear");
  if (o.capture.demosaic != "bilinear" && o.capture.demosaic != "mhc")
    reject("--demosaic", o.capture.demosaic, "bilinear or mhc");
  if (a.has("overlap")) o.overlap_px = std::size_t(parse_int("--overlap", a.get("overlap"), 1, 1 << 20));
  if (a.has("boundary")) {
    o.boundary_set = true;
    o.boundary = tile_boundary_from_string(a.get("boundary"), "--boundary");
  }
  if (a.get("noise-sigma") == "model")
    o.noise_sigma_model = true;
  else if (a.get("noise-sigma") == "ml")
    o.noise_sigma_ml = true;
  else if (a.get("noise-sigma") == "gcv")
    o.noise_sigma_gcv = true;
  else if (a.has("noise-sigma"))
    o.noise_sigma = parse_double("--noise-sigma", a.get("noise-sigma"), 0, 10, "(units of full scale, model, ml or gcv)");
  o.regions = parse_regions(a.get("points"), false, "--points");
  for (const auto& r : parse_regions(a.get("boxes"), true, "--boxes")) o.regions.push_back(r);
  o.precision = precision_from_string(a.get("precision", "f32"));
  // --truth: the scene the capture shows (a simulation's cube), scored against the cube over the
  // interior (--truth-border px from each edge) with qdo eval's metrics. Read and checked against
  // the captures' size (after --crop) before any work.
  RealStack& truth = q.truth;
  std::size_t& border = q.border_px;
  const TruthArguments& truth_names = q.names;
  if (a.has("truth")) {
    q.truth_path = a.get("truth");
    truth = read_reconstruct_truth(o, a.get("truth"), a.get("truth-key"), truth_names);
    border = std::size_t(parse_int("--truth-border", a.get("truth-border", "0"), 0, 1 << 20));
    // The scored interior must hold the metrics' 11 x 11 SSIM window: checked here, before any work.
    check_truth_border(truth, border, truth_names);
  } else if (a.has("truth-key") || a.has("truth-border")) {
    reject(a.has("truth-key") ? "--truth-key" : "--truth-border", "(given)", "only with --truth");
  }
  return q;
}

std::string run_reconstruct_request(Runtime& rt, const ReconstructRequest& q) {
  const ReconstructOptions& o = q.options;
  const RealStack& truth = q.truth;
  const std::size_t border = q.border_px;
  const ReconstructResult r = reconstruct(rt, o);
  std::string s;
  if (!truth.data.empty()) {
    const testset::Scores sc = score_reconstruction(r, truth, border, q.truth_path, o.out, q.names);
    s += strprintf(
        "against %s (interior, %zu px border): PSNR %.3f dB, SSIM %.4f, RMSE %.5f, ERGAS %.3f, SAM %.4f rad\n",
        q.truth_path.c_str(), border, sc.psnr, sc.ssim, sc.rmse, sc.ergas, sc.sam_rad);
  }
  for (const auto& n : r.notes) s += "note: " + n + "\n";
  s += strprintf(
      "decoder: %s\nPSF: %s\nimage %zu x %zu -> cube %zu x %zu x %zu in %zu tile%s of %zu x %zu px, boundary %s "
      "(exposure factor %.6g)\nseconds:",
      r.decoder.c_str(), r.psf.c_str(), r.cube.rows, r.cube.cols, r.cube.planes, r.cube.rows, r.cube.cols, r.tiles,
      r.tiles == 1 ? "" : "s", r.tile_px, r.tile_px, r.boundary.c_str(), r.exposure_factor);
  for (const auto& [k, v] : r.seconds) s += strprintf(" %s %.3f", k.c_str(), v);
  s += strprintf("\nwrote %s/cube.h5, srgb.png, spectra.csv, spectra.png, reconstruct.json%s\n", o.out.c_str(),
                 truth.data.empty() ? "" : ", metrics.json");
  return s;
}

}  // namespace qdo
