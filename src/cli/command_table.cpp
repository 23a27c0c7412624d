// The command table of qdo: every command with its one-line summary, its positional argument
// (if any) and each of its options declared once (name, description with units and allowed
// values, default, flag or not). Parsing and help are commands.cpp's.
#include <string>
#include <vector>

#include "cli.hpp"
#include "qdo/decode/decoder_spec.hpp"

using namespace qdo;
using namespace qdo::cli;

namespace qdo::cli {
namespace {

OptionSpec opt(const std::string& name, const std::string& help, const std::string& def = "") { return {name, help, def, false, false}; }
OptionSpec flag(const std::string& name, const std::string& help) { return {name, help, "", true, false}; }

// Options several commands share, declared here once.
OptionSpec preset() { return opt("preset", "system preset: paper or small (omit with --config)", "small"); }
OptionSpec config() { return opt("config", "system configuration JSON file (instead of --preset)"); }
OptionSpec device() {
  return opt("device", "OpenCL device: gpu, cpu, P:D as 'qdo devices' prints, or a substring of the device name "
                       "(default: $QDO_DEVICE, else the first GPU, else the first CPU)");
}
OptionSpec precision() { return opt("precision", "floating-point precision on the device: f32 or f64", "f32"); }
OptionSpec placement() { return opt("placement", "quantization level placement: inclusive or wrapped", "inclusive"); }
OptionSpec design_spec() { return opt("design", "design: lens:NM (a diffractive lens for NM nanometres), flat, or a design .h5 file"); }
OptionSpec psf_file() {
  return opt("psf", "PSF stack file in place of --design: psf.h5 as qdo psf writes it (/psf_sensor, bands x S x S, with "
                    "/wavelengths_nm), for the configuration's bands and sensor grid (checked)");
}
OptionSpec levels_post() { return opt("levels", "quantize the design to L height levels, an integer in [2, 65536] (default: not quantized)"); }
OptionSpec out_dir_opt() { return opt("out", "output folder (created)"); }
OptionSpec save_opt() {
  return opt("save", "extra outputs, comma-separated: native (the native-grid PSF stack /psf_native, bands x N x N, in psf.h5)");
}
OptionSpec compress() {
  return flag("compress", "store psf.h5's PSF stacks chunked with HDF5's shuffle + deflate filters (smaller, slower; BENCHMARKS)");
}
OptionSpec scene() {
  return opt("scene", "scene: builtin (the configuration's chart), a cube file (.mat or .h5), or a folder of PNG bands", "builtin");
}
OptionSpec key() { return opt("key", "variable / dataset name of the cube in a .mat or .h5 --scene file (default: found automatically)"); }
OptionSpec resample_bands() { return flag("resample-bands", "interpolate a --scene cube whose band axis differs from the configuration's"); }
OptionSpec data(const std::string& what) {
  return opt("data", what + ": dataset names under the data root (cave, cave_train, ...; qdo data lists them), CAVE "
                     "folders, cube files or folders of them, comma-separated");
}
OptionSpec object_distances(const std::string& what, const std::string& role) {
  return opt("object-distances", what + ": object distances in metres, each > 0 (at least 1e-6) or inf, comma-separated, e.g. "
                                        "0.5,1,2,5; the object points are every distance under every --field-angles angle, " + role +
                                        " (default: the configuration's object_points, else its one scene distance); not with a "
                                        "--config that lists object_points");
}
OptionSpec field_angles(const std::string& what) {
  return opt("field-angles", what + ": field angles in degrees, comma-separated, A (on the x axis) or X:Y, each within the "
                                    "sampling at every distance (the refusal names the largest, max_field_angle_deg) (default: 0, "
                                    "on the axis)");
}
OptionSpec data_root() {
  return opt("data-root", "the folder that holds the datasets named in --data (default: $QDO_DATA, else data_root in "
                          "~/.config/qdo/settings.json, else ~/.local/share/qdo, else the source tree's data; qdo data)");
}
OptionSpec synthetic_scenes(const std::string& def) { return opt("synthetic-scenes", "number of synthetic scenes, an integer in [1, 100000]", def); }
OptionSpec noise_sigma(const std::string& help, const std::string& def) { return opt("noise-sigma", help, def); }
OptionSpec seed() { return opt("seed", "random seed, an integer in [0, 2147483647]", "0"); }
OptionSpec psf_path() {
  return opt("psf-path", "PSF engine of the optimisation: auto (radial for radial designs), 2d or radial (radial designs only)", "auto");
}
OptionSpec mode() { return opt("mode", "design mode: full, do, qdo, ste, qdo+a or qdo+m", "qdo+a"); }
OptionSpec parameterization() { return opt("parameterization", "height map parameterization: radial, quad or 2d", "radial"); }
OptionSpec objective() {
  return opt("objective", "design objective: wiener, wiener-mse, wiener-mae, psf-target or network (default: wiener; network with a network --decoder)");
}
OptionSpec target() { return opt("target", "PSF target for --objective psf-target: lens:NM or a design .h5 file", "lens:550"); }

// The options of the optimisation (qdo design; qdo sweep takes them too).
std::vector<OptionSpec> training_options() {
  const std::string r = "default from --recipe: ";
  return {opt("recipe", "training recipe that gives every default marked 'recipe': release (the authors' release as it trains: "
                        "lr x0.8 per 500 steps continuously, 50 x 418 steps, u = 0.5 start, L_aq over rings, +-20 nm height noise, "
                        "Keras' Adam) or qdo (qdo's earlier defaults); docs/recipes.md", "release"),
          opt("epochs", "number of epochs, an integer in [1, 1000000] (" + r + "release 50, qdo 50)"),
          opt("steps-per-epoch", "optimiser steps per epoch, an integer in [1, 1000000] (" + r + "release 418, qdo 10)"),
          opt("t0", "epoch where the quantization temperature schedule starts, in [0, 1e6] (default: 0.1 x epochs; recipe qdo: min(5, 0.1 x epochs))"),
          opt("t1", "epoch where the quantization temperature schedule ends, in [0, 1e6] and > --t0 (default: 0.8 x epochs)"),
          opt("lr", "learning rate of the optics parameters, in [0, 1] (" + r + "0.01)"),
          opt("lr-offsets", "learning rate of the adaptive level offsets (qdo+a), in [0, 1] (" + r + "0.01)"),
          opt("decay", "learning-rate decay factor per decay period, in (0, 1] (" + r + "0.8)"),
          opt("decay-steps", "decay period: a number of steps >= 1, or epoch (" + r + "release 500, qdo epoch)"),
          opt("decay-staircase", "on: decay in whole periods; off: continuously (" + r + "release off, qdo on)"),
          opt("adam-eps", "Adam's epsilon, in (0, 1] (" + r + "release 1e-7, qdo 1e-8)"),
          opt("adam-form", "Adam's epsilon form: keras (TF's epsilon hat) or textbook (" + r + "release keras, qdo textbook)"),
          opt("beta", "weight of the adaptive-quantization regulariser (qdo+a), in [0, 1000] (" + r + "0.01)"),
          opt("aq-domain", "what the adaptive-quantization regulariser averages over: parameters (a radial design's rings) or "
                           "pixels (" + r + "release parameters, qdo pixels)"),
          opt("pinned-level", "which level's offset is fixed in qdo+a: top (the release's unetched level) or bottom (" + r +
                              "release top, qdo bottom)"),
          opt("height-noise-nm", "half-width of the uniform fabrication height noise on every training step, nm, in [0, 10000] (" + r +
                                 "release 20, qdo 0)"),
          opt("noise-at-test", "on: the height noise also on the PSF the evaluation measures through (" + r + "release on, qdo off)"),
          noise_sigma("sensor noise std of the decoder's training data, in units of full scale, in [0, 10] (" + r + "0.001)", ""),
          opt("noise-at", "where a network's training noise enters: bands (each band on the DOE grid, before the response and the "
                          "sensor's area resampling) or rgb (each sensor pixel) (" + r + "release bands, qdo rgb)"),
          opt("patches", "a network's training patches: fixed (per scene the whole scene resized and a 3 x 3 grid of crops, in "
                         "order, no augmentation) or random (random crops, flips, transposes) (" + r + "release fixed, qdo random)"),
          opt("batch-norm", "a network's batch-norm constants: keras (momentum 0.99 in Keras' terms, eps 1e-3) or torch (0.1, "
                            "1e-5) (" + r + "release keras, qdo torch)"),
          opt("final-init", "initialiser of a network's last convolution: glorot or he (uniform) (" + r + "release glorot, qdo he)"),
          opt("init", "initial design: random, flat, half (u = 0.5, the release's) or lens:NM (" + r + "release half, qdo random)"),
          seed(),
          synthetic_scenes("12"),
          opt("batch", "scenes per optimiser step, an integer in [1, 100000]", "4"),
          opt("psf-path", "PSF engine of the optimisation: auto (radial for radial designs), 2d or radial (radial designs only; its "
                          "height noise is drawn per ring) (" + r + "release 2d, qdo auto)"),
          opt("wiener-on", "where the wiener objective runs: device (OpenCL, the run's precision) or cpu (double, the reference)",
              "device"),
          opt("decoder", "decoder trained with the optics: wiener (closed form), resunet (depth 4, root 16), resunet:paper "
                         "(depth 7, root 32) or resunet:depth=D,root=R (needs the qdo tool built with LibTorch)", DecoderSpec{}.to_string()),
          opt("lr-decoder", "learning rate of the network decoder, in (0, 1] (do-finetune: default the do run's last) (" + r + "0.001)"),
          opt("gamma", "weight decay gamma of the network's convolution weights (Eq. 14), in [0, 1000] (" + r + "release 0, qdo 0.0001)")};
}

std::vector<OptionSpec> concat(std::vector<OptionSpec> a, const std::vector<OptionSpec>& b) {
  a.insert(a.end(), b.begin(), b.end());
  return a;
}

std::vector<CommandSpec> make_table() {
  std::vector<CommandSpec> t;
  t.push_back({"devices", "list the OpenCL platforms and devices and the default choice", "", "", {}, cmd_devices});
  t.push_back({"config", "print the system configuration as JSON", "", "", {preset(), config()}, cmd_config});
  t.push_back({"data", "where qdo looks for datasets and what it finds: each dataset's scenes, formats, shapes, value ranges, "
                       "sizes and checksums, and the known ones that are missing", "", "",
               {data_root(), opt("bands", "bands expected in each scene, an integer in [1, 1024]", "31"),
                flag("quick", "leave the value ranges out (the cubes are not read; shapes come from the file headers)")},
               cmd_data});
  t.push_back({"psf", "compute a design's PSF stack: DIR/psf.h5 (the sensor-grid stack; points x bands x S x S with several "
                      "object points, and points.csv), psf.png, design.png", "", "",
               {preset(), config(), design_spec(), levels_post(), placement(),
                object_distances("several object points", "all computed in one batched pass"), field_angles("several object points"),
                precision(), device(), save_opt(), compress(), out_dir_opt()},
               cmd_psf});
  t.push_back({"calibrate",
               "measured PSFs from captures: a folder of point-source frames, one per band (16-bit PNG or TIFF, psf_<nm>nm.png), "
               "and dark frames -> DIR/psf.h5 (the layout of qdo psf), psf.png; with --design compare.csv, compare.png",
               "", "",
               {preset(), config(), opt("frames", "folder of PSF frames: 16-bit grayscale PNG or TIFF raw frames named <anything>_<nm>nm.png|.tif, one "
                                                  "or more per configured band (several of one band are exposures, averaged) (required)"),
                opt("darks", "folder of dark frames (16-bit grayscale PNG or TIFF, same exposure; averaged) (required)"),
                opt("white", "folder of white (flat-field) frames: a uniformly lit, spectrally flat white target filling the view, the "
                             "frames' size (averaged, dark subtracted); every frame is divided by its white signal over the white's "
                             "mean (colour gains and pixel response measured; psf.h5 /white_channel_gains) (default: none)"),
                opt("design", "design to compare with: lens:NM, flat, a design .h5 file or a run folder (its design.h5)"),
                opt("hot-sigma", "hot-pixel threshold, in noise sigmas (> 1)", "8"),
                opt("min-snr", "least peak SNR (peak above the dark / noise sigma) of a band; a darker frame is refused", "20"),
                opt("min-response", "least relative response, in (0, 1], of a mosaic colour at a band for its pixels to count as "
                                    "a measurement (weaker ones get the estimate of their neighbours; the rest are used, each "
                                    "weighted by its noise)", "0.005"),
                opt("floor-sigma", "signal-mask threshold: pixels whose 5 x 5 mean is below this many sigmas of its noise (and not within 2 px of one above) are set to 0", "4"),
                opt("background", "background removed after the dark: ring (the median of the S x S crop's outer 2-pixel ring) "
                                  "or none (the dark only; for a PSF with energy out to the crop's edge)",
                    "ring"),
                opt("centre", "ROW,COL: the frame pixel of the optical axis (default: the centroid of all bands)"),
                precision(), device(), out_dir_opt()},
               cmd_calibrate});
  t.push_back({"fit",
               "the as-built DOE: fit a design's level depths (or mask depths, or a height scale), DOE-sensor distance, object "
               "distance, lateral offset and aperture to a measured PSF stack by Levenberg-Marquardt through the adjoints -> "
               "DIR/fit.h5, fit.json (values, 1-sigma, correlation, residual per band), design.h5 (as built), config.json, fit.png, "
               "residual.png",
               "", "",
               {preset(), config(),
                opt("design", "the design that was built: a design .h5 file (its /levels_m defines each pixel's level), a run folder "
                              "(its design.h5), lens:NM or flat (required)"),
                opt("psf", "the measured PSF stack: psf.h5 as qdo calibrate (or qdo psf) writes it, for the configuration's bands and "
                           "sensor grid (checked) (required)"),
                opt("fit", "parameters, comma-separated: levels (the L-1 depths of levels 1..L-1, m; level 0 held: a piston is "
                           "invisible), masks (the log2 L mask depths of a qdo+m design, m), scale (one factor on all heights; not with "
                           "levels or masks), z (DOE-sensor distance, m), d (object distance, m; nearly degenerate with z, so not in the "
                           "default), offset (dx, dy: the relief against the aperture, m), shift (sx, sy: registration of the measured "
                           "stack, sensor px; a nuisance), aperture (radius, m, by a walk of the loss in half-pixel steps) (default: levels,z,offset for a "
                           "quantized design, else scale,z,offset)"),
                opt("iterations", "most Levenberg-Marquardt iterations, an integer in [1, 1000]", "30"),
                opt("lateral-starts", "auto: scans of the offset along x, then y, twice, an eighth of a DOE pixel apart, over the "
                                      "centroid's reach plus 1.5 DOE px, and the mirrors of the lowest (a DOE's PSF has narrow mirror "
                                      "minima the centroid start does not tell apart; the shift alone: a grid half a sensor px apart); "
                                      "K: a K x K grid over the centroid's reach plus 1 sensor px; 1: the centroid difference alone; "
                                      "auto or an integer in [1, 15]", "auto"),
                opt("refine-starts", "M: short fits (3 iterations) from M starts in different basins (the lowest, its "
                                     "mirrors, the next lowest), the fit going on from the lowest; 1: the lowest start alone; "
                                     "an integer in [1, 16]", "4"),
                opt("start", "NAME=VALUE,...: start values of fitted parameters by the names the fit prints (level1, z, dx, sx, ...), "
                             "lengths in metres or with a unit (550nm, 1.5um, 12.5mm), sx and sy in sensor px, scale plain; bounded by "
                             "the aperture, the sensor window, a factor 10 on z and d (default: the design's, the centroid for offset or shift)"),
                opt("tolerance", "stop when an accepted step lowers the loss by less than this fraction, in [0, 1]", "1e-7"),
                opt("precision", "floating-point precision on the device: f32 or f64 (the fit's central differences want f64)", "f64"),
                device(), out_dir_opt()},
               cmd_fit});
  t.push_back({"quantize", "quantize a design to L levels (post-hoc, uniform) into a design .h5 file", "", "",
               {preset(), config(), design_spec(), opt("levels", "number of height levels L, an integer in [2, 65536] (required)"),
                placement(), opt("out", "output design .h5 file")},
               cmd_quantize});
  t.push_back({"simulate", "the RGB sensor image of a scene through a design: DIR/sensor.h5, sensor.png, scene.png, psf.*; with --raw also "
               "the raw capture (raw.png, raw.h5); with --capture psf-sweep a simulated calibration sweep for qdo calibrate",
               "", "",
               {preset(), config(), design_spec(), psf_file(), levels_post(), placement(), scene(), key(), resample_bands(),
                opt("formation",
                    "image formation: qdo (the configuration's convolution on the sensor grid, area-sampled PSF) or release "
                    "(the paper release's: bilinear up, mirror padding, PSF one 4 um sample off centre, bilinear down; "
                    "a square scene, N >= S + 2; pair it with \"aperture_edge\": \"strict\")",
                    "qdo"),
                flag("raw", "also write the capture as the sensor as built records it (the configuration's cfa, black_level_dn, "
                            "gain, bit_depth 8 .. 16, noise): raw.png (16-bit, DN), raw.h5 (/raw, and /rgb_demosaiced), "
                            "raw_demosaiced.png; needs a mosaic and a bit depth"),
                opt("demosaic", "demosaic of the --raw capture: bilinear or mhc (Malvar-He-Cutler 5 x 5)", "mhc"),
                opt("capture", "what to capture: scene (the --scene image) or psf-sweep (a point source at every configured band "
                               "through the sensor as built, and dark frames, for qdo calibrate: DIR/frames/psf_<nm>nm.png, "
                               "darks/dark_<k>.png, psf.h5 the stack imaged, sweep.h5, frames.png)",
                    "scene"),
                opt("frame-size", "psf-sweep: frame size F (F x F pixels), an integer in [S, 8192], S the sensor PSF size "
                                  "(default: S + 64)"),
                opt("peak", "psf-sweep: peak exposure of each band's brightest colour, a fraction of full well in (0, 1]", "0.6"),
                opt("darks", "psf-sweep: number of dark frames, an integer in [1, 1000]", "8"),
                opt("centre", "psf-sweep: ROW,COL, the frame pixel of the optical axis, so that the S x S PSF window lies "
                              "inside the frame (default: F/2,F/2)"),
                opt("depth", "FILE[:KEY]: a depth map of the scene, H x W metres, for a depth-layered image: an HDF5 dataset "
                             "(KEY, default /depth_m; values > 0, or inf for infinitely far) or a 16-bit PNG (codes times "
                             "--depth-scale; code 0 = infinitely far), or builtin (the built-in chart's: patch rows at 4z, 8z, 16z, "
                             "32z, z the DOE-sensor distance, the rest at infinity); every pixel takes the PSF of its nearest layer "
                             "in diopters; writes also depth.png, depth.h5, psf_points.h5, varying.json; not with --psf, --raw, "
                             "--field-grid"),
                opt("depth-scale", "--depth FILE.png: metres per PNG code, a number > 0", "0.001"),
                opt("depth-layers", "--depth: the layers D1,D2,... in metres > 0 or inf (default: the map's distinct values when "
                                    "at most 8, else 8 layers evenly spaced in diopters between its nearest and farthest); "
                                    "PSFs are computed at the layers some pixel uses only"),
                opt("psf-placement", "--depth / --field-grid: source (each scene pixel emits through its own PSF) or output "
                                     "(each sensor pixel takes the image blurred with its own PSF: the release's per-depth rule)",
                    "source"),
                opt("field-grid", "NX[xNY]: a field-dependent PSF from an NX x NY grid of field angles (integers in [1, 31]) up "
                                  "to the field edge, the image interpolated bilinearly between neighbouring points' recentred "
                                  "PSFs; points whose hats miss the scene are not computed; 1 = the on-axis PSF"),
                opt("field-edge-deg", "--field-grid: the outermost field angle in degrees, in (0, the sampling limit] "
                                      "(default: min(atan(half the scene's extent on the sensor / z), atan(a quarter of the N x N window / z), the "
                                      "sampling limit); beyond the default, PSFs near the window's edge lose energy (the "
                                      "sampling line says how much)"),
                opt("field-rank", "--field-grid: use the R leading components of the field PSFs (low-rank form), an integer in "
                                  "[1, computed points] (default: all points, no low-rank form)"),
                precision(), device(), save_opt(), compress(), out_dir_opt()},
               cmd_simulate});
  t.push_back({"demo", "QDO+A against conventional deep optics (DO) at L levels, designed and evaluated end to end", "", "",
               {opt("preset", "system preset: paper or small", "small"), opt("levels", "height levels L, an integer in [2, 65536]", "4"),
                opt("epochs", "epochs per design, an integer in [2, 100000] (default: 15; 8 with a network decoder)"),
                opt("steps-per-epoch", "optimiser steps per epoch, an integer in [1, 100000] (default: 8; 50 with a network decoder)"),
                opt("decoder", "decoder: wiener (closed form, trained on synthetic scenes) or a network spec (resunet, ...; "
                               "trained with the optics on --train-data; about 10 minutes on 2 cores with resunet)", DecoderSpec{}.to_string()),
                opt("train-data", "training scenes of the network decoder: dataset names under the data root or paths, "
                                  "comma-separated (each must exist)", "cave_train,cave_png"),
                opt("finetune-steps", "network decoder: do-finetune steps (doft/), an integer in [1, 100000000]", "100"),
                opt("data", "real test scenes: a dataset name under the data root or a path; none leaves the real-scene rows out", "cave"),
                data_root(), precision(), device(),
                opt("out", "output folder (created; its qdoa/ and do/ (and doft/) run folders are replaced)", "out/demo")},
               cmd_demo, true});
  t.push_back({"design", "optimise a design end to end into a run folder (resumable)", "", "",
               concat({preset(), config(),
                       opt("mode", "design mode: full, do, qdo, ste, qdo+a, qdo+m, or do-finetune (with --from: a network do run's "
                                   "network trained on with its DOE quantized to --levels and frozen)", "qdo+a"),
                       opt("levels", "height levels L, an integer in [2, 65536]", "4"), placement(),
                       parameterization(), objective(), target(), data("training scenes (default: synthetic scenes)"), data_root(),
                       opt("from", "do-finetune: the finished network do run folder to fine-tune"),
                       opt("finetune-steps", "do-finetune: network steps with the DOE frozen, an integer in [1, 100000000]", "200"),
                       opt("psf", "do-finetune for the camera as built: a measured PSF stack (qdo calibrate's psf.h5, for the run's "
                                  "bands and sensor grid; checked) frozen in place of the do run's quantized DOE; not with --levels"),
                       opt("design", "do-finetune for the camera as built: a fitted as-built design .h5 (N x N at the run's pitch), "
                                     "its simulated PSF frozen in place of the do run's quantized DOE; not with --levels or --psf"),
                       object_distances("design over a range", "the training conditions of the run"), field_angles("design over a range"),
                       opt("points-per-step", "object points each optimiser step trains on, drawn anew each step (seeded), an integer "
                                              "in [1, P] for P object points (P: every point every step)", "1")},
                      concat(training_options(),
                             {opt("checkpoint-every", "steps between checkpoints, an integer in [1, 100000000]", "10"),
                              opt("max-steps", "stop after N steps in this session, resumable, an integer >= 0 (default: no limit)"),
                              flag("resume", "continue the run in --out with its stored options"),
                              flag("check-gradients", "run the gradient check on this configuration first"), precision(), device(),
                              opt("out", "run folder (config.json checkpoint.h5 log.csv design.h5 psf.h5 *.png)")})),
               cmd_design, true});
  t.push_back({"gradcheck", "check the analytic gradients against finite differences (exit 5 on failure)", "", "",
               {preset(), config(), mode(), opt("levels", "height levels L, an integer in [2, 65536]", "4"), placement(),
                parameterization(), objective(), target(), seed(), device(), psf_path(),
                opt("wiener-on", "where the wiener objective's device row is checked: device (default) or cpu (no such row)", "device")},
               cmd_gradcheck});
  t.push_back({"eval", "evaluate a run's design: metrics, reconstructions and figures", "RUN", "run folder written by qdo design",
               {data("test scenes (default: synthetic scenes)"), data_root(),
                opt("levels", "re-quantize the full-precision design to L levels, an integer in [2, 65536] (default: the run's)"),
                placement(), opt("decoder", "decoder: matched (refit to the evaluated design) or mismatch (fit to the full-precision design)", "matched"),
                opt("decoder-kind", "the decoder that reconstructs: wiener, cg[:tolerance=T,max_iterations=N] (conjugate-gradient MAP) or "
                                    "another registered one (default: the run's own, its Wiener decoder or its trained network)"),
                opt("psf", "PSF stack file through which the scenes are measured in place of the design's PSF: psf.h5 as qdo psf "
                           "writes it (a measured stack in that layout), for the run's bands and sensor grid (checked); not with --levels"),
                opt("design", "a fitted as-built design .h5 (N x N at the run's pitch) whose simulated PSF measures the scenes in place "
                              "of the run's design (a matched Wiener decoder is refit for it); not with --psf or --levels"),
                noise_sigma("sensor noise std, in units of full scale, in [0, 10] (default: the run's)", ""),
                opt("pixels", "pixels whose spectra are plotted: y:x pairs, comma-separated"),
                opt("renders", "number of reconstructions rendered as PNG, an integer in [0, 1000]", "4"), synthetic_scenes("6"),
                precision(), device(), out_dir_opt()},
               cmd_eval});
  t.push_back({"eval-points", "a run's design against object distance and field angle: quality, depth of field and valid field of view",
               "RUN", "run folder written by qdo design",
               {opt("design", "a design .h5 (N x N at the run's pitch) evaluated in place of RUN/design.h5"),
                opt("distances", "object distances in metres, comma-separated, each > 0 or inf (a point at infinity); the "
                                 "nominal distance (--nominal) is always added", "0.3,0.5,0.7,1,1.5,2,3,5,10,inf"),
                opt("nominal", "the distance the camera is focused at, metres > 0 or inf: the mismatch decoder is built for "
                               "the PSF there and the field angles are evaluated there (default: the run's one object point, "
                               "else its scene_distance_m)"),
                opt("angles", "field angles along x in degrees, comma-separated, each in [0, the sampling limit at the nominal "
                              "distance] (default: 0 to the field edge, min(atan(half the sensor window / z), that limit), in "
                              "--angle-steps steps); 0 is always added"),
                opt("angle-steps", "steps of the default angle grid, an integer in [1, 1000]", "8"),
                data("test scenes (default: synthetic held-out scenes, as qdo eval)"), data_root(), synthetic_scenes("6"),
                opt("fov-tolerance", "largest model error ||I_theta - I_0|| / ||I_0|| (field-dependent image against the "
                                     "shift-invariant model's) inside the valid field of view, a number in (0, 10]; 0.05: a 5 % "
                                     "relative image error, about 26 dB of model PSNR", "0.05"),
                opt("dof-margin-db", "depth of field: the distances where the mismatch PSNR stays within this many dB of the "
                                     "nominal's, a number in (0, 100]", "1"),
                noise_sigma("sensor noise std, in units of full scale, in [0, 10] (default: the run's)", ""),
                opt("decoder-kind", "decoder built from the PSF: wiener (default) or cg[:tolerance=T,max_iterations=N]", DecoderSpec{}.to_string()),
                precision(), device(), out_dir_opt()},
               cmd_eval_points});
  t.push_back({"image", "the RGB sensor image of one scene with the skipping rules of Camera and a skip report", "", "",
               {preset(), config(), design_spec(), psf_file(), levels_post(), placement(), scene(), key(), resample_bands(), precision(),
                device(), opt("tolerance", "error bound of the skipped work, in units of full scale, in [0, 1]", "3e-7"),
                flag("exact", "skip nothing"), opt("tiles", "tiled convolution: off, on or auto", "off"),
                opt("tile-px", "tile size in sensor pixels, an integer in [8, 4096]", "64"), out_dir_opt()},
               cmd_image});
  t.push_back({"export", "lithography mask set of a design (GDSII and figures)", "RUN|DESIGN.h5",
               "run folder written by qdo design, or a design .h5 file",
               {opt("scheme", "mask scheme: binary, nested or greyscale", "binary"), out_dir_opt(),
                opt("preset", "system preset for a DESIGN.h5: paper or small (omit with a run folder)", "small"),
                opt("config", "system configuration JSON file for a DESIGN.h5 (omit with a run folder)"),
                opt("min-feature-um", "minimum feature size in um, in (0, 10000]", "1"),
                opt("max-levels", "maximum number of height levels, an integer in [0, 65536] (0: no limit)", "0"),
                opt("max-height-nm", "maximum etch depth in nm, in [0, 1e6] (0: no limit)", "0"),
                opt("dose-curve", "greyscale dose curve CSV file (default: linear)"),
                opt("tolerance-nm", "tolerance when matching heights to levels, in nm, in [0, 1000]", "0.001")},
               cmd_export});
  t.push_back({"tolerance", "Monte Carlo over fabrication errors of a run's design", "RUN", "run folder written by qdo design",
               {opt("etch-depth-error-nm", "etch depth error std in nm, in [0, 10000]", "20"), opt("overlay-um", "mask overlay error std in um, in [0, 1000]", "0.5"),
                opt("edge-blur-um", "edge blur in um, in [0, 1000]", "0"), opt("height-noise-nm", "height noise std in nm, in [0, 10000]", "0"),
                opt("trials", "trials per scenario, an integer in [1, 100000]", "16"), seed(),
                opt("scheme", "mask scheme: auto, binary, nested or greyscale", "auto"),
                opt("oversample", "mask oversampling, an integer in [1, 16]", "4"), data("test scenes (default: synthetic scenes)"), data_root(),
                synthetic_scenes("6"), noise_sigma("sensor noise std, in units of full scale, in [0, 10] (default: the run's)", ""),
                flag("no-per-source", "skip the scenarios of one error source at a time"),
                flag("save-psfs", "write every trial's PSF stack to psfs.h5"), precision(), device(), out_dir_opt()},
               cmd_tolerance});
  t.push_back({"fabricate",
               "one camera as built, for simulating it: the design's masks made with one draw of qdo tolerance's errors, the relief "
               "offset against the aperture, the DOE-sensor distance changed -> DIR/design.h5, config.json, truth.json (the true "
               "values in qdo fit's names), heights.png, height_error.png",
               "RUN|DESIGN.h5", "run folder written by qdo design, or a design .h5 file",
               {opt("preset", "system preset for a DESIGN.h5: paper or small (omit with a run folder)", "small"),
                opt("config", "system configuration JSON file for a DESIGN.h5 (omit with a run folder)"),
                opt("scheme", "mask scheme: auto (binary when possible, else nested), binary, nested or greyscale", "auto"),
                opt("etch-depth-error-nm", "etch depth error bound per mask, uniform in [-S, S], nm, in [0, 10000]", "20"),
                opt("overlay-um", "overlay error bound per mask after the first and per axis, uniform in [-S, S], um, in [0, 1000]", "0.5"),
                opt("edge-blur-um", "edge blur (Gaussian sigma) of every mask, um, in [0, 1000]", "0"),
                seed(), opt("trial", "which draw of the seed's sequence (qdo tolerance's trial index), an integer in [0, 100000]", "0"),
                opt("oversample", "mask oversampling, an integer in [1, 16]", "4"),
                opt("offset-um", "DX,DY: the whole relief moved against the aperture after the masks, um (x along columns)", "0,0"),
                opt("sensor-distance-error-um", "added to the DOE-sensor distance (assembly), um, in [-1e6, 1e6]; z must stay > 0", "0"),
                out_dir_opt()},
               cmd_fabricate});
  t.push_back({"sweep", "a grid of designs (levels x modes x encoders), each designed and evaluated, with summary tables", "", "",
               concat({{"grid", "a grid axis AXIS=V1,V2,...: levels=2,4,8; mode=do,do-refit,do-finetune,qdo,qdo+a; "
                                "encoder=doe,fresnel,cassi; decoder=wiener,resunet; seed=1,2,3 (repeatable)",
                        "", false, true},
                       opt("finetune-steps", "do-finetune with a network decoder: network steps with the DOE frozen, an integer in [1, 100000000]", "100"),
                       preset(), config(), placement(), parameterization(), objective(),
                       data("training scenes (default: synthetic scenes)"), data_root(),
                       opt("test-data", "test scenes: dataset names under the data root, CAVE folders, cube files or folders of "
                                        "them, comma-separated (default: synthetic)"),
                       opt("eval-scenes", "synthetic test scenes, an integer in [1, 10000]", "4"),
                       opt("seeds", "N seeds as a grid axis: --seed, --seed + 1, ..., an integer in [1, 1000] (or --grid seed=S1,S2,...)"),
                       flag("plan", "print the grid's cells (index, name, mode, levels, seed, runs) and exit: nothing is run or written"),
                       opt("cell", "run cell K of --plan's list only (its runs, then its evaluation), no tables; K = slurm reads "
                                   "SLURM_ARRAY_TASK_ID"),
                       opt("shard", "run shard i/n of the cells only (cells i, i + n, ...), no tables"),
                       flag("collect", "write the tables from the finished cells only, naming any that are not finished")},
                      concat(training_options(), {precision(), device(), out_dir_opt()})),
               cmd_sweep, true});
  t.push_back({"sweep-psf", "PSF quality against the number of levels for one design", "", "",
               {opt("design", "a design .h5 file or a run folder"),
                opt("levels", "level counts, comma-separated integers in [2, 65536]", "2,4,8,16,32"), placement(),
                opt("adaptive-from", "also the adaptive levels of this qdo+a run folder"), preset(), config(), precision(), device(),
                opt("designs-per-pass", "designs per device pass, an integer in [0, 1000] (0: automatic)", "0"), out_dir_opt()},
               cmd_sweep_psf, true});
  t.push_back({"reconstruct",
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
               cmd_reconstruct});
  // Every command that writes an output folder takes --into-existing (claim_output_dir, io.hpp).
  for (CommandSpec& c : t) {
    const bool folder_out = std::any_of(c.options.begin(), c.options.end(), [](const OptionSpec& o) { return o.name == "out"; });
    if (folder_out && c.name != "quantize")
      c.options.push_back(flag("into-existing", "write into an existing --out folder that qdo did not make, or that another qdo "
                                                "command made (files of the names this command writes are replaced)"));
  }
  return t;
}

}  // namespace

const std::vector<CommandSpec>& command_table() {
  static const std::vector<CommandSpec> t = make_table();
  return t;
}

}  // namespace qdo::cli
