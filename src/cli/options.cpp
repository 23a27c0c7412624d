// The options several commands share, each declared once (name, description with units and
// allowed values, default, flag or not); each command's own options are declared with the command,
// in its cmd_*.cpp file.
#include <string>
#include <vector>

#include "cli.hpp"
#include "qdo/decode/decoder_spec.hpp"

namespace qdo::cli::opts {

OptionSpec opt(const std::string& name, const std::string& help, const std::string& def) { return {name, help, def, false, false}; }
OptionSpec flag(const std::string& name, const std::string& help) { return {name, help, "", true, false}; }

OptionSpec preset() { return opt("preset", "system preset: paper or small (omit with --config)", "small"); }
OptionSpec config() { return opt("config", "system configuration JSON file (instead of --preset)"); }
OptionSpec device() {
  return opt("device", "OpenCL device: gpu, cpu, P:D as 'qdo devices' prints, or a substring of the device name "
                       "(default: $QDO_DEVICE, else the first GPU, else the first CPU)");
}
OptionSpec model_padding() {
  return opt("model-padding", "the model's zero padding per side: auto (raise the configuration's padding_px, never lower it, until the "
                              "transfer function is sampled in every band up to 5 % beyond the DOE-sensor distance: a built camera's "
                              "model, where the presets keep the paper's under-sampled window), config (the configuration's), or "
                              "an integer in [0, 4 n]", "auto");
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
OptionSpec seed() { return opt("seed", "random seed, an integer in [0, 2147483647]", "0"); }
OptionSpec parameterization() { return opt("parameterization", "height map parameterization: radial, quad or 2d", "radial"); }
OptionSpec objective() {
  return opt("objective", "design objective: wiener, wiener-mse, wiener-mae, psf-target or network (default: wiener; network with a network --decoder)");
}
OptionSpec target() { return opt("target", "PSF target for --objective psf-target: lens:NM or a design .h5 file", "lens:550"); }

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
          opt("noise-sigma", "sensor noise std of the decoder's training data, in units of full scale, in [0, 10] (" + r + "0.001)"),
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
          opt("decoder", "decoder trained with the optics: wiener (closed form), resunet (depth 4, root 16), resunet:paper (depth 7, "
                         "root 32), resunet:depth=D,root=R (these need LibTorch) or a registered decoder that trains", DecoderSpec{}.to_string()),
          opt("lr-decoder", "learning rate of the network decoder, in (0, 1] (do-finetune: default the do run's last) (" + r + "0.001)"),
          opt("gamma", "weight decay gamma of the network's convolution weights (Eq. 14), in [0, 1000] (" + r + "release 0, qdo 0.0001)")};
}

std::vector<OptionSpec> frame_reduction_options() {
  return {opt("hot-sigma", "hot-pixel threshold, in noise sigmas (> 1)", "8"),
          opt("min-snr", "least peak SNR (peak above the dark / noise sigma) of a band; a darker frame is refused", "20"),
          opt("min-response", "least relative response, in (0, 1], of a mosaic colour at a band for its pixels to count as a "
                              "measurement (every colour that responds is used, each weighted by its noise)", "0.005")};
}

std::vector<OptionSpec> concat(std::vector<OptionSpec> a, const std::vector<OptionSpec>& b) {
  a.insert(a.end(), b.begin(), b.end());
  return a;
}

}  // namespace qdo::cli::opts
