// qdo reconstruct: captured photos of one scene through the built camera -> a run's decoder with
// the PSF of the camera as built -> cube.h5, srgb.png, spectra.csv / spectra.png (reconstruct.hpp).
#include <cstdio>
#include <string>

#include "cli.hpp"
#include "options.hpp"
#include "qdo/decode/decoder_registry.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"
#include "qdo/asbuilt/reconstruct.hpp"
#include "qdo/data/scenes.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/decode/testset.hpp"

namespace qdo::cli {

static int cmd_reconstruct(const Args& a) {
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
  TruthArguments truth_names;
  truth_names.run = "--run";
  truth_names.truth = "--truth";
  truth_names.key = "--truth-key";
  truth_names.border = "--truth-border";
  if (a.has("truth")) {
    truth = read_reconstruct_truth(o, a.get("truth"), a.get("truth-key"), truth_names);
    border = std::size_t(parse_int("--truth-border", a.get("truth-border", "0"), 0, 1 << 20));
    // The scored interior must hold the metrics' 11 x 11 SSIM window: checked here, before any work.
    check_truth_border(truth, border, truth_names);
  } else if (a.has("truth-key") || a.has("truth-border")) {
    reject(a.has("truth-key") ? "--truth-key" : "--truth-border", "(given)", "only with --truth");
  }
  o.out = out_dir(a);
  Runtime rt(a.get("device"));
  const ReconstructResult r = reconstruct(rt, o);
  if (!truth.data.empty()) {
    const testset::Scores sc = score_reconstruction(r, truth, border, a.get("truth"), o.out, truth_names);
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

namespace {
// qdo reconstruct: its entry in the command table (help order 200).
const RegisterCommand registered_reconstruct(200, [] {
  using namespace opts;
  CommandSpec c{"reconstruct",
                   "captured photos of one scene through the built camera -> the run's decoder (tiled) -> DIR/cube.h5 (bands x H x W with "
                   "/wavelengths_nm), srgb.png, spectra.csv, spectra.png, reconstruct.json",
                   "", "",
                   {opt("run", "the run folder whose decoder reconstructs (its Wiener decoder or its network), its configuration and prior "
                               "(required)"),
                    {"capture", "a capture: 16-bit PNG or TIFF, RGB with the run's cfa none, else the raw mosaic (grayscale); repeat for "
                                "several frames of the scene (averaged, all the same size) (required)",
                     "", false, true},
                    opt("darks", "folder of dark frames (16-bit PNG or TIFF, the captures' size and kind; the mean is subtracted) (default: the "
                                 "configuration's black_level_dn)"),
                    opt("white", "folder of white (flat-field) frames: a uniformly lit, spectrally flat white target filling the view, "
                                 "the captures' size and kind (averaged, dark subtracted); each capture pixel is divided by its white "
                                 "signal over the white's mean (colour gains and pixel response measured; reconstruct.json records the "
                                 "gains) (default: none)"),
                    opt("sensor", "the sensor as built: a JSON file of sensor keys (cfa, black_level_dn, bit_depth, gain, read_noise_sigma, "
                                  "full_well_photons, noise_seed, camera, srf_interpolate) over the run's configuration, e.g. raw "
                                  "captures for a run trained on RGB (default: the run's sensor)"),
                    opt("psf", "the camera as built: a measured PSF stack (qdo calibrate's psf.h5), for the run's bands and sensor grid "
                               "(checked) (default: the run's design simulated, or the PSF a do-finetune run was fine-tuned for)"),
                    opt("design", "the camera as built: a fitted design .h5 (N x N at the run's pitch), simulated; not with --psf"),
                    opt("exposure", "exposure normalisation of the signal (DN - dark) / (gain (white - black)): none, scale:K (times K, K in "
                                    "(0, 1e6]) or percentile:P:L (the P-th percentile, P in (0, 100], of the cropped image to L in (0, 1])",
                        "none"),
                    opt("crop", "ROW,COL,H,W: the part of the frame reconstructed, 0-based pixels, H and W at least the decoder's tile S "
                                "(default: the whole frame)"),
                    opt("demosaic", "raw captures: bilinear or mhc (Malvar-He-Cutler)", "bilinear"),
                    opt("overlap", "overlap of neighbouring S x S tiles, pixels, an integer in [1, S - 1] (default: S / 4)"),
                    opt("boundary", "how a tile meets the decoder's circular model: mirror (the tile extended by its mirror image to 2S x 2S and "
                                    "decoded there: far less ringing from light that reaches the tile from outside it) or circular (as the "
                                    "decoder was trained: exact for circularly simulated captures; a network's only choice) (default: mirror "
                                    "for the Wiener decoder, circular for a network)"),
                    opt("noise-sigma", "noise std the Wiener decoder assumes, in units of full scale, in [0, 10], or model: the sensor's "
                                       "noise model (read noise, shot noise at the capture's mean signal, quantization; not demosaic "
                                       "error) (default: the run's)"),
                    opt("points", "spectra at points ROW,COL;ROW,COL;... of the reconstructed image (default: its centre when no --boxes)"),
                    opt("boxes", "mean spectra over boxes ROW,COL,H,W;... of the reconstructed image"),
                    opt("truth", "the scene the captures show (a cube file or PNG band folder of the captures' size, e.g. the --scene of "
                                 "qdo simulate --raw): the cube is scored against it (cropped as --crop) with qdo eval's metrics -> "
                                 "metrics.json"),
                    opt("truth-key", "variable / dataset name of the --truth cube (default: found automatically)"),
                    opt("truth-border", "pixels left out of the score at each edge (light from outside the frame is missing there), "
                                        "an integer >= 0 below half the image's smaller side", "0"),
                    precision(), device(),
                    out_dir_opt()},
                   cmd_reconstruct};
  c.memory_advice = "--crop, or fewer captures and darks";
  return c;
});
}  // namespace

}  // namespace qdo::cli
