#include "qdo/evaluate/sweep.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <cstdint>
#include <fstream>
#include <iterator>
#include <memory>
#include <set>
#include <sstream>
#include <thread>
#include <chrono>
#include <utility>

#include "evaluate/sweep_internal.hpp"

#include "data/json_strict.hpp"
#include "qdo/data/datasets.hpp"
#include "qdo/decode/decoder_registry.hpp"
#include "qdo/design/design_run.hpp"
#include "qdo/decode/encoders.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/hash.hpp"
#include "qdo/data/io.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/design/run.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/physics/simulator.hpp"

namespace fs = std::filesystem;

namespace qdo::sweep_detail {

bool run_finished(const fs::path& run) { return fs::exists(run / "DONE"); }

using Fnv = Fnv1a64;  // content hash for provenance checks (qdo/runtime/hash.hpp)

// The bytes of a file, or of every regular file under a folder (sorted by path, each with its
// relative path and size); "missing" for a path that does not exist. Only the last name of `p`
// enters, never its spelling: `sw`, `./sw` and `$PWD/sw/` (a Slurm array and its collect step
// spell paths as they like) name the same inputs.
void hash_path(Fnv& f, const fs::path& p) {
  std::error_code ec;
  fs::path canon = fs::weakly_canonical(p, ec);
  if (ec) canon = p.lexically_normal();
  if (canon.filename().empty()) canon = canon.parent_path();  // "dir/"
  f.add(canon.filename().string());
  auto file = [&](const fs::path& q) {
    std::ifstream in(q, std::ios::binary);
    if (!in) throw InputError("file '" + q.string() + "': cannot be read (to hash a sweep cell's inputs)");
    f.add(std::to_string(fs::file_size(q)));
    std::vector<char> buf(1 << 20);
    while (in) {
      in.read(buf.data(), std::streamsize(buf.size()));
      f.add(buf.data(), std::size_t(in.gcount()));
    }
  };
  if (!fs::exists(p)) {
    f.add("missing");
  } else if (fs::is_directory(p)) {
    std::vector<fs::path> files;
    for (const auto& e : fs::recursive_directory_iterator(p))
      if (e.is_regular_file()) files.push_back(e.path());
    std::sort(files.begin(), files.end());
    for (const auto& q : files) {
      f.add(fs::relative(q, p).string());
      file(q);
    }
  } else {
    file(p);
  }
}

std::string hash_paths(const std::vector<std::string>& paths) {
  Fnv f;
  f.add(std::to_string(paths.size()));
  for (const auto& p : paths) hash_path(f, p);
  return f.hex();
}

std::string read_text(const fs::path& p) {
  std::ifstream f(p, std::ios::binary);
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

// Every field that differs between two JSON objects, as "a.b: stored X, given Y".
void json_diffs(const nlohmann::json& stored, const nlohmann::json& given, const std::string& prefix,
                const std::set<std::string>& ignore, std::vector<std::string>& out) {
  for (auto it = given.begin(); it != given.end(); ++it) {
    const std::string key = prefix + it.key();
    if (ignore.count(key)) continue;
    if (!stored.contains(it.key())) out.push_back(key + ": stored (absent), given " + it.value().dump());
    else if (stored.at(it.key()).is_object() && it.value().is_object()) json_diffs(stored.at(it.key()), it.value(), key + ".", ignore, out);
    else if (stored.at(it.key()) != it.value()) out.push_back(key + ": stored " + stored.at(it.key()).dump() + ", given " + it.value().dump());
  }
  for (auto it = stored.begin(); it != stored.end(); ++it)
    if (!given.contains(it.key()) && !ignore.count(prefix + it.key()))
      out.push_back(prefix + it.key() + ": stored " + it.value().dump() + ", given (absent)");
}

// Test cubes as S x S patches, as evaluate_run cuts them.
std::vector<RealStack> test_patches(const SystemConfig& cfg, const std::vector<std::string>& test, std::size_t synthetic,
                                    std::uint64_t seed) {
  const std::size_t s = cfg.sensor_size_px();
  std::vector<RealStack> out;
  if (test.empty()) {
    const SceneIndex idx = SceneIndex::synthetic(cfg, synthetic, s, seed + 1000003);
    for (std::size_t i = 0; i < idx.size(); ++i) out.push_back(idx.load(i));
    return out;
  }
  const SceneIndex idx(test, "auto", cfg.bands, cfg.wavelengths_nm());
  for (std::size_t i = 0; i < idx.size(); ++i)
    for (auto& p : extract_patches(idx.load(i), s, s)) out.push_back(std::move(p));
  return out;
}

void write_cell_metrics(const fs::path& dir, const GridCell& c) {
  fs::create_directories(dir);
  nlohmann::json j;
  j["mode"] = c.mode;
  j["levels"] = c.levels;
  j["deviation_nm"] = c.deviation_nm;
  if (std::isfinite(c.deviation_rings_nm)) j["deviation_rings_nm"] = c.deviation_rings_nm;
  j["inputs"] = c.inputs;
  j["mean"] = {{"psnr_db", c.mean.psnr}, {"psnr_h_db", c.mean.psnr_hyper}, {"ssim", c.mean.ssim},
               {"rmse", c.mean.rmse},    {"ergas", c.mean.ergas},          {"sam_rad", c.mean.sam_rad}};
  write_text_atomic((dir / "metrics.json").string(), j.dump(2) + "\n");
  write_text_atomic((dir / "inputs").string(), c.inputs + "\n");
}

// A run folder of an earlier sweep is reused (finished) or resumed only when it was made with
// the same options (its config.json) and the same training scenes (bytes, runs/NAME/sweep_inputs);
// otherwise the sweep stops naming the differences (it deletes nothing). `ignore`: fields that do
// not change what the sweep uses from the run. `inputs`: the hash of o.data's bytes.
void check_run_inputs(const DesignRunOptions& o, const std::string& inputs, const std::string& sweep_out,
                      const std::set<std::string>& ignore) {
  const fs::path dir(o.out);
  // The message says what is wrong: the folder holds a run made with other options or scenes.
  const std::string what = "a new sweep folder, or one whose runs were made with this call's options; its run '" +
                           dir.filename().string() + "' was made with other ones";
  const fs::path cfg = RunFolder(o.out).config_path();
  const fs::path stamp = dir / "sweep_inputs";
  if (fs::exists(cfg)) {
    const DesignRunOptions stored = read_run_config(dir.string());
    std::vector<std::string> diffs;
    // With the stamp, the training scenes are compared by their bytes (below), not by how the
    // paths to them are spelt.
    std::set<std::string> ign = ignore;
    if (fs::exists(stamp)) ign.insert("design.data");
    ign.insert("system.preset");  // informational: which preset a configuration started from
    json_diffs(nlohmann::json::parse(design_run_options_to_json(stored)), nlohmann::json::parse(design_run_options_to_json(o)), "",
               ign, diffs);
    if (!diffs.empty()) {
      std::string list;
      for (std::string d : diffs) {
        // A do-finetune run's steps come from --finetune-steps (its epochs are 1).
        if (!o.finetune_from.empty() && d.rfind("design.steps_per_epoch", 0) == 0) d = "--finetune-steps (" + d + ")";
        list += (list.empty() ? "" : "; ") + d;
      }
      reject("out", sweep_out, what + " (" + cfg.string() + " differs: " + list +
                                   "; choose another --out, or move that run folder and the cells/ folder away to redo them)");
    }
  }
  if (fs::exists(stamp)) {
    std::string held = read_text(stamp);
    while (!held.empty() && (held.back() == '\n' || held.back() == ' ')) held.pop_back();
    if (held != inputs)
      reject("out", sweep_out, what + " (its training scenes changed since: " + stamp.string() + " holds " + held +
                                   ", the scenes now hash to " + inputs + "; choose another --out, or move that run folder away)");
  }
}

void ensure_run(Runtime& rt, const DesignRunOptions& o, const std::string& inputs, bool quiet, const std::string& sweep_out,
                const std::set<std::string>& ignore) {
  const fs::path dir(o.out);
  check_run_inputs(o, inputs, sweep_out, ignore);
  if (!fs::exists(dir / "sweep_inputs")) {  // runs of sweeps before this check: their options matched
    fs::create_directories(dir);
    write_text_atomic((dir / "sweep_inputs").string(), inputs + "\n");
  }
  if (run_finished(dir)) return;
  DesignRunOptions r = o;
  r.quiet = quiet;
  const bool resume = fs::exists(RunFolder(o.out).checkpoint_path());
  if (!quiet) std::fprintf(stderr, "[sweep] %s run %s\n", resume ? "resuming" : "starting", o.out.c_str());
  run_design(rt, r, resume);
  write_text_atomic((dir / "DONE").string(), "finished\n");
}

void ensure_run_waiting(Runtime& rt, const DesignRunOptions& o, const std::string& inputs, bool quiet, const std::string& sweep_out,
                        const std::set<std::string>& ignore) {
  bool told = false;
  for (;;) {
    try {
      ensure_run(rt, o, inputs, quiet, sweep_out, ignore);
      return;
    } catch (const RunBusyError& e) {
      // Another process (a rank, a job array task, a second sweep) trains this run: wait for it.
      if (!told) std::fprintf(stderr, "[sweep] waiting for run %s (another process trains it: %s)\n", o.out.c_str(), e.what());
      told = true;
      std::this_thread::sleep_for(std::chrono::seconds(2));
    }
  }
}

}  // namespace qdo::sweep_detail

namespace qdo {

using namespace sweep_detail;

bool read_cell_metrics(const std::string& path, EvalRow& mean, double& deviation_nm, std::vector<EvalRow>* scenes,
                       double* deviation_rings_nm) {
  try {  // a torn, foreign or mistyped file is evaluated again, never half-read
    std::error_code ec;
    if (!fs::is_regular_file(path, ec) || fs::file_size(path, ec) > (std::uintmax_t{1} << 20)) return false;
    const nlohmann::json j = parse_json_strict(read_text(path), "file '" + path + "'");
    auto row_of = [](const nlohmann::json& m, EvalRow r) {
      r.psnr = m.at("psnr_db").get<double>();
      r.psnr_hyper = m.value("psnr_h_db", 0.0);
      r.ssim = m.at("ssim").get<double>();
      r.rmse = m.at("rmse").get<double>();
      r.ergas = m.at("ergas").get<double>();
      r.sam_rad = m.at("sam_rad").get<double>();
      for (double v : {r.psnr, r.psnr_hyper, r.ssim, r.rmse, r.ergas, r.sam_rad})
        if (!std::isfinite(v)) throw std::domain_error("not finite");
      return r;
    };
    const EvalRow r = row_of(j.at("mean"), mean);
    const double dev = j.at("deviation_nm").get<double>();
    if (!std::isfinite(dev)) return false;
    std::vector<EvalRow> rows;
    if (scenes) {
      const nlohmann::json& ps = j.at("per_scene");
      if (!ps.is_array() || ps.empty() || ps.size() > 100000) return false;
      for (const auto& e : ps) {
        EvalRow row = row_of(e, EvalRow{});
        row.scene = e.at("scene").get<std::string>();
        rows.push_back(row);
      }
    }
    mean = r;
    deviation_nm = dev;
    if (deviation_rings_nm) {
      const auto it = j.find("deviation_rings_nm");
      *deviation_rings_nm = it != j.end() && it->is_number() && std::isfinite(it->get<double>()) ? it->get<double>() : NAN;
    }
    if (scenes) *scenes = std::move(rows);
    return true;
  } catch (const nlohmann::json::exception&) {
    return false;
  } catch (const std::domain_error&) {
    return false;
  } catch (const InputError&) {  // not JSON, or JSON qdo refuses (repeated keys, ...)
    return false;
  }
}

}  // namespace qdo
