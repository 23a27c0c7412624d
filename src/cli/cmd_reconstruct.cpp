// qdo reconstruct: captured photos of one scene through the built camera -> a run's decoder with
// the PSF of the camera as built -> cube.h5, srgb.png, spectra.csv / spectra.png (reconstruct.hpp).
#include <cstdio>
#include <string>

#include <nlohmann/json.hpp>

#include "cli.hpp"
#include "qdo/decode/decoder_registry.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"
#include "qdo/design/reconstruct.hpp"
#include "qdo/data/scenes.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/decode/testset.hpp"

namespace qdo::cli {

int cmd_reconstruct(const Args& a) {
  ReconstructOptions o;
  if (!a.has("run")) reject("--run", "(missing)", "the run folder whose decoder reconstructs");
  o.run = a.get("run");
  o.sensor_file = a.get("sensor");
  const auto it = a.multi.find("capture");
  if (it != a.multi.end()) o.capture.captures = it->second;
  else if (a.has("capture")) o.capture.captures = {a.get("capture")};
  if (o.capture.captures.empty()) reject("--capture", "(missing)", "one or more 16-bit PNG captures of the scene");
  o.capture.darks_dir = a.get("darks");
  o.capture.white_dir = a.get("white");
  o.psf_file = a.get("psf");
  o.design_file = a.get("design");
  if (a.has("psf") && a.has("design")) reject("--design", o.design_file, "either --psf or --design, not both (the camera as built is one of them)");
  o.capture.exposure = exposure_rule_from_string(a.get("exposure"), "--exposure");
  if (a.has("crop")) {
    const auto v = split_items(a.get("crop"));
    if (v.size() != 4) reject("--crop", a.get("crop"), "ROW,COL,H,W (four integers)");
    o.capture.crop = true;
    o.capture.crop_row = std::size_t(parse_int("--crop", v[0], 0, 1 << 28));
    o.capture.crop_col = std::size_t(parse_int("--crop", v[1], 0, 1 << 28));
    o.capture.crop_rows = std::size_t(parse_int("--crop", v[2], 1, 1 << 28));
    o.capture.crop_cols = std::size_t(parse_int("--crop", v[3], 1, 1 << 28));
  }
  o.capture.demosaic = a.get("demosaic");
  if (o.capture.demosaic != "bilinear" && o.capture.demosaic != "mhc") reject("--demosaic", o.capture.demosaic, "bilinear or mhc");
  if (a.has("overlap")) o.overlap_px = std::size_t(parse_int("--overlap", a.get("overlap"), 1, 1 << 20));
  if (a.has("boundary")) {
    o.boundary_set = true;
    o.boundary = tile_boundary_from_string(a.get("boundary"), "--boundary");
  }
  if (a.get("noise-sigma") == "model")
    o.noise_sigma_model = true;
  else if (a.has("noise-sigma"))
    o.noise_sigma = parse_double("--noise-sigma", a.get("noise-sigma"), 0, 10, "(units of full scale, or model)");
  o.regions = parse_regions(a.get("points"), false, "--points");
  for (const auto& r : parse_regions(a.get("boxes"), true, "--boxes")) o.regions.push_back(r);
  o.precision = precision_from_string(a.get("precision"));
  // --truth: the scene the capture shows (a simulation's cube), scored against the cube over the
  // interior (--truth-border px from each edge) with qdo eval's metrics. Read and checked against
  // the captures' size (after --crop) before any work.
  RealStack truth;
  std::size_t border = 0;
  if (a.has("truth")) {
    const DesignRunOptions ro = read_run_config(o.run, "--run", "a run folder written by qdo design");
    const SystemConfig cfg = o.sensor_file.empty() ? ro.cfg : with_sensor(ro.cfg, o.sensor_file, decoder_entry(ro.decoder.kind_name()).trained);
    truth = read_scene(cfg, a.get("truth"), a.get("truth-key"), false, "--truth-key");
    const CaptureFiles f = read_captures(cfg, o.capture);
    if (truth.rows != f.mean_dn.rows || truth.cols != f.mean_dn.cols)
      reject("--truth", a.get("truth"),
             "a scene of the captures' size, " + std::to_string(f.mean_dn.rows) + " x " + std::to_string(f.mean_dn.cols) + " (it is " +
                 std::to_string(truth.rows) + " x " + std::to_string(truth.cols) + ")");
    if (o.capture.crop) {
      RealStack c(truth.planes, o.capture.crop_rows, o.capture.crop_cols);
      for (std::size_t b = 0; b < truth.planes; ++b)
        for (std::size_t y = 0; y < c.rows; ++y)
          for (std::size_t x = 0; x < c.cols; ++x) c(b, y, x) = truth(b, o.capture.crop_row + y, o.capture.crop_col + x);
      truth = std::move(c);
    }
    border = std::size_t(parse_int("--truth-border", a.get("truth-border", "0"), 0, 1 << 20));
    // The scored interior must hold the metrics' 11 x 11 SSIM window: checked here, before any work.
    const std::size_t side = std::min(truth.rows, truth.cols);
    if (side < 11 || border > (side - 11) / 2)
      reject("--truth-border", std::to_string(border),
             "at most " + std::to_string(side < 11 ? 0 : (side - 11) / 2) + " px for a " + std::to_string(truth.rows) + " x " +
                 std::to_string(truth.cols) + " image (the scored interior must be at least 11 x 11, the SSIM window)");
  } else if (a.has("truth-key") || a.has("truth-border")) {
    reject(a.has("truth-key") ? "--truth-key" : "--truth-border", "(given)", "only with --truth");
  }
  o.out = out_dir(a);
  Runtime rt(a.get("device"));
  const ReconstructResult r = reconstruct(rt, o);
  if (!truth.data.empty()) {
    const auto interior = [&](const RealStack& s) {
      RealStack c(s.planes, s.rows - 2 * border, s.cols - 2 * border);
      for (std::size_t b = 0; b < s.planes; ++b)
        for (std::size_t y = 0; y < c.rows; ++y)
          for (std::size_t x = 0; x < c.cols; ++x) c(b, y, x) = s(b, border + y, border + x);
      return c;
    };
    if (truth.planes != r.cube.planes) reject("--truth", a.get("truth"), "a cube of the run's " + std::to_string(r.cube.planes) + " bands");
    const testset::Scores sc = testset::score(interior(r.cube), interior(truth));
    nlohmann::json m;
    m["truth"] = a.get("truth");
    m["border_px"] = border;
    m["psf"] = r.psf;
    m["decoder"] = r.decoder;
    m["mean"] = {{"psnr", sc.psnr}, {"psnr_hyper", sc.psnr_hyper}, {"ssim", sc.ssim}, {"rmse", sc.rmse}, {"ergas", sc.ergas}, {"sam_rad", sc.sam_rad}};
    write_text_atomic(o.out + "/metrics.json", m.dump(2) + "\n");
    std::printf("against %s (interior, %zu px border): PSNR %.3f dB, SSIM %.4f, RMSE %.5f, ERGAS %.3f, SAM %.4f rad\n",
                a.get("truth").c_str(), border, sc.psnr, sc.ssim, sc.rmse, sc.ergas, sc.sam_rad);
  }
  for (const auto& n : r.notes) std::printf("note: %s\n", n.c_str());
  std::printf("decoder: %s\nPSF: %s\nimage %zu x %zu -> cube %zu x %zu x %zu in %zu tile%s of %zu x %zu px, boundary %s (exposure factor %.6g)\nseconds:",
              r.decoder.c_str(), r.psf.c_str(), r.cube.rows, r.cube.cols, r.cube.planes, r.cube.rows, r.cube.cols, r.tiles,
              r.tiles == 1 ? "" : "s", r.tile_px, r.tile_px, r.boundary.c_str(), r.exposure_factor);
  for (const auto& [k, v] : r.seconds) std::printf(" %s %.3f", k.c_str(), v);
  std::printf("\nwrote %s/cube.h5, srgb.png, spectra.csv, spectra.png, reconstruct.json%s\n", o.out.c_str(), truth.data.empty() ? "" : ", metrics.json");
  return 0;
}

}  // namespace qdo::cli
