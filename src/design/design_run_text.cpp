// A design run's options read from options as a user typed them, and its report
// (design_run_text.hpp).
#include "qdo/design/design_run_text.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <set>
#include <utility>

#include "qdo/design/option_inputs.hpp"
#include "qdo/design/recipe.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/strprintf.hpp"
#include "qdo/runtime/util.hpp"

namespace fs = std::filesystem;

namespace qdo {

namespace {

// qdo design's object-point options on o.cfg and o.design.points_per_step (object_points_from_options;
// --points-per-step in 1 .. P).
void range_options(const TextOptions& a, DesignRunOptions& o) {
  object_points_from_options(a, o.cfg);
  const SystemConfig& c = o.cfg;
  // With --resume the run's points are in its config.json, not here: check_resume_options compares
  // the value with the stored one.
  const std::size_t points = a.has("resume") ? 4096 : c.point_count();
  o.design.points_per_step = std::size_t(
      parse_int("--points-per-step", a.get("points-per-step", "1"), 1, int(std::min<std::size_t>(points, 4096))));
}

}  // namespace

DesignRunOptions design_run_options_from_options(const TextOptions& a, bool range) {
  DesignRunOptions o;
  o.cfg = config_from_options(a, range);
  if (range) range_options(a, o);
  o.design.mode = design_mode_from_string(a.get("mode", "qdo+a"));
  o.design.parameterization = parameterization_from_string(a.get("parameterization", "radial"));
  o.design.quantizer.levels = parse_int("--levels", a.get("levels", "4"), 2, 65536);
  o.design.quantizer.placement = placement_from_string(a.get("placement", "inclusive"));
  // The training recipe (qdo/design/recipe.hpp) gives every default below that it names; an option given
  // explicitly wins over it, and config.json records each value.
  const std::string recipe = a.get("recipe", "release");
  const auto rv = [&](const char* option) { return recipe_value(recipe, option, "--recipe"); };
  o.design.steps_per_epoch =
      std::size_t(parse_int("--steps-per-epoch", a.get("steps-per-epoch", rv("steps-per-epoch")), 1, 1000000));
  o.epochs = std::size_t(parse_int("--epochs", a.get("epochs", rv("epochs")), 1, 1000000));
  DesignRunOptions window;  // the recipe's alpha window for these epochs (apply_recipe's rule)
  window.epochs = o.epochs;
  apply_recipe(recipe, window, [](const std::string& option) { return option == "epochs"; });
  o.design.t0_epochs = parse_double("--t0", a.get("t0", to_str(window.design.t0_epochs)), 0, 1e6, "epochs");
  o.design.t1_epochs = parse_double("--t1", a.get("t1", to_str(window.design.t1_epochs)), 0, 1e6, "epochs");
  o.design.lr_optics = parse_double("--lr", a.get("lr", rv("lr")), 0, 1, "(Adam step on weights in [-1, 1])");
  o.design.lr_offsets =
      parse_double("--lr-offsets", a.get("lr-offsets", rv("lr-offsets")), 0, 1, "(Adam step on normalised offsets)");
  o.design.lr_decay_per_epoch =
      parse_double("--decay", a.get("decay", rv("decay")), 0, 1, "(factor per decay period)", true);
  const std::string decay_steps = a.get("decay-steps", rv("decay-steps"));
  o.design.lr_decay_steps =
      decay_steps == "epoch" ? 0.0 : parse_double("--decay-steps", decay_steps, 1, 1e9, "steps, or epoch", false);
  o.design.lr_staircase = parse_on_off("--decay-staircase", a.get("decay-staircase", rv("decay-staircase")));
  o.design.adam_epsilon = parse_double("--adam-eps", a.get("adam-eps", rv("adam-eps")), 0, 1, "", true);
  const std::string form = a.get("adam-form", rv("adam-form"));
  if (form != "keras" && form != "textbook") reject("--adam-form", form, "keras or textbook");
  o.design.adam_keras_form = form == "keras";
  o.design.aq_domain = aq_domain_from_string(a.get("aq-domain", rv("aq-domain")), "--aq-domain");
  const std::string pinned = a.get("pinned-level", rv("pinned-level"));
  if (pinned != "top" && pinned != "bottom") reject("--pinned-level", pinned, "top or bottom");
  o.design.quantizer.pin_top = pinned == "top";
  o.design.beta_aq = parse_double("--beta", a.get("beta", rv("beta")), 0, 1e3, "");
  o.design.height_noise_m =
      parse_double("--height-noise-nm", a.get("height-noise-nm", rv("height-noise-nm")), 0, 1e4, "nm") * 1e-9;
  o.height_noise_at_test = parse_on_off("--noise-at-test", a.get("noise-at-test", rv("noise-at-test")));
  // The network's recipe items: each a choice of two words, the first the release's.
  const auto choice = [&](const char* option, const char* release, const char* other) {
    const std::string v = a.get(option, rv(option));
    if (v != release && v != other) reject(std::string("--") + option, v, std::string(release) + " or " + other);
    return v == release;
  };
  o.sampling.noise_on_bands = choice("noise-at", "bands", "rgb");
  o.sampling.fixed_patches = choice("patches", "fixed", "random");
  o.network_style.keras_batch_norm = choice("batch-norm", "keras", "torch");
  o.network_style.glorot_final = choice("final-init", "glorot", "he");
  o.design.seed = std::uint64_t(parse_int("--seed", a.get("seed", "0"), 0, 2147483647));
  // PSF engine of the optimisation: auto (radial engine for radial designs), 2d or radial.
  o.design.psf_path = psf_path_from_string(a.get("psf-path", rv("psf-path")));
  if (o.design.psf_path == PsfPath::Radial && o.design.parameterization != Parameterization::Radial)
    reject("--psf-path", "radial", "auto or 2d unless --parameterization is radial");
  o.decoder = decoder_spec_from_string(a.get("decoder", DecoderSpec{}.to_string()));
  o.objective = a.has("objective")    ? objective_from_string(a.get("objective"), "--objective")
                : o.decoder.network() ? Objective::Network
                                      : Objective::Wiener;
  o.lr_decoder = parse_double("--lr-decoder", a.get("lr-decoder", rv("lr-decoder")), 0, 1, "", true);
  o.gamma_decoder = parse_double("--gamma", a.get("gamma", rv("gamma")), 0, 1e3, "");
  o.target = target_spec_from_string(a.get("target", "lens:550"), "--target");
  o.data = scene_paths_from_options(a, "data");
  o.synthetic_scenes = std::size_t(parse_int("--synthetic-scenes", a.get("synthetic-scenes", "12"), 1, 100000));
  o.batch = std::size_t(parse_int("--batch", a.get("batch", "4"), 1, 100000));
  o.decoder_noise_sigma =
      parse_double("--noise-sigma", a.get("noise-sigma", rv("noise-sigma")), 0, 10, "(units of full scale)");
  o.wiener_on = wiener_on_from_string(a.get("wiener-on", "device"), "--wiener-on");
  o.init = init_spec_from_string(a.get("init", rv("init")), "--init");
  o.recipe = recipe;
  o.checkpoint_every = std::size_t(parse_int("--checkpoint-every", a.get("checkpoint-every", "10"), 1, 100000000));
  o.max_steps = a.has("max-steps") ? parse_int("--max-steps", a.get("max-steps"), 0, 2147483647) : -1;
  o.precision = precision_from_string(a.get("precision", "f32"));
  o.out = a.get("out");
  return o;
}

// qdo design --mode do-finetune --from RUN: the options of the do run RUN with this run's levels
// and placement, frozen optics, finetune-steps network steps in one epoch at the do run's last
// network learning rate (or --lr-decoder), constant. Options that would be dropped are refused.
DesignRunOptions finetune_options_from_options(const TextOptions& a) {
  static const std::set<std::string> allowed = {
      "mode",   "from", "levels",    "placement", "finetune-steps", "lr-decoder", "checkpoint-every", "max-steps",
      "device", "out",  "precision", "psf",       "design"};
  for (const auto& [k, v] : a.opt)
    if (!allowed.count(k))
      reject("--" + k, v,
             "not with --mode do-finetune (it takes the do run's options; allowed: --from --levels --placement --psf "
             "--design "
             "--finetune-steps --lr-decoder --checkpoint-every --max-steps --precision --device --out)");
  if (!a.has("from")) reject("--from", "(missing)", "the network do run folder to fine-tune (--mode do-finetune)");
  const std::string from = a.get("from");
  DesignRunOptions o = read_run_config(from, "--from", "a run folder written by qdo design (config.json missing)");
  if (o.design.mode != DesignMode::DO || !o.decoder.network())
    reject("--from", from,
           "a do run with a network decoder (it is a " + to_string(o.design.mode) + " run, decoder " +
               o.decoder.to_string() + "); with the Wiener decoder the refit is qdo eval --decoder matched");
  const double last_lr = o.lr_decoder * std::pow(o.design.lr_decay_per_epoch, double(o.epochs - 1));
  o.finetune_from = from;
  if (a.has("levels")) o.design.quantizer.levels = parse_int("--levels", a.get("levels"), 2, 65536);
  if (a.has("placement")) o.design.quantizer.placement = placement_from_string(a.get("placement"));
  o.design.steps_per_epoch = std::size_t(parse_int("--finetune-steps", a.get("finetune-steps", "200"), 1, 100000000));
  o.epochs = 1;
  o.design.t0_epochs = 0;
  o.design.t1_epochs = 1;
  o.design.lr_decay_per_epoch = 1;
  o.lr_decoder = a.has("lr-decoder") ? parse_double("--lr-decoder", a.get("lr-decoder"), 0, 1, "", true) : last_lr;
  o.checkpoint_every = std::size_t(parse_int("--checkpoint-every", a.get("checkpoint-every", "10"), 1, 100000000));
  o.max_steps = a.has("max-steps") ? parse_int("--max-steps", a.get("max-steps"), 0, 2147483647) : -1;
  if (a.has("precision")) o.precision = precision_from_string(a.get("precision"));
  // do-finetune for the camera as built: the frozen PSF is a measured stack or a fitted design's,
  // checked against the do run's configuration here, before any work.
  const PsfSpec asbuilt = psf_spec_from_options(a.get("psf"), a.get("design"), "--psf", "--design",
                                                "the frozen PSF comes from one of them");
  if (asbuilt.kind != PsfSpec::Kind::Run) {
    if (a.has("levels"))
      reject("--levels", a.get("levels"),
             asbuilt.kind == PsfSpec::Kind::File ? "no --levels with --psf (the measured stack is used as it is)"
                                                 : "no --levels with --design (the fitted design is used as it is)");
    (asbuilt.kind == PsfSpec::Kind::File ? o.finetune_psf : o.finetune_design) = asbuilt.value;
    (void)read_psf_input(asbuilt, o.cfg);
  }
  o.out = a.get("out");
  return o;
}
// An option given explicitly that does nothing in the run's mode, objective or decoder is
// refused, naming where it acts (it was ignored silently).
void check_options_act(const TextOptions& a, const DesignRunOptions& o) {
  const DesignMode m = o.design.mode;
  const bool levels_trained = m == DesignMode::QDOA || m == DesignMode::QDOM;
  const bool network = o.objective == Objective::Network;
  const bool wiener =
      o.objective == Objective::Wiener || o.objective == Objective::WienerMse || o.objective == Objective::WienerMae;
  struct Rule {
    const char* option;
    bool acts;
    const char* where;
  };
  const Rule rules[] = {
      {"beta", levels_trained, "--mode qdo+a or qdo+m (the regulariser of the trained levels)"},
      {"lr-offsets", levels_trained, "--mode qdo+a or qdo+m (the trained level offsets or mask depths)"},
      {"lr-decoder", network, "a network --decoder"},
      {"gamma", network, "a network --decoder"},
      {"target", o.objective == Objective::PsfTarget, "--objective psf-target"},
      {"wiener-on", wiener, "the Wiener objectives (--objective wiener, wiener-mse or wiener-mae)"},
      {"from", false, "--mode do-finetune"},
      {"finetune-steps", false, "--mode do-finetune"},
      {"psf", false, "--mode do-finetune (the measured PSF the network is fine-tuned for)"},
      {"design", false, "--mode do-finetune (the fitted design whose PSF the network is fine-tuned for)"},
  };
  for (const Rule& r : rules)
    if (a.has(r.option) && !r.acts)
      reject(std::string("--") + r.option, a.get(r.option),
             std::string("an option of ") + r.where + "; this run (--mode " + to_string(m) + ", --objective " +
                 to_string(o.objective) + (network ? ", --decoder " + o.decoder.to_string() : std::string()) +
                 ") would ignore it: leave it out");
}

// --resume continues a run with the options in RUN/config.json. An option given explicitly on the
// command line that differs from the stored one is refused (it would be dropped silently),
// naming each one: "--lr: stored 0.01, given 0.02". Not compared (allowed to differ): --max-steps
// (where this session stops), --device, --out, --resume, --check-gradients.
void check_resume_options(const TextOptions& a, const DesignRunOptions& given) {
  const fs::path cfg = RunFolder(given.out).config_path();
  if (given.out.empty() || !fs::exists(cfg)) return;  // run_design names the missing file
  // Both sides through the same reader and writer, so defaults of old run folders (psf_path)
  // and number formatting compare equal.
  const DesignRunOptions stored =
      read_run_config(given.out, "out", "a run folder written by qdo design (config.json missing)", true);
  const nlohmann::json s = nlohmann::json::parse(design_run_options_to_json(stored));
  const nlohmann::json g = nlohmann::json::parse(design_run_options_to_json(given));
  static const std::vector<std::pair<std::string, std::string>> fields = {{"mode", "mode"},
                                                                          {"levels", "levels"},
                                                                          {"placement", "placement"},
                                                                          {"parameterization", "parameterization"},
                                                                          {"psf-path", "psf_path"},
                                                                          {"objective", "objective"},
                                                                          {"target", "target"},
                                                                          {"data", "data"},
                                                                          {"epochs", "epochs"},
                                                                          {"steps-per-epoch", "steps_per_epoch"},
                                                                          {"t0", "t0_epochs"},
                                                                          {"t1", "t1_epochs"},
                                                                          {"lr", "lr_optics"},
                                                                          {"lr-offsets", "lr_offsets"},
                                                                          {"decay", "lr_decay_per_epoch"},
                                                                          {"beta", "beta_aq"},
                                                                          {"height-noise-nm", "height_noise_m"},
                                                                          {"noise-sigma", "decoder_noise_sigma"},
                                                                          {"init", "init"},
                                                                          {"seed", "seed"},
                                                                          {"checkpoint-every", "checkpoint_every"},
                                                                          {"precision", "precision"},
                                                                          {"synthetic-scenes", "synthetic_scenes"},
                                                                          {"batch", "batch"},
                                                                          {"wiener-on", "wiener_on"},
                                                                          {"decoder", "decoder"},
                                                                          {"lr-decoder", "lr_decoder"},
                                                                          {"gamma", "gamma_decoder"},
                                                                          {"points-per-step", "points_per_step"},
                                                                          {"recipe", "recipe"},
                                                                          {"decay-steps", "lr_decay_steps"},
                                                                          {"decay-staircase", "lr_staircase"},
                                                                          {"adam-eps", "adam_epsilon"},
                                                                          {"adam-form", "adam_keras_form"},
                                                                          {"aq-domain", "aq_domain"},
                                                                          {"pinned-level", "pin_top"},
                                                                          {"noise-at-test", "height_noise_at_test"},
                                                                          {"noise-at", "noise_on_bands"},
                                                                          {"patches", "fixed_patches"},
                                                                          {"batch-norm", "keras_batch_norm"},
                                                                          {"final-init", "glorot_final"}};
  std::vector<std::string> diffs;
  for (const auto& [opt, key] : fields) {
    if (!a.has(opt)) continue;
    const nlohmann::json& sv = s.at("design").at(key);
    const nlohmann::json& gv = g.at("design").at(key);
    if (sv != gv) diffs.push_back("--" + opt + ": stored " + sv.dump() + ", given " + gv.dump());
  }
  for (const char* opt : {"preset", "config", "object-distances", "field-angles"}) {
    if (!a.has(opt)) continue;
    const nlohmann::json& ss_ = s.at("system");
    const nlohmann::json& gs = g.at("system");
    for (auto it = gs.begin(); it != gs.end(); ++it)
      if (!ss_.contains(it.key()) || ss_.at(it.key()) != it.value())
        diffs.push_back("--" + std::string(opt) + ": system." + it.key() + " stored " +
                        (ss_.contains(it.key()) ? ss_.at(it.key()).dump() : std::string("(absent)")) + ", given " +
                        it.value().dump());
    for (auto it = ss_.begin(); it != ss_.end(); ++it)
      if (!gs.contains(it.key()))
        diffs.push_back("--" + std::string(opt) + ": system." + it.key() + " stored " + it.value().dump() +
                        ", given (absent)");
  }
  if (diffs.empty()) return;
  std::string list;
  for (const auto& d : diffs) list += (list.empty() ? "" : "; ") + d;
  reject("--resume", given.out,
         "options that match the run's config.json (a resumed run continues with its stored options; these differ: " +
             list + "; omit them, or start a new run in another --out)");
}

DesignRunOptions design_command_options(const TextOptions& a) {
  const bool finetune = a.get("mode") == "do-finetune";
  if (finetune && a.has("resume")) {  // a do-finetune run resumes like any run: its stored options
    TextOptions b = a;
    for (const char* k : {"mode", "from", "psf", "design"}) b.opt.erase(k);
    return design_command_options(b);
  }
  DesignRunOptions o = finetune ? finetune_options_from_options(a) : design_run_options_from_options(a, true);
  const bool resume = a.has("resume");
  if (!resume)
    o.validate();
  else
    check_resume_options(a, o);
  if (!resume && !finetune) check_options_act(a, o);
  return o;
}

std::string design_run_report(const DesignRunResult& r, double seconds, const std::string& out) {
  std::string s;
  char b[512];
  std::snprintf(b, sizeof b, "design: %ld steps, final loss %.6g, %.1f s; levels (nm):", r.steps_done, r.final_loss,
                seconds);
  s += b;
  for (double l : r.levels_m) {
    std::snprintf(b, sizeof b, " %.1f", l * 1e9);
    s += b;
  }
  s += "\n";
  if (!r.point_losses.empty()) {  // a design over a range of object points: its spread over the range
    std::snprintf(b, sizeof b, "%-6s %12s %12s %12s %14s\n", "point", "distance_m", "field_x_deg", "field_y_deg",
                  "loss");
    s += b;
    double worst = r.point_losses[0], sum = 0;
    for (std::size_t p = 0; p < r.point_losses.size(); ++p) {
      const ObjectPoint& pt = r.points[p];
      std::snprintf(b, sizeof b, "%-6zu %12s %12.4g %12.4g %14.6g\n", p,
                    pt.at_infinity() ? "inf" : to_str(pt.distance_m).c_str(), pt.field_x_deg, pt.field_y_deg,
                    r.point_losses[p]);
      s += b;
      worst = std::max(worst, r.point_losses[p]);
      sum += r.point_losses[p];
    }
    std::snprintf(b, sizeof b, "range: mean loss %.6g, worst %.6g over %zu points\n",
                  sum / double(r.point_losses.size()), worst, r.point_losses.size());
    s += b;
  }
  return s + "wrote " + out + "/ (config.json checkpoint.h5 log.csv design.h5 psf.h5 design.png psf.png loss.png" +
         (r.point_losses.empty() ? "" : " range.csv range.png") + ")\n";
}

DesignRunOptions gradcheck_options_from_options(const TextOptions& a) {
  TextOptions b = a;
  b.opt["out"] = "(unused)";
  b.opt["epochs"] = "10";
  // A generic state whatever the training recipe: qdo's (random heights away from the quantizer's
  // thresholds, 10 steps an epoch so the checked step 6 lies inside the alpha window). The release
  // recipe's own terms (L_aq over the rings, the pinned top level) are checked by suite recipe.
  b.opt["recipe"] = "qdo";
  DesignRunOptions o = design_run_options_from_options(b);
  o.validate();  // every option checked before the device is opened
  return o;
}

GradcheckReport gradcheck_report(const std::vector<GradcheckRow>& rows) {
  GradcheckReport rep;
  rep.text = strprintf("%-78s %12s %10s  %s\n", "parameter group", "max rel err", "tolerance", "");
  for (const auto& r : rows) {
    rep.text +=
        strprintf("%-78s %12.3e %10.1e  %s\n", r.group.c_str(), r.max_rel_error, r.tolerance, r.ok() ? "ok" : "FAIL");
    rep.ok = rep.ok && r.ok();
  }
  return rep;
}

GradcheckReport design_gradient_check(Runtime& rt, const DesignRunOptions& o) {
  // A design over several points: each point's chain is the one-point chain of point_config(cfg, p)
  // (the range objective is their mean); checked at the first point.
  DesignRunOptions g = o;
  if (o.cfg.point_count() > 1) {
    g.cfg = point_config(o.cfg, 0);
    g.design.points_per_step = 1;
  }
  GradcheckReport rep = gradcheck_report(gradcheck(rt, g, g.design.seed));
  rep.text = strprintf("gradient check on this run's configuration (reduced to N <= 64)%s:\n",
                       o.cfg.point_count() > 1 ? ", at object point 0" : "") +
             rep.text;
  return rep;
}

}  // namespace qdo
