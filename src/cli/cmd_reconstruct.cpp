// qdo reconstruct: captured photos of one scene through the built camera -> a run's decoder with
// the PSF of the camera as built -> cube.h5, srgb.png, spectra.csv / spectra.png (reconstruct.hpp:
// reconstruct_request_from_options reads and checks the options, run_reconstruct_request does the
// work); this file claims --out, opens the device and prints.
#include <cstdio>
#include <string>

#include "cli.hpp"
#include "qdo/asbuilt/reconstruct.hpp"
#include "qdo/runtime/runtime.hpp"

namespace qdo::cli {

static int cmd_reconstruct(const Args& a) {
  ReconstructRequest q = reconstruct_request_from_options(a);
  q.options.out = out_dir(a);
  Runtime rt(a.get("device"));
  std::fputs(run_reconstruct_request(rt, q).c_str(), stdout);
  return 0;
}

// qdo reconstruct: its entry in the command table (help order 200).
const RegisterCommand registered_reconstruct(200, [] {
  using namespace opts;
  return CommandSpec{"reconstruct",
                   "captured photos of one scene through the built camera -> the run's decoder (tiled) -> DIR/cube.h5 (bands x H x W with "
                   "/wavelengths_nm), srgb.png, spectra.csv, spectra.png, reconstruct.json", "", "",
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
                                    "decoded there: far less ringing from light that reaches the tile from outside it), linear (the capture's own "
                                    "model: the tile is the recorded window of a scene twice its size, solved for by conjugate gradients "
                                    "under the decoder's prior and sigma; exact for real and linearly simulated captures, slower; Wiener "
                                    "and cg decoders) or circular (as the decoder was trained: exact for circularly simulated captures; a "
                                    "network's only choice) (default: linear for the Wiener decoder, mirror for cg, circular for a network)"),
                    opt("noise-sigma", "the Wiener decoder's noise std, full-scale units in [0, 10]; model: the sensor's noise model (read, "
                                       "shot, quantization, the capture's demosaic error); ml: from the capture, the largest marginal "
                                       "likelihood under the decoder's model; gcv: by cross-validation, for comparison (default: the run's)"),
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
                   cmd_reconstruct, false,
                   "--crop, or fewer captures and darks"};
});

}  // namespace qdo::cli
