// The recipe table (recipe.hpp): each item's option, its value in each recipe, and how it sets a
// DesignRunOptions field. The command line (src/cli) takes its defaults from here.
#include "qdo/design/recipe.hpp"

#include <algorithm>
#include <cstdlib>
#include <map>

#include "qdo/runtime/error.hpp"

namespace qdo {

namespace {

double number(const std::string& v) { return std::strtod(v.c_str(), nullptr); }
bool on(const std::string& v) { return v == "on"; }

using Setter = std::function<void(DesignRunOptions&, const std::string&)>;

const std::map<std::string, Setter>& setters() {
  static const std::map<std::string, Setter> t = {
      {"epochs", [](DesignRunOptions& o, const std::string& v) { o.epochs = std::size_t(number(v)); }},
      {"steps-per-epoch", [](DesignRunOptions& o, const std::string& v) { o.design.steps_per_epoch = std::size_t(number(v)); }},
      {"lr", [](DesignRunOptions& o, const std::string& v) { o.design.lr_optics = number(v); }},
      {"lr-offsets", [](DesignRunOptions& o, const std::string& v) { o.design.lr_offsets = number(v); }},
      {"lr-decoder", [](DesignRunOptions& o, const std::string& v) { o.lr_decoder = number(v); }},
      {"decay", [](DesignRunOptions& o, const std::string& v) { o.design.lr_decay_per_epoch = number(v); }},
      {"decay-steps", [](DesignRunOptions& o, const std::string& v) { o.design.lr_decay_steps = v == "epoch" ? 0.0 : number(v); }},
      {"decay-staircase", [](DesignRunOptions& o, const std::string& v) { o.design.lr_staircase = on(v); }},
      {"adam-eps", [](DesignRunOptions& o, const std::string& v) { o.design.adam_epsilon = number(v); }},
      {"adam-form", [](DesignRunOptions& o, const std::string& v) { o.design.adam_keras_form = v == "keras"; }},
      {"init", [](DesignRunOptions& o, const std::string& v) { o.init = init_spec_from_string(v, "--init"); }},
      {"aq-domain", [](DesignRunOptions& o, const std::string& v) { o.design.aq_domain = aq_domain_from_string(v, "--aq-domain"); }},
      {"pinned-level", [](DesignRunOptions& o, const std::string& v) { o.design.quantizer.pin_top = v == "top"; }},
      {"beta", [](DesignRunOptions& o, const std::string& v) { o.design.beta_aq = number(v); }},
      {"height-noise-nm", [](DesignRunOptions& o, const std::string& v) { o.design.height_noise_m = number(v) * 1e-9; }},
      {"noise-at-test", [](DesignRunOptions& o, const std::string& v) { o.height_noise_at_test = on(v); }},
      {"psf-path", [](DesignRunOptions& o, const std::string& v) { o.design.psf_path = psf_path_from_string(v); }},
      {"gamma", [](DesignRunOptions& o, const std::string& v) { o.gamma_decoder = number(v); }},
      {"noise-sigma", [](DesignRunOptions& o, const std::string& v) { o.decoder_noise_sigma = number(v); }},
      {"noise-at", [](DesignRunOptions& o, const std::string& v) { o.sampling.noise_on_bands = v == "bands"; }},
      {"patches", [](DesignRunOptions& o, const std::string& v) { o.sampling.fixed_patches = v == "fixed"; }},
      {"batch-norm", [](DesignRunOptions& o, const std::string& v) { o.network_style.keras_batch_norm = v == "keras"; }},
      {"final-init", [](DesignRunOptions& o, const std::string& v) { o.network_style.glorot_final = v == "glorot"; }},
  };
  return t;
}

}  // namespace

const std::vector<std::string>& recipe_names() {
  static const std::vector<std::string> n = {"release", "qdo"};
  return n;
}

const std::vector<RecipeItem>& recipe_items() {
  static const std::vector<RecipeItem> t = {
      {"epochs", "50", "50", "epochs (release: 50)"},
      {"steps-per-epoch", "418", "10", "steps per epoch (release: 1672 patches / batch 4 = 418)"},
      {"lr", "0.01", "0.01", "Adam learning rate of the DOE weights w in [-1, 1]"},
      {"lr-offsets", "0.01", "0.01", "Adam learning rate of the level offsets (the release: the same optimiser as w)"},
      {"lr-decoder", "0.001", "0.001", "Adam learning rate of a network decoder"},
      {"decay", "0.8", "0.8", "learning-rate factor per decay period"},
      {"decay-steps", "500", "epoch", "decay period in steps (epoch: one epoch)"},
      {"decay-staircase", "off", "on", "on: the factor applies whole periods (floor); off: continuously (ExponentialDecay)"},
      {"adam-eps", "1e-7", "1e-8", "Adam's epsilon"},
      {"adam-form", "keras", "textbook", "where epsilon enters: keras (added to sqrt(v) before bias correction) or textbook"},
      {"init", "half", "random", "initial design: half (w = 1e-4 on the release's etch axis, u = 0.5) or random heights"},
      {"aq-domain", "parameters", "pixels", "what L_aq averages over: the ring profile (parameters) or the N x N pixels"},
      {"pinned-level", "top", "bottom", "which level's offset is fixed: top (the release's unetched level 0) or bottom"},
      {"beta", "0.01", "0.01", "weight of L_aq"},
      {"height-noise-nm", "20", "0", "half-width of the uniform fabrication height noise, nm, on every training step"},
      {"noise-at-test", "on", "off", "the same height noise on the PSF of the evaluation's measurements"},
      {"psf-path", "2d", "auto", "PSF engine: 2d draws the height noise per pixel, as the release; the radial engine can only per ring"},
      {"gamma", "0", "0.0001", "network weight decay (the release's L2 regulariser is never added to its loss)"},
      {"noise-sigma", "0.001", "0.001", "sensor noise std of the network's training images (noise-at: where it is added)"},
      {"noise-at", "bands", "rgb", "where the network's training noise enters: bands (on the band image on the DOE grid, before the "
                                   "response and the area resampling) or rgb (on the sensor image)"},
      {"patches", "fixed", "random", "the network's training patches: fixed (per scene the whole scene resized and a 3 x 3 grid of "
                                     "crops, in order, no augmentation) or random (crops with flips and transposes)"},
      {"batch-norm", "keras", "torch", "the network's batch-norm constants: keras (momentum 0.99 in Keras' convention, eps 1e-3) or "
                                       "torch (momentum 0.1, eps 1e-5)"},
      {"final-init", "glorot", "he", "the initialiser of the network's last 1x1 convolution: glorot (uniform) or he (uniform)"},
  };
  return t;
}

const std::vector<std::string>& recipe_gaps() {
  static const std::vector<std::string> g = {
      "ring geometry: the release centres its rings on a pixel corner (r from (N/2 - 0.5, N/2 - 0.5) samples) and leaves "
      "pixels with r >= N/2 - 1 unetched; qdo centres rings on sample (N/2, N/2) and extends the last ring to the corners",
      "rounding: the release rounds half to even (tf.round), qdo half up; they differ only at exact ties",
      "sensor noise in training: the release draws it on the 4 um band image before a bilinear 2x downsampling; qdo draws "
      "the same distribution (srf * n per sensor pixel, n of std sigma / 2 per band) on the sensor grid, not the same numbers",
      "sensor noise at test: the release images its test patches without noise (training only); qdo's evaluations add "
      "sigma on RGB for every decoder, so a network and the Wiener decoder are scored under the same noise",
      "batch norm's running variance: Keras keeps the batch's biased variance, torch the unbiased one (a factor "
      "n / (n - 1), n = batch x H x W, about 1 + 1.5e-5 at 4 x 128 x 128)",
      "data: the release trains on ICVL (167 scenes, 1,672 patches, 418 steps per epoch); qdo's runs use CAVE, whose "
      "fixed patches number 10 per scene",
  };
  return g;
}

std::string recipe_value(const std::string& name, const std::string& option, const std::string& argument) {
  const auto& names = recipe_names();
  if (std::find(names.begin(), names.end(), name) == names.end()) reject(argument, name, "one of release, qdo");
  for (const RecipeItem& it : recipe_items())
    if (it.option == option) return name == "release" ? it.release : it.qdo;
  reject("recipe item", option, "an option the recipes set");
}

void apply_recipe(const std::string& name, DesignRunOptions& o, const std::function<bool(const std::string&)>& given) {
  const auto& names = recipe_names();
  if (std::find(names.begin(), names.end(), name) == names.end()) reject("recipe", name, "one of release, qdo");
  for (const RecipeItem& it : recipe_items()) {
    if (given(it.option)) continue;
    setters().at(it.option)(o, name == "release" ? it.release : it.qdo);
  }
  const double e = double(o.epochs);
  if (!given("t0")) o.design.t0_epochs = name == "release" ? 0.1 * e : std::min(5.0, 0.1 * e);
  if (!given("t1")) o.design.t1_epochs = 0.8 * e;
  o.recipe = name;
}

}  // namespace qdo
