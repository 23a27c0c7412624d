#include "qdo/design/design_run_options.hpp"

#include <nlohmann/json.hpp>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <functional>
#include <limits>

#include "data/json_strict.hpp"
#include "qdo/decode/decoder_registry.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/design/joint.hpp"
#include "qdo/decode/testset.hpp"

namespace fs = std::filesystem;
using nlohmann::json;

namespace qdo {

Objective objective_from_string(const std::string& s, const std::string& argument) {
  if (s == "wiener") return Objective::Wiener;
  if (s == "wiener-mse") return Objective::WienerMse;
  if (s == "wiener-mae") return Objective::WienerMae;
  if (s == "psf-target") return Objective::PsfTarget;
  if (s == "network") return Objective::Network;
  reject(argument, s, "one of wiener, wiener-mse, wiener-mae, psf-target, network");
}

std::string to_string(Objective o) {
  switch (o) {
    case Objective::Wiener: return "wiener";
    case Objective::WienerMse: return "wiener-mse";
    case Objective::WienerMae: return "wiener-mae";
    case Objective::PsfTarget: return "psf-target";
    case Objective::Network: return "network";
  }
  return "wiener";
}

WienerOn wiener_on_from_string(const std::string& s, const std::string& argument) {
  if (s == "device") return WienerOn::Device;
  if (s == "cpu") return WienerOn::Cpu;
  reject(argument, s, "device or cpu");
}

std::string to_string(WienerOn w) { return w == WienerOn::Cpu ? "cpu" : "device"; }

namespace {

// NM of "lens:NM": a finite wavelength in nm, 100 ... 20000; InputError naming `argument` otherwise.
double lens_nm(const std::string& argument, const std::string& spec) {
  const std::string num = spec.substr(5);
  char* end = nullptr;
  const double nm = std::strtod(num.c_str(), &end);
  if (num.empty() || *end || !std::isfinite(nm) || nm < 100 || nm > 20000)
    reject(argument, spec, "lens:NM with NM a wavelength in nm (100 ... 20000), e.g. lens:550");
  return nm;
}

// "lens:" + NM as written (`text`), or else the shortest plain decimal that reads back as nm
// (550 -> lens:550, 632.8 -> lens:632.8).
std::string lens_text(double nm, const std::string& text) {
  if (!text.empty()) return "lens:" + text;
  char b[64];
  for (int p = 1; p <= 17; ++p) {
    std::snprintf(b, sizeof b, "%.*g", p, nm);
    if (!std::strchr(b, 'e') && std::strtod(b, nullptr) == nm) break;
  }
  return std::string("lens:") + b;
}

}  // namespace

std::string InitSpec::to_string() const {
  if (kind == Kind::Flat) return "flat";
  if (kind == Kind::Half) return "half";
  if (kind == Kind::Lens) return lens_text(wavelength_nm, wavelength_text);
  return "random";
}

InitSpec init_spec_from_string(const std::string& s, const std::string& argument) {
  InitSpec i;
  if (s == "random") return i;
  if (s == "flat") {
    i.kind = InitSpec::Kind::Flat;
    return i;
  }
  if (s == "half") {
    i.kind = InitSpec::Kind::Half;
    return i;
  }
  if (s.rfind("lens:", 0) != 0) reject(argument, s, "random, flat, half or lens:NM");
  i.kind = InitSpec::Kind::Lens;
  i.wavelength_nm = lens_nm(argument, s);
  i.wavelength_text = s.substr(5);
  return i;
}

std::string TargetSpec::to_string() const {
  if (kind == Kind::Lens) return lens_text(wavelength_nm, wavelength_text);
  return kind == Kind::File ? path : std::string();
}

TargetSpec target_spec_from_string(const std::string& s, const std::string& argument) {
  TargetSpec t;
  if (s.empty()) return t;
  if (s.rfind("lens:", 0) == 0) {
    t.kind = TargetSpec::Kind::Lens;
    t.wavelength_nm = lens_nm(argument, s);
    t.wavelength_text = s.substr(5);
    return t;
  }
  t.kind = TargetSpec::Kind::File;
  t.path = s;
  return t;
}

void DesignRunOptions::validate() const {
  cfg.validate();
  design.validate();
  if (design.mode == DesignMode::QDOM) mask_count(design.quantizer.levels);  // a power of two
  const bool net = decoder.network();
  // The decoders a design trains with: wiener (closed form) and those trained with the optics (a
  // resunet spec, or a registered decoder with a train factory, decoder_registry.hpp).
  std::string trainable = "resunet, resunet:paper, resunet:depth=D,root=R";
  for (const std::string& n : decoder_names())
    if (n != "resunet" && decoder_entry(n).trained) trainable += ", " + n;
  if (decoder.kind == DecoderSpec::Kind::Named && !net)
    reject("decoder", decoder.to_string(),
           "wiener or a decoder trained with the optics (" + trainable + "): the decoders a design trains with (" +
               decoder.kind_name() + " decodes at evaluation: qdo eval --decoder-kind)");
  if (net && objective != Objective::Network)
    reject("objective", to_string(objective), "network: a network decoder (" + decoder.to_string() + ") is trained with its own loss (Eq. 14)");
  if (!net && objective == Objective::Network)
    reject("decoder", decoder.to_string(), "a decoder trained with the optics (" + trainable + ") for objective network");
  if (net) {
    const std::size_t s = cfg.sensor_size_px(), m = std::size_t(1) << (decoder.depth - 1);
    if (decoder.kind == DecoderSpec::Kind::ResUNet && s % m)
      reject("decoder", decoder.to_string(),
             "a depth D whose 2^(D-1) divides the sensor patch size S = " + to_str(s) + " (the network pools D-1 times)");
    if (!(lr_decoder > 0) || !std::isfinite(lr_decoder)) reject("lr_decoder", lr_decoder, "a finite learning rate > 0");
    if (!(gamma_decoder >= 0) || !std::isfinite(gamma_decoder)) reject("gamma_decoder", gamma_decoder, "a finite weight >= 0");
    if (batch > testset::PatchCamera::kMaxBatch) reject("batch", batch, "1 to " + to_str(testset::PatchCamera::kMaxBatch) + " with a network decoder");
  }
  if (!finetune_from.empty()) {
    if (!net) reject("finetune_from", finetune_from, "empty: do-finetune trains a network (a resunet decoder)");
    if (design.mode != DesignMode::DO) reject("mode", to_string(design.mode), "do for a do-finetune run");
  }
  if (!finetune_psf.empty() && !finetune_design.empty())
    reject("finetune_design", finetune_design, "empty with finetune_psf = " + finetune_psf + " (the frozen PSF comes from one of them)");
  for (const auto& [key, path] : {std::pair<const char*, const std::string*>{"finetune_psf", &finetune_psf}, {"finetune_design", &finetune_design}}) {
    if (path->empty()) continue;
    if (finetune_from.empty()) reject(key, *path, "empty without finetune_from (a do-finetune run's frozen PSF)");
    if (!fs::is_regular_file(*path)) reject(key, *path, "an existing file");
  }
  if (objective == Objective::PsfTarget && target.kind != TargetSpec::Kind::Lens && !fs::exists(target.path))
    reject("target", target.to_string(), "lens:NM or an existing design .h5 file");
  // A design over a range of object points: points_per_step of the P points per step.
  const std::size_t points = cfg.point_count();
  if (design.points_per_step < 1 || design.points_per_step > points)
    reject("points_per_step", design.points_per_step,
           "1 to the number of object points P = " + to_str(points) + " (P: every point every step)");
  if (points > 1 && (net || objective == Objective::Network || !finetune_from.empty()))
    reject("objective", to_string(objective),
           "wiener, wiener-mse, wiener-mae or psf-target for a design over " + to_str(points) +
               " object points (a network decoder trained over a range of points is not supported)");
  if (epochs < 1) reject("epochs", epochs, ">= 1");
  if (batch < 1) reject("batch", batch, ">= 1");
  if (synthetic_scenes < 1) reject("synthetic_scenes", synthetic_scenes, ">= 1");
  if (prior_bins < 2 || prior_bins > 4096) reject("prior_bins", prior_bins, "in [2, 4096]");
  if (checkpoint_every < 1) reject("checkpoint_every", checkpoint_every, ">= 1");
  if (!(decoder_noise_sigma >= 0 && decoder_noise_sigma <= 10))
    reject("noise_sigma", decoder_noise_sigma, "a sensor noise std in [0, 10] (units of full scale)");
  if (out.empty()) reject("out", "(missing)", "a run folder");
  if (double(design.t1_epochs) > double(epochs)) reject("t1", design.t1_epochs, "<= epochs (" + to_str(epochs) + ")");
  for (const auto& d : data) {
    if (d.rfind("synthetic:", 0) == 0) {  // network runs: N synthetic training scenes beside the real ones
      if (!net) reject("data", d, "existing scene files or folders (synthetic:N adds synthetic scenes to a network run's training set)");
      synthetic_count(d);
      continue;
    }
    if (!fs::exists(d)) reject("data", d, "existing scene files or folders, or synthetic:N (network runs)");
  }
}

namespace {

std::string placement_name(Placement p) { return to_string(p); }
std::string param_name(Parameterization p) {
  return p == Parameterization::Full2D ? "2d" : p == Parameterization::Radial ? "radial" : "quad";
}


// An integer field of a run's config.json as T: an integer in T's range, else an InputError
// naming the key (a float such as 1e300 converted to int was undefined behaviour).
template <typename T>
T integer_field(const json& d, const char* key) {
  const json& v = d.at(key);
  bool ok = v.is_number_integer();
  if (ok && v.is_number_unsigned()) ok = v.get<std::uint64_t>() <= std::uint64_t(std::numeric_limits<T>::max());
  else if (ok) {
    const std::int64_t i = v.get<std::int64_t>();
    ok = i >= 0 && std::uint64_t(i) <= std::uint64_t(std::numeric_limits<T>::max());
  }
  if (!ok)
    throw InputError(std::string("key 'design.") + key + "' = " + v.dump() + ": an integer in [0, " +
                     std::to_string(std::numeric_limits<T>::max()) + "]");
  return static_cast<T>(v.get<std::uint64_t>());
}

// One field of config.json's "design" object: its key, how it is read (strictly) and written.
// `acc` is a generic accessor returning the member (for const and non-const options alike).
struct RunField {
  const char* key;
  std::function<void(DesignRunOptions&, const json&)> read;
  std::function<void(const DesignRunOptions&, json&)> write;
};
template <typename Acc>
RunField real_field(const char* key, Acc acc) {
  return {key, [=](DesignRunOptions& o, const json& d) { acc(o) = d.at(key).get<double>(); },
          [=](const DesignRunOptions& o, json& d) { d[key] = acc(o); }};
}
template <typename T, typename Acc>
RunField integer_field_of(const char* key, Acc acc) {
  return {key, [=](DesignRunOptions& o, const json& d) { acc(o) = integer_field<T>(d, key); },
          [=](const DesignRunOptions& o, json& d) { d[key] = acc(o); }};
}
template <typename Acc>
RunField text_field(const char* key, Acc acc) {
  return {key, [=](DesignRunOptions& o, const json& d) { acc(o) = d.at(key).get<std::string>(); },
          [=](const DesignRunOptions& o, json& d) { d[key] = acc(o); }};
}
// Fields that run folders of earlier versions lack: read as `def` when absent.
template <typename Acc>
RunField real_field_or(const char* key, Acc acc, double def) {
  return {key, [=](DesignRunOptions& o, const json& d) { acc(o) = d.contains(key) ? d.at(key).get<double>() : def; },
          [=](const DesignRunOptions& o, json& d) { d[key] = acc(o); }};
}
template <typename Acc>
RunField bool_field_or(const char* key, Acc acc, bool def) {
  return {key, [=](DesignRunOptions& o, const json& d) { acc(o) = d.contains(key) ? d.at(key).get<bool>() : def; },
          [=](const DesignRunOptions& o, json& d) { d[key] = acc(o); }};
}
template <typename Acc>
RunField text_field_or(const char* key, Acc acc, const char* def) {
  return {key, [=](DesignRunOptions& o, const json& d) { acc(o) = d.contains(key) ? d.at(key).get<std::string>() : std::string(def); },
          [=](const DesignRunOptions& o, json& d) { d[key] = acc(o); }};
}
// An enum written by its name (to_name) and read back through its parser (from_name).
template <typename Acc, typename From, typename To>
RunField named_field(const char* key, Acc acc, From from_name, To to_name) {
  return {key, [=](DesignRunOptions& o, const json& d) { acc(o) = from_name(d.at(key).get<std::string>()); },
          [=](const DesignRunOptions& o, json& d) { d[key] = to_name(acc(o)); }};
}

// A parser of a typed option with its key as the argument its InputError names.
template <typename T>
std::function<T(const std::string&)> from_key(T (*parse)(const std::string&, const std::string&), const char* key) {
  return [parse, key](const std::string& s) { return parse(s, key); };
}

// The one field list of the "design" object (to_json and from_json both walk it, in this order).
const std::vector<RunField>& run_fields() {
  static const std::vector<RunField> t = {
      named_field("mode", [](auto& o) -> auto& { return o.design.mode; }, design_mode_from_string,
                  [](DesignMode m) { return to_string(m); }),
      named_field("parameterization", [](auto& o) -> auto& { return o.design.parameterization; },
                  parameterization_from_string, param_name),
      // Run folders written before the radial path existed ran the 2-D path: resume them on it.
      {"psf_path",
       [](DesignRunOptions& o, const json& d) { o.design.psf_path = psf_path_from_string(d.value("psf_path", std::string("2d"))); },
       [](const DesignRunOptions& o, json& d) { d["psf_path"] = to_string(o.design.psf_path); }},
      integer_field_of<int>("levels", [](auto& o) -> auto& { return o.design.quantizer.levels; }),
      named_field("placement", [](auto& o) -> auto& { return o.design.quantizer.placement; }, placement_from_string,
                  placement_name),
      integer_field_of<std::size_t>("steps_per_epoch", [](auto& o) -> auto& { return o.design.steps_per_epoch; }),
      real_field("t0_epochs", [](auto& o) -> auto& { return o.design.t0_epochs; }),
      real_field("t1_epochs", [](auto& o) -> auto& { return o.design.t1_epochs; }),
      real_field("lr_optics", [](auto& o) -> auto& { return o.design.lr_optics; }),
      real_field("lr_offsets", [](auto& o) -> auto& { return o.design.lr_offsets; }),
      real_field("lr_decay_per_epoch", [](auto& o) -> auto& { return o.design.lr_decay_per_epoch; }),
      real_field("beta_aq", [](auto& o) -> auto& { return o.design.beta_aq; }),
      real_field("height_noise_m", [](auto& o) -> auto& { return o.design.height_noise_m; }),
      integer_field_of<std::uint64_t>("seed", [](auto& o) -> auto& { return o.design.seed; }),
      // Run folders written before designs over object points trained on their one point.
      {"points_per_step",
       [](DesignRunOptions& o, const json& d) {
         o.design.points_per_step = d.contains("points_per_step") ? integer_field<std::size_t>(d, "points_per_step") : 1;
       },
       [](const DesignRunOptions& o, json& d) { d["points_per_step"] = o.design.points_per_step; }},
      named_field("objective", [](auto& o) -> auto& { return o.objective; }, from_key(objective_from_string, "objective"),
                  [](Objective v) { return to_string(v); }),
      named_field("target", [](auto& o) -> auto& { return o.target; }, from_key(target_spec_from_string, "target"),
                  [](const TargetSpec& v) { return v.to_string(); }),
      {"data", [](DesignRunOptions& o, const json& d) { o.data = d.at("data").get<std::vector<std::string>>(); },
       [](const DesignRunOptions& o, json& d) { d["data"] = o.data; }},
      text_field("data_format", [](auto& o) -> auto& { return o.data_format; }),
      integer_field_of<std::size_t>("synthetic_scenes", [](auto& o) -> auto& { return o.synthetic_scenes; }),
      integer_field_of<std::size_t>("batch", [](auto& o) -> auto& { return o.batch; }),
      integer_field_of<std::size_t>("epochs", [](auto& o) -> auto& { return o.epochs; }),
      real_field("decoder_noise_sigma", [](auto& o) -> auto& { return o.decoder_noise_sigma; }),
      integer_field_of<std::size_t>("prior_bins", [](auto& o) -> auto& { return o.prior_bins; }),
      {"wiener_on",
       [](DesignRunOptions& o, const json& d) { o.wiener_on = wiener_on_from_string(d.value("wiener_on", std::string("cpu"))); },
       [](const DesignRunOptions& o, json& d) { d["wiener_on"] = to_string(o.wiener_on); }},
      named_field("init", [](auto& o) -> auto& { return o.init; }, from_key(init_spec_from_string, "init"),
                  [](const InitSpec& v) { return v.to_string(); }),
      integer_field_of<std::size_t>("checkpoint_every", [](auto& o) -> auto& { return o.checkpoint_every; }),
      named_field("precision", [](auto& o) -> auto& { return o.precision; }, precision_from_string,
                  [](Precision p) { return to_string(p); }),
      // Run folders written before the network decoder existed trained against the Wiener decoder.
      {"decoder", [](DesignRunOptions& o, const json& d) { o.decoder = decoder_spec_from_string(d.value("decoder", DecoderSpec{}.to_string())); },
       [](const DesignRunOptions& o, json& d) { d["decoder"] = o.decoder.to_string(); }},
      {"lr_decoder", [](DesignRunOptions& o, const json& d) { o.lr_decoder = d.value("lr_decoder", 1e-3); },
       [](const DesignRunOptions& o, json& d) { d["lr_decoder"] = o.lr_decoder; }},
      {"gamma_decoder", [](DesignRunOptions& o, const json& d) { o.gamma_decoder = d.value("gamma_decoder", 1e-4); },
       [](const DesignRunOptions& o, json& d) { d["gamma_decoder"] = o.gamma_decoder; }},
      {"finetune_from", [](DesignRunOptions& o, const json& d) { o.finetune_from = d.value("finetune_from", std::string()); },
       [](const DesignRunOptions& o, json& d) { d["finetune_from"] = o.finetune_from; }},
      // The training recipe and its items beyond the fields above (recipe.hpp). Run folders written
      // before recipes existed trained with qdo's: per-epoch staircase decay, Adam's textbook form
      // with eps 1e-8, L_aq over the pixels, level 0 pinned, no height noise at evaluation.
      text_field_or("recipe", [](auto& o) -> auto& { return o.recipe; }, "qdo"),
      real_field_or("lr_decay_steps", [](auto& o) -> auto& { return o.design.lr_decay_steps; }, 0.0),
      bool_field_or("lr_staircase", [](auto& o) -> auto& { return o.design.lr_staircase; }, true),
      real_field_or("adam_epsilon", [](auto& o) -> auto& { return o.design.adam_epsilon; }, 1e-8),
      bool_field_or("adam_keras_form", [](auto& o) -> auto& { return o.design.adam_keras_form; }, false),
      {"aq_domain",
       [](DesignRunOptions& o, const json& d) { o.design.aq_domain = aq_domain_from_string(d.value("aq_domain", std::string("pixels"))); },
       [](const DesignRunOptions& o, json& d) { d["aq_domain"] = to_string(o.design.aq_domain); }},
      bool_field_or("pin_top", [](auto& o) -> auto& { return o.design.quantizer.pin_top; }, false),
      bool_field_or("height_noise_at_test", [](auto& o) -> auto& { return o.height_noise_at_test; }, false),
      // Run folders written before these recipe items trained qdo's network as qdo does.
      bool_field_or("keras_batch_norm", [](auto& o) -> auto& { return o.network_style.keras_batch_norm; }, false),
      bool_field_or("glorot_final", [](auto& o) -> auto& { return o.network_style.glorot_final; }, false),
      bool_field_or("noise_on_bands", [](auto& o) -> auto& { return o.sampling.noise_on_bands; }, false),
      bool_field_or("fixed_patches", [](auto& o) -> auto& { return o.sampling.fixed_patches; }, false),
      // Written only when set: the config.json of every other run reads as before.
      {"finetune_psf", [](DesignRunOptions& o, const json& d) { o.finetune_psf = d.value("finetune_psf", std::string()); },
       [](const DesignRunOptions& o, json& d) {
         if (!o.finetune_psf.empty()) d["finetune_psf"] = o.finetune_psf;
       }},
      {"finetune_design", [](DesignRunOptions& o, const json& d) { o.finetune_design = d.value("finetune_design", std::string()); },
       [](const DesignRunOptions& o, json& d) {
         if (!o.finetune_design.empty()) d["finetune_design"] = o.finetune_design;
       }},
  };
  return t;
}

}  // namespace

std::string design_run_options_to_json(const DesignRunOptions& o) {
  json j;
  j["system"] = json::parse(config_to_json_text(o.cfg));
  json d;
  for (const RunField& f : run_fields()) f.write(o, d);
  j["design"] = d;
  return j.dump(2);
}

DesignRunOptions design_run_options_from_json(const std::string& text, const std::string& origin) {
  DesignRunOptions o;
  try {
    const json j = parse_json_strict(text, "file '" + origin + "'");
    o.cfg = config_from_json_text(j.at("system").dump(), origin + " (system)");
    const json& d = j.at("design");
    for (const RunField& f : run_fields()) f.read(o, d);
  } catch (const json::exception& e) {
    throw InputError("file '" + origin + "': " + e.what());
  } catch (const InputError& e) {  // a value the option parsers refuse ("argument 'mode' = ..."): name the file
    if (std::string(e.what()).find(origin) != std::string::npos) throw;
    throw InputError("file '" + origin + "': " + e.what());
  }
  return o;
}

}  // namespace qdo
