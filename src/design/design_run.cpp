#include "qdo/design_run.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <memory>
#include <random>
#include <sstream>
#include <unistd.h>

#include "qdo/adjoint.hpp"
#include "qdo/simulator.hpp"
#include "qdo/datasets.hpp"
#include "qdo/error.hpp"
#include "data/json_strict.hpp"
#include "qdo/hash.hpp"
#include "qdo/io.hpp"
#include "qdo/joint.hpp"
#include "qdo/network_decoder.hpp"
#include "qdo/optics.hpp"
#include "qdo/run.hpp"
#include "qdo/run_folder.hpp"
#include "qdo/wiener.hpp"
#include "qdo/wiener_device.hpp"

namespace fs = std::filesystem;
using nlohmann::json;

namespace qdo {
namespace {

std::string placement_name(Placement p) { return to_string(p); }
std::string param_name(Parameterization p) {
  return p == Parameterization::Full2D ? "2d" : p == Parameterization::Radial ? "radial" : "quad";
}

// Training scenes as S x S patches at the sensor pitch (S = sensor PSF size, so the Wiener
// prior, the PSF and the scenes share one grid).
std::vector<RealStack> training_scenes(const DesignRunOptions& o) {
  const std::size_t s = o.cfg.sensor_size_px();
  std::vector<RealStack> out;
  if (o.data.empty()) {
    const SceneIndex idx = SceneIndex::synthetic(o.cfg, o.synthetic_scenes, s, o.design.seed);
    for (std::size_t i = 0; i < idx.size(); ++i) out.push_back(idx.load(i));
    return out;
  }
  const SceneIndex idx(o.data, o.data_format, o.cfg.bands, o.cfg.wavelengths_nm());
  const SceneSplit split = idx.split(o.design.seed, 0.8, 0.1);
  const auto& use = split.train.empty() ? split.test : split.train;
  for (std::size_t i : use) {
    const RealStack cube = idx.load(i);
    check_training_scene(cube, idx[i].path);
    if (cube.rows < s || cube.cols < s)
      reject("data", idx[i].path, "scenes of at least " + to_str(s) + " x " + to_str(s) + " pixels (the sensor PSF size)");
    for (auto& p : extract_patches(cube, s, s / 2)) out.push_back(std::move(p));
  }
  return out;
}

struct Problem {
  Eigen::MatrixXd srf;
  wiener::SpectralPrior prior;
  std::vector<RealStack> scenes;
  RealStack target;
  JointData joint;  // objective network: the scenes the network trains and validates on
};

// The Wiener expected-error objective on the device for this run, when it asks for one
// (objective wiener, wiener_on device) and the device has float64 for the C x C solve; null
// otherwise (the CPU objective then runs).
std::unique_ptr<wiener::DeviceObjective> make_device_objective(Runtime& rt, const DesignRunOptions& o, const Problem& pb) {
  if (o.objective != "wiener" || o.wiener_on != "device") return nullptr;
  if (!rt.has_fp64()) {  // float32 cannot hold σ² next to M's large eigenvalues (kernels/wiener.cl)
    if (!o.quiet)
      std::fprintf(stderr, "qdo: note: %s has no float64; the wiener objective runs on the CPU (double) instead\n",
                   rt.info().name.c_str());
    return nullptr;
  }
  return std::make_unique<wiener::DeviceObjective>(rt, o.precision, pb.srf, pb.prior, o.decoder_noise_sigma,
                                                   o.cfg.sensor_size_px());
}

// The step's objective; `dev` (from make_device_objective) evaluates the wiener objective when given.
PsfObjective make_objective(const DesignRunOptions& o, const Problem& pb, long step, wiener::DeviceObjective* dev = nullptr) {
  if (o.objective == "psf-target") return psf_target_objective(pb.target);
  const wiener::Loss loss = o.objective == "wiener" ? wiener::Loss::Expected
                            : o.objective == "wiener-mse" ? wiener::Loss::Mse
                                                          : wiener::Loss::Mae;
  if (loss == wiener::Loss::Expected && dev)
    return [dev](const RealStack& psf, RealStack& grad) {
      wiener::PsfObjective r = dev->expected(psf);
      grad = std::move(r.grad_psf);
      return r.value;
    };
  std::vector<RealStack> batch;
  if (loss != wiener::Loss::Expected) {
    std::mt19937_64 rng(o.design.seed * 1000003ull + std::uint64_t(step));
    for (std::size_t k = 0; k < o.batch; ++k) batch.push_back(pb.scenes[rng() % pb.scenes.size()]);
  }
  const double sigma = o.decoder_noise_sigma;
  const Problem* p = &pb;
  return [p, loss, sigma, batch](const RealStack& psf, RealStack& grad) {
    wiener::PsfObjective r = wiener::objective_psf(loss, psf, p->srf, p->prior, sigma, batch);
    grad = std::move(r.grad_psf);
    return r.value;
  };
}

namespace {
// NM of "lens:NM": a finite wavelength in nm, 100 ... 20000; InputError naming `arg` otherwise.
double lens_nm(const std::string& arg, const std::string& spec) {
  const std::string num = spec.substr(5);
  char* end = nullptr;
  const double nm = std::strtod(num.c_str(), &end);
  if (num.empty() || *end || !std::isfinite(nm) || nm < 100 || nm > 20000)
    reject(arg, spec, "lens:NM with NM a wavelength in nm (100 ... 20000), e.g. lens:550");
  return nm;
}
}  // namespace

Problem make_problem(Runtime& rt, const DesignRunOptions& o) {
  Problem pb;
  pb.srf = sensor_response(o.cfg);
  if (o.objective == "psf-target") {
    Simulator sim(rt, o.cfg, o.precision);
    Map2D h;
    if (o.target.rfind("lens:", 0) == 0) h = lens_design(o.cfg, lens_nm("target", o.target));
    else h = read_design(o.target).height_m;
    sim.set_heights(h);
    sim.compute_psf();
    pb.target = sim.psf_sensor();
    return pb;
  }
  if (o.objective == "network") {  // the network's training scenes; the prior (for Wiener evaluations) from their patches
    pb.joint = load_joint_data(o.cfg, o.data, o.data_format, o.synthetic_scenes, o.design.seed);
    const std::size_t s = o.cfg.sensor_size_px();
    for (const RealStack& c : pb.joint.train)
      for (auto& p : extract_patches(c, s, s / 2)) pb.scenes.push_back(std::move(p));
  } else {
    pb.scenes = training_scenes(o);
  }
  pb.prior = wiener::estimate_prior(pb.scenes, o.prior_bins);
  return pb;
}

std::vector<double> initial_params(const DesignRunOptions& o) {
  const SystemConfig& c = o.cfg;
  const Parameterization kind = o.design.parameterization;
  const std::size_t count = parameter_count(kind, c.n);
  std::vector<double> p(count, 0.0);
  if (o.init == "flat") return p;
  if (o.init == "random") {
    std::mt19937_64 rng(o.design.seed + 17);
    std::uniform_real_distribution<double> u(0.0, c.h_max_m());
    for (double& v : p) v = u(rng);
    return p;
  }
  const Map2D lens = lens_design(c, lens_nm("init", o.init));
  const std::size_t h = c.n / 2;
  for (std::size_t k = 0; k < count; ++k) {
    if (kind == Parameterization::Full2D) p[k] = lens.data[k];
    else if (kind == Parameterization::Radial) p[k] = lens(h, h + k);
    else p[k] = lens(h + k / h, h + k % h);
  }
  return p;
}

std::string fmt_time(double s) {
  char b[32];
  if (s >= 3600) std::snprintf(b, sizeof b, "%dh%02dm", int(s / 3600), int(std::fmod(s, 3600) / 60));
  else if (s >= 60) std::snprintf(b, sizeof b, "%dm%02ds", int(s / 60), int(std::fmod(s, 60)));
  else std::snprintf(b, sizeof b, "%.1fs", s);
  return b;
}

}  // namespace

void DesignRunOptions::validate() const {
  cfg.validate();
  design.validate();
  if (design.mode == DesignMode::QDOM) mask_count(design.quantizer.levels);  // a power of two
  if (objective != "wiener" && objective != "wiener-mse" && objective != "wiener-mae" && objective != "psf-target" &&
      objective != "network")
    reject("objective", objective, "one of wiener, wiener-mse, wiener-mae, psf-target, network");
  const DecoderSpec spec = decoder_spec_from_string(decoder);
  const bool net = spec.kind == DecoderSpec::Kind::ResUNet;
  if (net && objective != "network")
    reject("objective", objective, "network: a network decoder (" + spec.to_string() + ") is trained with its own loss (Eq. 14)");
  if (!net && objective == "network") reject("decoder", decoder, "a network (resunet, resunet:paper, resunet:depth=D,root=R) for objective network");
  if (net) {
    const std::size_t s = cfg.sensor_size_px(), m = std::size_t(1) << (spec.depth - 1);
    if (s % m)
      reject("decoder", decoder, "a depth D whose 2^(D-1) divides the sensor patch size S = " + to_str(s) + " (the network pools D-1 times)");
    if (!(lr_decoder > 0) || !std::isfinite(lr_decoder)) reject("lr_decoder", lr_decoder, "a finite learning rate > 0");
    if (!(gamma_decoder >= 0) || !std::isfinite(gamma_decoder)) reject("gamma_decoder", gamma_decoder, "a finite weight >= 0");
    if (batch > testset::PatchCamera::kMaxBatch) reject("batch", batch, "1 to " + to_str(testset::PatchCamera::kMaxBatch) + " with a network decoder");
  }
  if (!finetune_from.empty()) {
    if (!net) reject("finetune_from", finetune_from, "empty: do-finetune trains a network (a resunet decoder)");
    if (design.mode != DesignMode::DO) reject("mode", to_string(design.mode), "do for a do-finetune run");
  }
  if (objective == "psf-target" && target.rfind("lens:", 0) != 0 && !fs::exists(target))
    reject("target", target, "lens:NM or an existing design .h5 file");
  if (init != "random" && init != "flat" && init.rfind("lens:", 0) != 0) reject("init", init, "random, flat or lens:NM");
  if (init.rfind("lens:", 0) == 0) lens_nm("init", init);
  if (objective == "psf-target" && target.rfind("lens:", 0) == 0) lens_nm("target", target);
  if (epochs < 1) reject("epochs", epochs, ">= 1");
  if (batch < 1) reject("batch", batch, ">= 1");
  if (synthetic_scenes < 1) reject("synthetic_scenes", synthetic_scenes, ">= 1");
  if (prior_bins < 2) reject("prior_bins", prior_bins, ">= 2");
  if (wiener_on != "device" && wiener_on != "cpu") reject("wiener_on", wiener_on, "device or cpu");
  if (checkpoint_every < 1) reject("checkpoint_every", checkpoint_every, ">= 1");
  if (!(decoder_noise_sigma >= 0) || !std::isfinite(decoder_noise_sigma)) reject("noise_sigma", decoder_noise_sigma, ">= 0");
  if (out.empty()) reject("out", "(missing)", "a run folder");
  if (double(design.t1_epochs) > double(epochs)) reject("t1", design.t1_epochs, "<= epochs (" + to_str(epochs) + ")");
  for (const auto& d : data) {
    if (d.rfind("synthetic:", 0) == 0) {  // network runs: N synthetic training scenes beside the real ones
      if (decoder_spec_from_string(decoder).kind != DecoderSpec::Kind::ResUNet)
        reject("data", d, "existing scene files or folders (synthetic:N adds synthetic scenes to a network run's training set)");
      synthetic_count(d);
      continue;
    }
    if (!fs::exists(d)) reject("data", d, "existing scene files or folders, or synthetic:N (network runs)");
  }
}

namespace {

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
// An enum written by its name (to_name) and read back through its parser (from_name).
template <typename Acc, typename From, typename To>
RunField named_field(const char* key, Acc acc, From from_name, To to_name) {
  return {key, [=](DesignRunOptions& o, const json& d) { acc(o) = from_name(d.at(key).get<std::string>()); },
          [=](const DesignRunOptions& o, json& d) { d[key] = to_name(acc(o)); }};
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
      text_field("objective", [](auto& o) -> auto& { return o.objective; }),
      text_field("target", [](auto& o) -> auto& { return o.target; }),
      {"data", [](DesignRunOptions& o, const json& d) { o.data = d.at("data").get<std::vector<std::string>>(); },
       [](const DesignRunOptions& o, json& d) { d["data"] = o.data; }},
      text_field("data_format", [](auto& o) -> auto& { return o.data_format; }),
      integer_field_of<std::size_t>("synthetic_scenes", [](auto& o) -> auto& { return o.synthetic_scenes; }),
      integer_field_of<std::size_t>("batch", [](auto& o) -> auto& { return o.batch; }),
      integer_field_of<std::size_t>("epochs", [](auto& o) -> auto& { return o.epochs; }),
      real_field("decoder_noise_sigma", [](auto& o) -> auto& { return o.decoder_noise_sigma; }),
      integer_field_of<std::size_t>("prior_bins", [](auto& o) -> auto& { return o.prior_bins; }),
      {"wiener_on",
       [](DesignRunOptions& o, const json& d) { o.wiener_on = d.value("wiener_on", std::string("cpu")); },
       [](const DesignRunOptions& o, json& d) { d["wiener_on"] = o.wiener_on; }},
      text_field("init", [](auto& o) -> auto& { return o.init; }),
      integer_field_of<std::size_t>("checkpoint_every", [](auto& o) -> auto& { return o.checkpoint_every; }),
      named_field("precision", [](auto& o) -> auto& { return o.precision; }, precision_from_string,
                  [](Precision p) { return to_string(p); }),
      // Run folders written before the network decoder existed trained against the Wiener decoder.
      {"decoder", [](DesignRunOptions& o, const json& d) { o.decoder = d.value("decoder", std::string("wiener")); },
       [](const DesignRunOptions& o, json& d) { d["decoder"] = o.decoder; }},
      {"lr_decoder", [](DesignRunOptions& o, const json& d) { o.lr_decoder = d.value("lr_decoder", 1e-3); },
       [](const DesignRunOptions& o, json& d) { d["lr_decoder"] = o.lr_decoder; }},
      {"gamma_decoder", [](DesignRunOptions& o, const json& d) { o.gamma_decoder = d.value("gamma_decoder", 1e-4); },
       [](const DesignRunOptions& o, json& d) { d["gamma_decoder"] = o.gamma_decoder; }},
      {"finetune_from", [](DesignRunOptions& o, const json& d) { o.finetune_from = d.value("finetune_from", std::string()); },
       [](const DesignRunOptions& o, json& d) { d["finetune_from"] = o.finetune_from; }},
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

namespace {

std::string read_file_bytes(const fs::path& p) {
  std::ifstream f(p, std::ios::binary);
  if (!f) throw InputError("file '" + p.string() + "': cannot be read");
  std::ostringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

std::string bytes_checksum(const std::string& bytes) {
  Fnv1a64 f;
  f.add(bytes.data(), bytes.size());
  return f.hex();
}

// The network's state at s.step as RUN/network/step_<8 digits>.pt (written, then renamed), named
// with its checksum in s (save_checkpoint then records both).
void save_network_state(const fs::path& dir, const NetworkDecoder& net, DesignState& s) {
  char name[64];
  std::snprintf(name, sizeof name, "network/step_%08ld.pt", s.step);
  make_output_dir((dir / "network").string(), "out");
  const std::string bytes = net.save();
  write_text_atomic((dir / name).string(), bytes);
  s.network_file = name;
  s.network_checksum = bytes_checksum(bytes);
}

// The network file a checkpoint names (its /counters attribute), or "" (none, or unreadable).
std::string network_file_of(const fs::path& ckpt) {
  std::error_code ec;
  if (!fs::is_regular_file(ckpt, ec)) return "";
  try {
    const H5Dataset c = h5_read(ckpt.string(), "/counters", 16);
    const auto it = c.str_attrs.find("network_file");
    return it == c.str_attrs.end() ? "" : it->second;
  } catch (const InputError&) {
    return "";
  }
}

// Removes the network states this run wrote (RUN/network/step_*.pt) that no checkpoint of the
// folder names any more (checkpoint.h5, checkpoint.prev.h5, checkpoint.refused.h5).
void prune_network_states(const fs::path& dir) {
  const fs::path nd = dir / "network";
  std::error_code ec;
  if (!fs::is_directory(nd, ec)) return;
  std::vector<std::string> keep;
  for (const char* c : {"checkpoint.h5", "checkpoint.prev.h5", "checkpoint.refused.h5"}) keep.push_back(network_file_of(dir / c));
  for (const auto& e : fs::directory_iterator(nd, ec)) {
    const std::string fname = e.path().filename().string();
    if (fname.rfind("step_", 0) != 0 || e.path().extension() != ".pt" || fname.size() != 16) continue;  // not ours
    if (std::find(keep.begin(), keep.end(), "network/" + fname) != keep.end()) continue;
    fs::remove(e.path(), ec);
  }
}

// The network state a checkpoint's state names, its checksum verified.
std::string read_network_state(const fs::path& dir, const DesignState& s, const std::string& ckpt) {
  if (s.network_file.empty())
    throw InputError("file '" + ckpt + "': names no network state, but the run trains a network decoder (a checkpoint of a Wiener run?)");
  const fs::path p = dir / s.network_file;
  if (!fs::is_regular_file(p))
    throw InputError("file '" + p.string() + "': missing (named by " + ckpt + "); the run's network state is gone");
  const std::string bytes = read_file_bytes(p);
  const std::string sum = bytes_checksum(bytes);
  if (sum != s.network_checksum)
    throw InputError("file '" + p.string() + "': checksum mismatch (" + ckpt + " recorded " + s.network_checksum + ", the file hashes to " +
                     sum + "): the network state is corrupt");
  return bytes;
}

NetworkSettings network_settings(const DesignRunOptions& o) {
  NetworkSettings ns;
  ns.spec = decoder_spec_from_string(o.decoder);
  ns.in_channels = 3;
  ns.out_channels = o.cfg.bands;
  ns.seed = o.design.seed;
  ns.weight_decay_gamma = o.gamma_decoder;
  return ns;
}

double network_lr(const DesignRunOptions& o, long step) {
  return o.lr_decoder * std::pow(o.design.lr_decay_per_epoch, std::floor(double(step) / double(o.design.steps_per_epoch)));
}

}  // namespace

std::unique_ptr<NetworkDecoder> load_run_network(const std::string& run) {
  const ResumeState st = load_resume_state(run);
  const DesignRunOptions& o = st.options;
  if (decoder_spec_from_string(o.decoder).kind != DecoderSpec::Kind::ResUNet)
    reject("run", run, "a run that trained a network decoder (this one's decoder is " + o.decoder + ")");
  std::unique_ptr<NetworkDecoder> net = make_network_decoder(network_settings(o));
  const fs::path p = fs::path(run) / st.state.network_file;
  net->load(read_network_state(run, st.state, st.checkpoint), p.string());
  return net;
}

DesignRunResult run_design(Runtime& rt, const DesignRunOptions& given, bool resume) {
  const fs::path dir(given.out);
  const RunFolder folder(given.out);
  const fs::path cfg_path = folder.config_path(), ckpt_path = folder.checkpoint_path(), log_path = folder.log_path();
  DesignRunOptions o = given;
  // The folder is ours while this call runs (RunLock): taken first when the folder exists, so
  // its config and checkpoint are read and judged under the lock; else right after creating it.
  std::unique_ptr<RunLock> lock;
  if (!given.out.empty() && fs::is_directory(dir)) lock = std::make_unique<RunLock>(given.out);
  ResumeState resumed;  // read and checked before any work (no device needed)
  if (resume) {
    resumed = load_resume_state(given.out);
    o = resumed.options;
    o.out = given.out;
    o.max_steps = given.max_steps;
    o.quiet = given.quiet;
    if (!resumed.refused.empty()) {
      // Resume from the previous checkpoint; the refused one is set aside (kept for inspection,
      // never deleted), so the next save does not rotate it into checkpoint.prev.h5.
      const fs::path aside = dir / "checkpoint.refused.h5";
      std::fprintf(stderr, "qdo: note: %s: %s; resuming from the previous checkpoint %s (step %ld)%s\n",
                   ckpt_path.string().c_str(), resumed.refused.c_str(), resumed.checkpoint.c_str(), resumed.state.step,
                   fs::exists(ckpt_path) ? ", the refused one kept as checkpoint.refused.h5" : "");
      if (fs::exists(ckpt_path)) fs::rename(ckpt_path, aside);
    }
  } else if (fs::exists(ckpt_path) || fs::exists(checkpoint_prev_path(ckpt_path.string()))) {
    reject("out", given.out, "a folder without a checkpoint (this one holds one: continue it with --resume)");
  }
  o.validate();
  const bool network = o.objective == "network", finetune = !o.finetune_from.empty();
  // do-finetune: the network `do` run it continues (its state, network and configuration checked
  // here, before any writing).
  ResumeState source;
  std::string source_network;
  if (finetune && !resume) {
    source = load_resume_state(o.finetune_from);
    const DesignRunOptions& so = source.options;
    if (so.design.mode != DesignMode::DO || so.decoder != o.decoder || so.design.parameterization != o.design.parameterization ||
        config_to_json_text(so.cfg) != config_to_json_text(o.cfg))
      reject("finetune_from", o.finetune_from,
             "a network do run of this configuration and decoder (it is a " + to_string(so.design.mode) + " run with decoder " + so.decoder + ")");
    source_network = read_network_state(o.finetune_from, source.state, source.checkpoint);
  }
  const Problem pb = make_problem(rt, o);  // reads data and estimates the prior before any writing
  std::unique_ptr<NetworkDecoder> net;
  if (network) net = make_network_decoder(network_settings(o));  // refused here when built without LibTorch
  if (network && resume) net->load(read_network_state(dir, resumed.state, resumed.checkpoint), (dir / resumed.state.network_file).string());
  if (finetune && !resume) net->load(source_network, (fs::path(o.finetune_from) / source.state.network_file).string());
  make_output_dir(dir.string(), "out");
  if (!lock) {
    lock = std::make_unique<RunLock>(given.out);
    if (!resume && fs::exists(ckpt_path))  // another writer made it meanwhile and has finished
      reject("out", given.out, "a folder without a checkpoint (this one holds one: continue it with --resume)");
  }
  if (!resume) write_text_atomic(cfg_path.string(), design_run_options_to_json(o) + "\n");
  if (o.objective != "psf-target") save_prior(folder.prior_path(), pb.prior);
  if (network && !resume) {  // the scenes the network trains and validates on (issue 13 item 6)
    json sp;
    sp["train"] = pb.joint.train_names;
    sp["validation"] = pb.joint.val_names;
    sp["validation_patches"] = pb.joint.val.size();
    sp["patch_px"] = o.cfg.sensor_size_px();
    sp["augmentation"] = "random S x S crops, one of the 8 flips/rotations each (qdo/joint.hpp)";
    if (finetune) sp["finetune_from"] = o.finetune_from;
    write_text_atomic((dir / "split.json").string(), sp.dump(2) + "\n");
  }

  Simulator sim(rt, o.cfg, o.precision);
  Designer d(sim, o.design);
  const std::unique_ptr<wiener::DeviceObjective> dev = network ? nullptr : make_device_objective(rt, o, pb);
  // The device objective evaluated where the PSF lies (Designer::gradient's device path): the same
  // numbers as through the host (float32 survives the double round trip exactly), no PSF copies.
  DevicePsfObjective dev_resident;
  if (dev) dev_resident = [&dev](const cl::Buffer& psf, cl::Buffer& grad) { return dev->expected(psf, grad); };
  std::unique_ptr<JointTrainer> joint;
  if (network) joint = std::make_unique<JointTrainer>(rt, o.cfg, o.precision, *net, pb.joint, o.batch, o.decoder_noise_sigma, o.design.seed);
  const std::size_t levels = static_cast<std::size_t>(o.design.quantizer.levels);
  DesignState s;
  if (resume) {
    s = std::move(resumed.state);
  } else if (finetune) {  // the do run's optics, frozen; a fresh step count
    s = source.state;
    s.step = 0;
  } else {
    s = d.initial_state(initial_params(o));
  }
  if (s.w.size() != parameter_count(o.design.parameterization, o.cfg.n))
    throw Error("internal: resume state sized for another parameterization");
  if (s.offsets.size() != d.level_parameter_count()) {
    if (!finetune) throw Error("internal: resume state sized for another level count");
    s.offsets.assign(d.level_parameter_count(), 0.0);  // do has no trained offsets; the finetune's levels may differ
    s.adam_a = Adam{};
  }
  // do-finetune: the PSF of the frozen, quantized DOE (the run's levels), computed once.
  RealStack frozen_psf;
  if (finetune) {
    sim.set_heights(d.fabricated_heights(s));
    sim.compute_psf();
    frozen_psf = sim.psf_sensor();
  }
  std::vector<std::string> rows = std::move(resumed.log_rows);
  std::vector<double> losses = std::move(resumed.losses);
  const long total = long(o.epochs * o.design.steps_per_epoch);
  const long stop = o.max_steps >= 0 ? std::min(total, o.max_steps) : total;
  auto write_log = [&]() {
    std::string text = "step,loss,loss_aq,alpha,lr,step_s,level_heights_nm";
    if (network) text += ",mae,train_psnr_db,val_psnr_db,lr_decoder";
    text += "\n";
    for (const auto& r : rows) text += r + "\n";
    write_text_atomic(log_path.string(), text);
  };
  const auto t_start = std::chrono::steady_clock::now();
  const long first = s.step;
  double last_loss = losses.empty() ? NAN : losses.back();
  while (s.step < stop) {
    const auto t0 = std::chrono::steady_clock::now();
    const long cur = s.step;
    const double lr_net = network ? network_lr(o, cur) : 0.0;
    StepReport rep;
    if (finetune) {  // the network alone; the optics stay as they are
      RealStack unused;
      rep.step = cur;
      rep.loss = joint->step(cur, lr_net, frozen_psf, unused);
      rep.alpha = 1;
      rep.lr = 0;
      ++s.step;
    } else if (network) {
      const PsfObjective obj = [&](const RealStack& psf, RealStack& grad) { return joint->step(cur, lr_net, psf, grad); };
      rep = d.step(s, obj, nullptr);
    } else {
      rep = d.step(s, make_objective(o, pb, s.step, dev.get()), dev ? &dev_resident : nullptr);
    }
    if (!std::isfinite(rep.loss) || !std::isfinite(rep.loss_aq))
      throw NumericalError("design step " + std::to_string(rep.step) + ": the loss is " + to_str(rep.loss) +
                           " (L_aq " + to_str(rep.loss_aq) + "); stopped before writing it: " + ckpt_path.string() +
                           " still holds step " + std::to_string(s.step - 1 >= 0 ? s.step - 1 : 0) +
                           " or earlier (lower --lr, or check the data)");
    // Validation at the end of each epoch (not where a session stops: a resumed run logs what an
    // uninterrupted one does).
    const bool epoch_end = s.step % long(o.design.steps_per_epoch) == 0;
    double val_psnr = NAN;
    if (network && epoch_end) val_psnr = joint->validation_psnr_db(joint->last_psf());
    const double dt = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    last_loss = rep.loss;
    losses.push_back(rep.loss);
    std::ostringstream row;
    row.precision(10);
    row << rep.step << "," << rep.loss << "," << rep.loss_aq << "," << rep.alpha << "," << rep.lr << "," << dt << ",";
    const auto lv = d.quantizer(s).level_heights_m(o.cfg.h_max_m());
    for (std::size_t l = 0; l < lv.size(); ++l) row << (l ? ";" : "") << lv[l] * 1e9;
    if (network) {
      row << "," << joint->last().mae << "," << joint->last().psnr_db << ",";
      if (std::isfinite(val_psnr)) row << val_psnr;
      row << "," << lr_net;
    }
    rows.push_back(row.str());
    const bool tty = ::isatty(2) != 0;
    const long every = std::max<long>(1, (stop - first) / 20);
    if (!o.quiet && (tty || (s.step - first) % every == 0 || s.step == stop || (network && epoch_end))) {
      const double el = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count();
      const double eta = el / double(s.step - first) * double(stop - s.step);
      std::string extra;
      if (network) {
        char b[96];
        std::snprintf(b, sizeof b, "  train PSNR %.2f dB", joint->last().psnr_db);
        extra = b;
        if (std::isfinite(val_psnr)) {
          std::snprintf(b, sizeof b, "  val PSNR %.2f dB", val_psnr);
          extra += b;
        }
      }
      std::fprintf(stderr, "%s[design %s%s] step %ld/%ld  loss %.5g%s  alpha %.3f  lr %.4g  %.2f s/step  ETA %s   %s",
                   tty ? "\r" : "", finetune ? "do-finetune" : to_string(o.design.mode).c_str(),
                   network ? (", " + o.decoder).c_str() : "", s.step, total, rep.loss, extra.c_str(), rep.alpha, rep.lr, dt,
                   fmt_time(eta).c_str(), tty && !(network && epoch_end) ? "" : "\n");
      std::fflush(stderr);
    }
    if (s.step % long(o.checkpoint_every) == 0 || s.step == stop) {
      write_log();  // the log first: a kill between the two leaves rows the resume redoes, never a gap
      if (network) save_network_state(dir, *net, s);  // then the network state the checkpoint will name
      save_checkpoint(ckpt_path.string(), s);
      if (network) prune_network_states(dir);
    }
  }
  if (!o.quiet && ::isatty(2)) std::fprintf(stderr, "\n");
  if (first == s.step) write_log();

  // Outputs of the design as it would be fabricated.
  Design out;
  out.height_m = d.fabricated_heights(s);
  out.pitch_m = o.cfg.pitch_m;
  if (o.design.mode != DesignMode::Full) out.levels_m = d.quantizer(s).level_heights_m(o.cfg.h_max_m());
  std::map<std::string, std::string> provenance = {{"mode", to_string(o.design.mode)}, {"levels", std::to_string(levels)},
                                                   {"objective", o.objective}, {"steps", std::to_string(s.step)},
                                                   {"run", dir.string()}, {"decoder", o.decoder}};
  if (finetune) provenance["finetune_from"] = o.finetune_from;
  if (o.design.mode == DesignMode::QDOM) {  // the k binary-mask etch depths (level l = sum over the bits of l)
    std::ostringstream md;
    md.precision(12);
    for (std::size_t j = 0; j < s.offsets.size(); ++j) md << (j ? "," : "") << s.offsets[j] * o.cfg.h_max_m() * 1e9;
    provenance["mask_depths_nm"] = md.str();
  }
  write_design(folder.design_path(), out, provenance);
  Design full;
  full.height_m = expand_parameters(o.design.parameterization, d.params_m(s), o.cfg.n, o.cfg.h_max_m());
  full.pitch_m = o.cfg.pitch_m;
  write_design(folder.design_full_path(), full, {{"mode", to_string(o.design.mode)}, {"note", "full-precision H_f"}});
  sim.set_heights(out.height_m);
  sim.compute_psf();
  const RealStack psf = sim.psf_sensor();
  write_psf(folder.psf_path(), psf, o.cfg.wavelengths_nm(), o.cfg.sensor_pitch_m);
  write_montage_png((dir / "psf.png").string(), psf, o.cfg.wavelengths_nm(), 0.5, std::min<std::size_t>(psf.rows, 96));
  write_map_png((dir / "design.png").string(), out.height_m);
  if (!losses.empty()) write_line_plot_png((dir / "loss.png").string(), {losses});
  if (network && !rows.empty()) {  // training PSNR per step (blue), validation PSNR per epoch (red)
    std::vector<double> tr, va;
    for (const auto& r : rows) {
      std::vector<std::string> f;
      std::stringstream ss(r);
      for (std::string x; std::getline(ss, x, ',');) f.push_back(x);
      tr.push_back(f.size() > 8 && !f[8].empty() ? std::strtod(f[8].c_str(), nullptr) : NAN);
      va.push_back(f.size() > 9 && !f[9].empty() ? std::strtod(f[9].c_str(), nullptr) : NAN);
    }
    write_line_plot_png((dir / "psnr.png").string(), {tr, va});
  }
  DesignRunResult r;
  r.steps_done = s.step;
  r.final_loss = last_loss;
  r.levels_m = out.levels_m;
  return r;
}

std::vector<GradcheckRow> gradcheck(Runtime& rt, const DesignRunOptions& given, std::uint64_t seed) {
  DesignRunOptions o = given;
  SystemConfig& c = o.cfg;
  if (c.n > 64) {  // same physics at a smaller N: z scales with N (constant NA and sampling ratio)
    const double f = 64.0 / double(c.n);
    c.sensor_distance_m *= f;
    c.padding_px = std::size_t(double(c.padding_px) * f);
    c.n = 64;
  }
  c.bands = std::min<std::size_t>(c.bands, 4);
  c.srf_interpolate = true;
  o.synthetic_scenes = 4;
  o.design.seed = seed;
  o.design.steps_per_epoch = 2;
  o.design.t0_epochs = 1;
  o.design.t1_epochs = 5;
  c.validate();
  const Precision p = rt.has_fp64() ? Precision::F64 : Precision::F32;
  o.precision = p;
  std::vector<GradcheckRow> rows;
  std::mt19937_64 rng(seed);
  // Error relative to the analytic value, floored at 1 % of the gradient's RMS so entries that
  // are nearly zero do not turn round-off into large relative errors.
  auto rms = [](const std::vector<double>& v) {
    double s2 = 0;
    for (double x : v) s2 += x * x;
    return std::sqrt(s2 / double(std::max<std::size_t>(v.size(), 1)));
  };
  auto rel = [](double fd, double an, double scale) { return std::fabs(fd - an) / std::max({std::fabs(an), 1e-2 * scale, 1e-300}); };

  // 1. The PSF chain: OpenCL adjoint vs CPU reference adjoint, on random heights.
  Simulator sim(rt, c, p);
  Map2D h(c.n, c.n);
  std::uniform_real_distribution<double> uh(0.2 * c.h_max_m(), 0.8 * c.h_max_m());
  for (double& v : h.data) v = uh(rng);
  sim.set_heights(h);
  sim.compute_psf();
  RealStack g(c.bands, sim.sensor_size(), sim.sensor_size());
  std::normal_distribution<double> nd;
  for (double& v : g.data) v = nd(rng);
  const Map2D gk = sim.psf_sensor_vjp(g), gr = ref::psf_sensor_vjp(c, h, g);
  double num = 0, den = 0;
  for (std::size_t i = 0; i < gk.data.size(); ++i) {
    num += (gk.data[i] - gr.data[i]) * (gk.data[i] - gr.data[i]);
    den += gr.data[i] * gr.data[i];
  }
  rows.push_back({"PSF chain: OpenCL " + to_string(p) + " adjoint vs CPU adjoint (rel. L2)", std::sqrt(num / den),
                  p == Precision::F64 ? 1e-9 : 3e-4});
  // 2. CPU adjoint vs central differences on sampled heights.
  auto loss_h = [&](const Map2D& hh) {
    const RealStack s = ref::psf_sensor_stack(c, hh);
    double l = 0;
    for (std::size_t i = 0; i < s.size(); ++i) l += s.data[i] * g.data[i];
    return l;
  };
  double worst = 0;
  for (int k = 0; k < 6; ++k) {
    const std::size_t i = c.n / 2 - 8 + rng() % 16, j = c.n / 2 - 8 + rng() % 16;
    Map2D a = h, b = h;
    a(i, j) += 1e-11;
    b(i, j) -= 1e-11;
    worst = std::max(worst, rel((loss_h(a) - loss_h(b)) / 2e-11, gr(i, j), rms(gr.data)));
  }
  rows.push_back({"PSF chain: CPU adjoint vs central differences (6 heights)", worst, 1e-5});
  // 3-4. End to end through the mode's quantizer and the parameterization, and the offsets.
  const Problem pb = make_problem(rt, o);
  const PsfObjective obj = make_objective(o, pb, 0);
  Designer d(sim, o.design);
  DesignState st = d.initial_state(initial_params(o));
  st.step = 6;  // mid-schedule
  for (std::size_t l = 1; l < st.offsets.size(); ++l) st.offsets[l] = 0.1 * double(l % 3) - 0.1;
  if (o.design.mode == DesignMode::QDOM)  // mask depths: uniform, moved by +-10 % so levels are not uniform
    for (std::size_t j = 0; j < st.offsets.size(); ++j)
      st.offsets[j] = uniform_mask_depths(o.design.quantizer)[j] * (j % 2 ? 0.9 : 1.1);
  auto gd = d.gradient(st, obj);
  // Fault injection, for testing that a wrong gradient is caught and reported (exit code 5):
  // QDO_GRADCHECK_FAULT=1 scales the analytic weight gradient by 1.5 before the comparison.
  if (const char* f = std::getenv("QDO_GRADCHECK_FAULT"); f && std::string(f) == "1")
    for (double& gw : gd.g_w) gw *= 1.5;
  // Central-difference step on the normalised parameters: 1e-5 (7.7 pm of height, ~5e-5 rad) in
  // float64; in float32 the loss carries ~1e-7 relative rounding, which a 1e-5 step turns into
  // errors of several percent (the check failed falsely on float32-only devices), so the step
  // is 2e-3 there (truncation error ~h^2, still below the float32 tolerance).
  const double h_fd = p == Precision::F64 ? 1e-5 : 2e-3;
  worst = 0;
  for (int k = 0; k < 5; ++k) {
    const std::size_t idx = rng() % st.w.size();
    DesignState a = st, b = st;
    a.w[idx] += h_fd;
    b.w[idx] -= h_fd;
    const double fd = (d.gradient(a, obj).report.loss - d.gradient(b, obj).report.loss) / (2 * h_fd);
    worst = std::max(worst, rel(fd, gd.g_w[idx], rms(gd.g_w)));
  }
  const double tol_e2e = p == Precision::F64 ? 1e-4 : 5e-2;
  if (o.design.mode == DesignMode::STE) {
    rows.push_back({"weights w (ste): not a derivative (straight-through); checked in the test suite instead", 0, tol_e2e});
  } else {
    rows.push_back({"weights w (" + to_string(o.design.mode) + ", " + o.objective + ", end to end, 5 samples)", worst, tol_e2e});
  }
  if (o.design.mode == DesignMode::QDOA || o.design.mode == DesignMode::QDOM) {
    // qdo+a: the level offsets a_1.. (a_0 is fixed at 0); qdo+m: every mask depth.
    const bool masks = o.design.mode == DesignMode::QDOM;
    worst = 0;
    for (std::size_t l = masks ? 0 : 1; l < st.offsets.size(); ++l) {
      DesignState a = st, b = st;
      a.offsets[l] += h_fd;
      b.offsets[l] -= h_fd;
      const double fd = (d.gradient(a, obj).report.loss - d.gradient(b, obj).report.loss) / (2 * h_fd);
      worst = std::max(worst, rel(fd, gd.g_offsets[l], rms(gd.g_offsets)));
    }
    rows.push_back({masks ? "mask depths delta (qdo+m)" : "level offsets a (qdo+a)", worst, tol_e2e});
  }
  // 5. The objective with respect to the PSF (CPU, double), at the 6 entries with the largest
  // gradient (most PSF entries barely matter, and their differences are round-off).
  RealStack psf = sim.psf_sensor(), gp;
  const double ref_value = obj(psf, gp);  // also row 6's reference
  worst = 0;
  std::vector<std::size_t> order(psf.size());
  for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::partial_sort(order.begin(), order.begin() + 6, order.end(),
                    [&](std::size_t x, std::size_t y) { return std::fabs(gp.data[x]) > std::fabs(gp.data[y]); });
  for (int k = 0; k < 6; ++k) {
    const std::size_t i = order[std::size_t(k)];
    RealStack a = psf, b = psf, tmp;
    a.data[i] += 1e-7;
    b.data[i] -= 1e-7;
    worst = std::max(worst, rel((obj(a, tmp) - obj(b, tmp)) / 2e-7, gp.data[i], rms(gp.data)));
  }
  rows.push_back({"objective " + o.objective + " vs PSF (6 largest-gradient entries)", worst, 1e-5});
  // 6. The design loop's device objective (wiener, --wiener-on device) against that CPU reference
  // at the same PSF: the larger of the value's relative error and the gradient's relative L2
  // error. Rows 3-5 use the CPU objective (double) so that they check the chain alone.
  if (const auto dev = make_device_objective(rt, o, pb)) {
    const wiener::PsfObjective r = dev->expected(psf);
    double gnum = 0, gden = 0;
    for (std::size_t i = 0; i < gp.data.size(); ++i) {
      gnum += (r.grad_psf.data[i] - gp.data[i]) * (r.grad_psf.data[i] - gp.data[i]);
      gden += gp.data[i] * gp.data[i];
    }
    const double value_err = std::fabs(r.value - ref_value) / std::fabs(ref_value);
    // float64: round-off amplified by the solve's conditioning; float32: the OTFs and A P in float
    // (measured at the paper preset: 3e-8 value, 8e-6 gradient; BENCHMARKS "CPU speed").
    rows.push_back({"objective wiener on the device (" + to_string(o.precision) + ") vs the CPU reference",
                    std::max(value_err, gden > 0 ? std::sqrt(gnum / gden) : std::sqrt(gnum)),
                    o.precision == Precision::F64 ? 1e-8 : 1e-2});
  }
  return rows;
}

}  // namespace qdo
