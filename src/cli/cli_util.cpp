#include "cli.hpp"

#include <nlohmann/json.hpp>

#include <cmath>
#include <cstdlib>
#include <limits>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "qdo/data/data_root.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/data/datasets.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/design/recipe.hpp"
#include "qdo/data/scenes.hpp"

namespace fs = std::filesystem;

namespace qdo::cli {

RealStack scene_from_args(const SystemConfig& cfg, const Args& a) {
  return read_scene(cfg, a.get("scene", "builtin"), a.get("key"), a.has("resample-bands"), "--key");
}

// The configuration from --config or --preset, with the camera response checked too, so every
// configuration error surfaces before any device work or output.
SystemConfig load_config(const Args& a, bool allow_points) {
  SystemConfig c;
  if (a.has("config")) {
    if (a.has("preset")) reject("--preset", a.get("preset"), "omitted when --config is given (put \"preset\" in the file)");
    c = config_from_json_file(a.get("config"));
  } else {
    c = preset_config(a.get("preset", "small"));
  }
  // The commands image and write one PSF stack of bands planes: a configuration with several object
  // points (config.hpp) is qdo design's training conditions (allow_points); qdo simulate builds its
  // depth layers and field points from its own options (--depth, --field-grid).
  if (c.point_count() > 1 && !allow_points)
    reject("object_points", to_str(c.point_count()) + " points",
           "at most one point in the commands but qdo design (stacks of several object points: the library's Simulator and "
           "qdo.Optics.psf(height_m, object_points=...); designs over several points: qdo design; images of "
           "layered scenes and field-dependent images: qdo simulate --depth / --field-grid)");
  sensor_response(c);
  return c;
}

// lens:NM, flat, or an HDF5 design file matching the configuration's grid.
Map2D load_design(const SystemConfig& cfg, const std::string& spec) { return design_heights_from_spec(cfg, spec, "--design"); }

QuantSpec load_quantizer(const Args& a) {
  QuantSpec s;
  if (!a.has("levels")) {
    if (a.has("placement")) reject("--placement", a.get("placement"), "given together with --levels");
    return s;
  }
  s.active = true;
  s.q.levels = parse_int("--levels", a.get("levels"), 2, 65536);
  s.q.placement = placement_from_string(a.get("placement", "inclusive"));
  s.q.validate();
  return s;
}

Map2D design_heights(const SystemConfig& cfg, const Args& a, QuantSpec* qs_out) {
  const QuantSpec qs = load_quantizer(a);
  Map2D h = load_design(cfg, a.get("design"));
  if (qs.active) h = quantize_heights(h, cfg.h_max_m(), qs.q);
  if (qs_out) *qs_out = qs;
  return h;
}

std::string out_dir(const Args& a, const std::string& def) {
  const std::string d = a.get("out", def);
  if (d.empty()) reject("--out", "(missing)", "an output folder");
  claim_out(a, d);
  return d;
}

void claim_out(const Args& a, const std::string& dir) {
  if (dir.empty()) reject("--out", "(missing)", "an output folder");
  claim_output_dir(dir, "--out", a.command, a.has("into-existing"));
}

std::vector<std::string> scene_paths(const Args& a, const std::string& name) {
  const std::vector<std::string> out = resolve_datasets(split_items(a.get(name)), "--" + name);
  for (const std::string& p : out)
    if (p.rfind("synthetic:", 0) != 0 && !fs::exists(p))
      reject("--" + name, p, "existing scene files or folders, or dataset names under the data root (qdo data lists them)");
  return out;
}

// Options shared by design and gradcheck.
namespace {

// A distance of --object-distances: metres > 0 (at least 1e-6, as the configuration takes) or inf.
double object_distance(const std::string& v) {
  if (v == "inf") return std::numeric_limits<double>::infinity();
  char* end = nullptr;
  const double d = std::strtod(v.c_str(), &end);
  if (v.empty() || *end || !std::isfinite(d) || d < 1e-6)
    reject("--object-distances", v, "distances in metres > 0 (at least 1e-6 m) or inf, comma-separated, e.g. 0.5,1,2,5");
  return d;
}

}  // namespace

void object_point_options(const Args& a, SystemConfig& c) {
  if ((a.has("object-distances") || a.has("field-angles")) && !c.object_points.empty())
    reject(a.has("object-distances") ? "--object-distances" : "--field-angles",
           a.get(a.has("object-distances") ? "object-distances" : "field-angles"),
           "omitted when the configuration lists object_points (" + to_str(c.object_points.size()) +
               " points in --config): give the points one way");
  if (a.has("object-distances") || a.has("field-angles")) {
    std::vector<double> distances;
    for (const std::string& v : split_items(a.get("object-distances"))) distances.push_back(object_distance(v));
    if (a.has("object-distances") && distances.empty())
      reject("--object-distances", a.get("object-distances"), "one or more distances in metres or inf, comma-separated");
    if (distances.empty()) distances.push_back(c.points()[0].distance_m);
    std::vector<std::pair<double, double>> angles;
    for (const std::string& v : split_items(a.get("field-angles"))) {
      const auto colon = v.find(':');
      const double x = parse_double("--field-angles", colon == std::string::npos ? v : v.substr(0, colon), -89, 89, "deg");
      const double y = colon == std::string::npos ? 0.0 : parse_double("--field-angles", v.substr(colon + 1), -89, 89, "deg");
      angles.push_back({x, y});
    }
    if (a.has("field-angles") && angles.empty())
      reject("--field-angles", a.get("field-angles"), "one or more angles in degrees (A on the x axis, or X:Y), comma-separated");
    // Each value once, as eval-points asks: 1,1 is one point, not a range that eval then refuses.
    for (std::size_t i = 0; i < distances.size(); ++i)
      for (std::size_t j = 0; j < i; ++j)
        if (distances[i] == distances[j])
          reject("--object-distances", a.get("object-distances"), "distinct distances (" + split_items(a.get("object-distances"))[i] + " is given twice)");
    for (std::size_t i = 0; i < angles.size(); ++i)
      for (std::size_t j = 0; j < i; ++j)
        if (angles[i] == angles[j])
          reject("--field-angles", a.get("field-angles"), "distinct angles (" + split_items(a.get("field-angles"))[i] + " is given twice)");
    if (angles.empty()) angles.push_back({0.0, 0.0});
    // Each off-axis angle within the sampling at each distance, named with the limit there.
    for (const auto& ang : angles) {
      if (ang.first == 0 && ang.second == 0) continue;
      for (double d : distances) {
        const std::string why = object_point_limit(c, ObjectPoint{d, ang.first, ang.second});
        if (why.empty()) continue;
        const std::string text = ang.second == 0 ? to_str(ang.first) : to_str(ang.first) + ":" + to_str(ang.second);
        reject("--field-angles", text + " deg",
               "angles within the sampling at every distance: at " + (std::isinf(d) ? std::string("inf") : to_str(d) + " m") +
                   " this configuration supports field angles up to " + to_str(max_field_angle_deg(c, d)) +
                   " deg on one axis (" + why + ")");
      }
    }
    c.object_points = object_point_grid(distances, angles);
    if (c.object_points.size() > 4096)
      reject("--object-distances", a.get("object-distances"), "at most 4096 object points (distances x angles)");
  }
}

void range_options(const Args& a, DesignRunOptions& o) {
  object_point_options(a, o.cfg);
  const SystemConfig& c = o.cfg;
  // With --resume the run's points are in its config.json, not here: check_resume_options compares
  // the value with the stored one.
  const std::size_t points = a.has("resume") ? 4096 : c.point_count();
  o.design.points_per_step = std::size_t(parse_int("--points-per-step", a.get("points-per-step", "1"), 1, int(std::min<std::size_t>(points, 4096))));
}

DesignRunOptions design_options(const Args& a, bool range) {
  DesignRunOptions o;
  o.cfg = load_config(a, range);
  if (range) range_options(a, o);
  o.design.mode = design_mode_from_string(a.get("mode", "qdo+a"));
  o.design.parameterization = parameterization_from_string(a.get("parameterization", "radial"));
  o.design.quantizer.levels = parse_int("--levels", a.get("levels", "4"), 2, 65536);
  o.design.quantizer.placement = placement_from_string(a.get("placement", "inclusive"));
  // The training recipe (qdo/design/recipe.hpp) gives every default below that it names; an option given
  // explicitly wins over it, and config.json records each value.
  const std::string recipe = a.get("recipe", "release");
  const auto rv = [&](const char* option) { return recipe_value(recipe, option, "--recipe"); };
  o.design.steps_per_epoch = std::size_t(parse_int("--steps-per-epoch", a.get("steps-per-epoch", rv("steps-per-epoch")), 1, 1000000));
  o.epochs = std::size_t(parse_int("--epochs", a.get("epochs", rv("epochs")), 1, 1000000));
  DesignRunOptions window;  // the recipe's alpha window for these epochs (apply_recipe's rule)
  window.epochs = o.epochs;
  apply_recipe(recipe, window, [](const std::string& option) { return option == "epochs"; });
  o.design.t0_epochs = parse_double("--t0", a.get("t0", to_str(window.design.t0_epochs)), 0, 1e6, "epochs");
  o.design.t1_epochs = parse_double("--t1", a.get("t1", to_str(window.design.t1_epochs)), 0, 1e6, "epochs");
  o.design.lr_optics = parse_double("--lr", a.get("lr", rv("lr")), 0, 1, "(Adam step on weights in [-1, 1])");
  o.design.lr_offsets = parse_double("--lr-offsets", a.get("lr-offsets", rv("lr-offsets")), 0, 1, "(Adam step on normalised offsets)");
  o.design.lr_decay_per_epoch = parse_double("--decay", a.get("decay", rv("decay")), 0, 1, "(factor per decay period)", true);
  const std::string decay_steps = a.get("decay-steps", rv("decay-steps"));
  o.design.lr_decay_steps = decay_steps == "epoch" ? 0.0 : parse_double("--decay-steps", decay_steps, 1, 1e9, "steps, or epoch", false);
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
  o.design.height_noise_m = parse_double("--height-noise-nm", a.get("height-noise-nm", rv("height-noise-nm")), 0, 1e4, "nm") * 1e-9;
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
  o.decoder = decoder_spec_from_string(a.get("decoder", "wiener"));
  o.objective = a.has("objective") ? objective_from_string(a.get("objective"), "--objective")
                : o.decoder.network()  ? Objective::Network
                                       : Objective::Wiener;
  o.lr_decoder = parse_double("--lr-decoder", a.get("lr-decoder", rv("lr-decoder")), 0, 1, "", true);
  o.gamma_decoder = parse_double("--gamma", a.get("gamma", rv("gamma")), 0, 1e3, "");
  o.target = target_spec_from_string(a.get("target", "lens:550"), "--target");
  o.data = scene_paths(a, "data");
  o.synthetic_scenes = std::size_t(parse_int("--synthetic-scenes", a.get("synthetic-scenes", "12"), 1, 100000));
  o.batch = std::size_t(parse_int("--batch", a.get("batch", "4"), 1, 100000));
  o.decoder_noise_sigma = parse_double("--noise-sigma", a.get("noise-sigma", rv("noise-sigma")), 0, 10, "(units of full scale)");
  o.wiener_on = wiener_on_from_string(a.get("wiener-on", "device"), "--wiener-on");
  o.init = init_spec_from_string(a.get("init", rv("init")), "--init");
  o.recipe = recipe;
  o.checkpoint_every = std::size_t(parse_int("--checkpoint-every", a.get("checkpoint-every", "10"), 1, 100000000));
  o.max_steps = a.has("max-steps") ? parse_int("--max-steps", a.get("max-steps"), 0, 2147483647) : -1;
  o.precision = precision_from_string(a.get("precision", "f32"));
  o.out = a.get("out");
  return o;
}

// --resume continues a run with the options in RUN/config.json. An option given explicitly on the
// command line that differs from the stored one is refused (it would be dropped silently),
// naming each one: "--lr: stored 0.01, given 0.02". Not compared (allowed to differ): --max-steps
// (where this session stops), --device, --out, --resume, --check-gradients.
void check_resume_options(const Args& a, const DesignRunOptions& given) {
  const fs::path cfg = RunFolder(given.out).config_path();
  if (given.out.empty() || !fs::exists(cfg)) return;  // run_design names the missing file
  // Both sides through the same reader and writer, so defaults of old run folders (psf_path)
  // and number formatting compare equal.
  const DesignRunOptions stored = read_run_config(given.out, "out", "a run folder written by qdo design (config.json missing)", true);
  const nlohmann::json s = nlohmann::json::parse(design_run_options_to_json(stored));
  const nlohmann::json g = nlohmann::json::parse(design_run_options_to_json(given));
  static const std::vector<std::pair<std::string, std::string>> fields = {
      {"mode", "mode"}, {"levels", "levels"}, {"placement", "placement"}, {"parameterization", "parameterization"},
      {"psf-path", "psf_path"}, {"objective", "objective"}, {"target", "target"}, {"data", "data"},
      {"epochs", "epochs"}, {"steps-per-epoch", "steps_per_epoch"}, {"t0", "t0_epochs"}, {"t1", "t1_epochs"},
      {"lr", "lr_optics"}, {"lr-offsets", "lr_offsets"}, {"decay", "lr_decay_per_epoch"}, {"beta", "beta_aq"},
      {"height-noise-nm", "height_noise_m"}, {"noise-sigma", "decoder_noise_sigma"}, {"init", "init"}, {"seed", "seed"},
      {"checkpoint-every", "checkpoint_every"}, {"precision", "precision"}, {"synthetic-scenes", "synthetic_scenes"},
      {"batch", "batch"}, {"wiener-on", "wiener_on"}, {"decoder", "decoder"}, {"lr-decoder", "lr_decoder"},
      {"gamma", "gamma_decoder"}, {"points-per-step", "points_per_step"}, {"recipe", "recipe"},
      {"decay-steps", "lr_decay_steps"}, {"decay-staircase", "lr_staircase"}, {"adam-eps", "adam_epsilon"},
      {"adam-form", "adam_keras_form"}, {"aq-domain", "aq_domain"}, {"pinned-level", "pin_top"},
      {"noise-at-test", "height_noise_at_test"}, {"noise-at", "noise_on_bands"}, {"patches", "fixed_patches"},
      {"batch-norm", "keras_batch_norm"}, {"final-init", "glorot_final"}};
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
        diffs.push_back("--" + std::string(opt) + ": system." + it.key() + " stored " + it.value().dump() + ", given (absent)");
  }
  if (diffs.empty()) return;
  std::string list;
  for (const auto& d : diffs) list += (list.empty() ? "" : "; ") + d;
  reject("--resume", given.out,
         "options that match the run's config.json (a resumed run continues with its stored options; these differ: " + list +
             "; omit them, or start a new run in another --out)");
}

fab::DesignSource fab_source(const Args& a, bool check_grid) {
  const std::string& src = a.positional;
  if (fs::is_directory(src) && (a.has("preset") || a.has("config")))
    reject("--preset", "(given)", "omitted with a run folder (its config.json is used)");
  return fab::read_design_source(src, [&a] { return load_config(a); }, check_grid);
}

PsfInput psf_input(const SystemConfig& cfg, const Args& a) {
  const PsfSpec spec = psf_spec_from_options(a.get("psf"), a.get("design"), "--psf", "--design", "the PSF comes from one of them");
  if (spec.kind == PsfSpec::Kind::File) {
    if (a.has("levels")) reject("--levels", a.get("levels"), "no --levels with --psf (the PSF file is used as it is)");
    return read_psf_input(spec, cfg);
  }
  if (spec.kind == PsfSpec::Kind::Run) reject("--design", "(missing)", "lens:NM, flat, or a design .h5 file (or --psf FILE: a PSF stack)");
  PsfInput in;
  in.spec = spec;
  in.heights = design_heights(cfg, a);
  return in;
}

}  // namespace qdo::cli
