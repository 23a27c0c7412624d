#include "qdo/sweep.hpp"

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
#include <utility>

#include "data/json_strict.hpp"
#include "qdo/datasets.hpp"
#include "qdo/decoder_registry.hpp"
#include "qdo/design_run.hpp"
#include "qdo/encoders.hpp"
#include "qdo/error.hpp"
#include "qdo/hash.hpp"
#include "qdo/io.hpp"
#include "qdo/optics.hpp"
#include "qdo/run.hpp"
#include "qdo/run_folder.hpp"
#include "qdo/simulator.hpp"

namespace fs = std::filesystem;

namespace qdo {

namespace {

bool run_finished(const fs::path& run) { return fs::exists(run / "DONE"); }

using Fnv = Fnv1a64;  // content hash for provenance checks (qdo/hash.hpp)

// The bytes of a file, or of every regular file under a folder (sorted by path, each with its
// relative path and size); "missing" for a path that does not exist.
void hash_path(Fnv& f, const fs::path& p) {
  f.add(p.string());
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
  if (fs::exists(cfg)) {
    const DesignRunOptions stored = read_run_config(dir.string());
    std::vector<std::string> diffs;
    json_diffs(nlohmann::json::parse(design_run_options_to_json(stored)), nlohmann::json::parse(design_run_options_to_json(o)), "",
               ignore, diffs);
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
  const fs::path stamp = dir / "sweep_inputs";
  if (fs::exists(stamp)) {
    std::string held = read_text(stamp);
    while (!held.empty() && (held.back() == '\n' || held.back() == ' ')) held.pop_back();
    if (held != inputs)
      reject("out", sweep_out, what + " (its training scenes changed since: " + stamp.string() + " holds " + held +
                                   ", the scenes now hash to " + inputs + "; choose another --out, or move that run folder away)");
  }
}

void ensure_run(Runtime& rt, const DesignRunOptions& o, const std::string& inputs, bool quiet, const std::string& sweep_out,
                const std::set<std::string>& ignore = {"design.checkpoint_every"}) {
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

}  // namespace

bool read_cell_metrics(const std::string& path, EvalRow& mean, double& deviation_nm) {
  try {  // a torn, foreign or mistyped file is evaluated again, never half-read
    std::error_code ec;
    if (!fs::is_regular_file(path, ec) || fs::file_size(path, ec) > (std::uintmax_t{1} << 20)) return false;
    const nlohmann::json j = parse_json_strict(read_text(path), "file '" + path + "'");
    const nlohmann::json& m = j.at("mean");
    EvalRow r = mean;
    r.psnr = m.at("psnr_db").get<double>();
    r.psnr_hyper = m.value("psnr_h_db", 0.0);
    r.ssim = m.at("ssim").get<double>();
    r.rmse = m.at("rmse").get<double>();
    r.ergas = m.at("ergas").get<double>();
    r.sam_rad = m.at("sam_rad").get<double>();
    const double dev = j.at("deviation_nm").get<double>();
    for (double v : {r.psnr, r.psnr_hyper, r.ssim, r.rmse, r.ergas, r.sam_rad, dev})
      if (!std::isfinite(v)) return false;
    mean = r;
    deviation_nm = dev;
    return true;
  } catch (const nlohmann::json::exception&) {
    return false;
  } catch (const InputError&) {  // not JSON, or JSON qdo refuses (repeated keys, ...)
    return false;
  }
}

std::vector<GridCell> run_grid(Runtime& rt, const GridOptions& g) {
  if (g.out.empty()) reject("out", "(missing)", "an output folder");
  for (const auto& m : g.modes)
    if (m != "do" && m != "do-refit" && m != "do-finetune" && m != "qdo" && m != "qdo+a" && m != "ste" && m != "qdo+m")
      reject("grid mode", m, "do, do-refit, do-finetune, qdo, qdo+a, ste or qdo+m");
  std::vector<DecoderSpec> decoders;
  for (const DecoderSpec& d : g.decoders.empty() ? std::vector<DecoderSpec>{g.base.decoder} : g.decoders) {
    if (std::find(decoders.begin(), decoders.end(), d) == decoders.end()) decoders.push_back(d);
  }
  if (g.finetune_steps < 1) reject("finetune_steps", g.finetune_steps, ">= 1");
  for (int l : g.levels)
    if (l < 2 || l > 256) reject("grid levels", l, "integers in [2, 256]");
  DesignRunOptions base = g.base;
  base.out = "(set per run)";
  base.decoder = DecoderSpec{};
  if (base.objective == Objective::Network) base.objective = Objective::Wiener;
  base.validate();
  for (const auto& d : decoders) {  // every decoder's runs validated before any work
    DesignRunOptions o = base;
    o.decoder = d;
    if (d.network()) o.objective = Objective::Network;
    o.validate();
    if (d.network() && !network_decoder_available())
      reject("grid decoder", d.to_string(), "wiener: " + network_decoder_unavailable_reason());
  }
  // Test scenes.
  std::vector<std::string> test = g.test_data;
  if (test.empty() && !base.data.empty()) {
    const SceneIndex idx(base.data, base.data_format, base.cfg.bands, base.cfg.wavelengths_nm());
    for (std::size_t i : idx.split(base.design.seed, 0.8, 0.1).test) test.push_back(idx[i].path);
    if (test.empty()) reject("data", base.data.size(), "enough scenes for a test split (or pass test scenes explicitly)");
  }
  const fs::path out(g.out);
  fs::create_directories(out / "runs");
  fs::create_directories(out / "cells");
  // Runs of decoder `dec`: Wiener runs keep the names they always had, network runs carry the spec.
  auto tag_of = [](const DecoderSpec& dec) {
    if (dec.kind == DecoderSpec::Kind::Wiener) return std::string();
    std::string t = "_";
    for (char ch : dec.to_string()) t += ch == ':' || ch == ',' ? '-' : ch == '=' ? '\0' : ch;
    t.erase(std::remove(t.begin(), t.end(), '\0'), t.end());
    return t;
  };
  auto run_opts = [&](DesignMode mode, int levels, const std::string& name, const DecoderSpec& dec) {
    DesignRunOptions o = base;
    o.design.mode = mode;
    o.design.quantizer.levels = levels;
    o.decoder = dec;
    if (dec.network()) o.objective = Objective::Network;
    o.out = (out / "runs" / (name + tag_of(dec))).string();
    return o;
  };
  const std::string train_inputs = hash_paths(base.data);  // once: every run trains on base.data
  // What determines every cell: the test scenes (bytes), and per run, its outputs (bytes).
  const std::string test_inputs = test.empty() ? "synthetic" : hash_paths(test);
  auto run_outputs = [](const std::string& run) {
    std::vector<std::string> files;
    const RunFolder folder(run);
    for (const std::string& f : {folder.config_path(), folder.design_path(), folder.design_full_path(), folder.prior_path()}) files.push_back(f);
    return hash_paths(files);
  };
  auto cell_inputs = [&](const nlohmann::json& cell) {
    nlohmann::json j = cell;
    j["test"] = test_inputs;
    j["test_files"] = test;
    j["eval_synthetic_scenes"] = g.eval_synthetic_scenes;
    j["precision"] = to_string(base.precision);
    j["seed"] = base.design.seed;
    j["system"] = nlohmann::json::parse(config_to_json_text(base.cfg));
    Fnv f;
    f.add(j.dump());
    return f.hex();
  };
  // A cell's metrics.json is reused only when the cell's `inputs` file (written after it) holds
  // the same hash; else the stale stamp is dropped before the cell is evaluated again, so a
  // stamp never vouches for metrics of other inputs.
  auto read_cached = [&](const fs::path& dir, const std::string& inputs, GridCell& c) {
    const fs::path f = dir / "metrics.json", stamp = dir / "inputs";
    std::string held = fs::exists(stamp) ? read_text(stamp) : std::string();
    while (!held.empty() && (held.back() == '\n' || held.back() == ' ')) held.pop_back();
    bool ok = held == inputs && fs::exists(f);
    if (ok) {
      ok = read_cell_metrics(f.string(), c.mean, c.deviation_nm);
    }
    if (!ok) {
      std::error_code ec;
      fs::remove(stamp, ec);  // the sweep's own stamp
    }
    return ok;
  };
  std::vector<GridCell> cells;
  auto eval_cell = [&](const std::string& name, const std::string& mode, int levels, EvalOptions e) {
    GridCell c;
    c.name = name;
    c.mode = mode;
    c.levels = levels;
    const fs::path dir = out / "cells" / name;
    e.data = test;
    e.synthetic_scenes = g.eval_synthetic_scenes;
    e.out = dir.string();
    e.renders = 1;
    e.precision = base.precision;
    c.inputs = cell_inputs({{"cell", name},
                            {"mode", mode},
                            {"levels", levels},
                            {"eval_levels", e.levels},
                            {"placement", to_string(e.placement)},
                            {"decoder", to_string(e.decoder)},
                            {"full_precision", e.full_precision},
                            {"renders", e.renders},
                            {"run", run_outputs(e.run)}});
    if (!read_cached(dir, c.inputs, c)) {  // not finished earlier, or with other inputs
      const EvalResult r = evaluate_run(rt, e);
      c.mean = r.mean;
      c.deviation_nm = r.deviation_nm;
      write_text_atomic((dir / "inputs").string(), c.inputs + "\n");
    }
    if (!g.quiet) std::fprintf(stderr, "[sweep] %-16s PSNR %.2f dB\n", name.c_str(), c.mean.psnr);
    cells.push_back(c);
  };
  const bool doe = std::find(g.encoders.begin(), g.encoders.end(), "doe") != g.encoders.end();
  std::string first_do;  // the first decoder's DO run: the prior of the other encoders
  for (const DecoderSpec& dec : decoders) {
    const bool network = dec.network();
    const std::string tag = tag_of(dec), label = network ? "@" + dec.to_string() : "";
    // DO is trained once in full precision; its levels and placement only shape its design.h5,
    // which no cell reads (cells quantize design_full.h5 themselves).
    const DesignRunOptions do_run = run_opts(DesignMode::DO, g.levels.front(), "do", dec);
    ensure_run(rt, do_run, train_inputs, g.quiet, g.out, {"design.checkpoint_every", "design.levels", "design.placement"});
    if (first_do.empty()) first_do = do_run.out;
    {
      EvalOptions e;
      e.run = do_run.out;
      e.full_precision = true;
      eval_cell("full" + tag, "full" + label, 0, e);
      cells.back().decoder = dec;
    }
    for (int L : g.levels)
      for (const auto& m : g.modes) {
        if (!doe) break;
        if (network && m == "do-refit") {
          if (!g.quiet) std::fprintf(stderr, "[sweep] do-refit_L%d%s skipped: a network has no closed-form refit (do-finetune is its counterpart)\n", L, tag.c_str());
          continue;
        }
        const std::string name = m + "_L" + std::to_string(L) + tag;
        EvalOptions e;
        if (m == "do" || m == "do-refit" || (m == "do-finetune" && !network)) {
          e.run = do_run.out;
          e.levels = L;
          e.placement = base.design.quantizer.placement;
          e.decoder = m == "do" ? DecoderFit::Mismatch : DecoderFit::Matched;
        } else if (m == "do-finetune") {  // the do run's network trained on, the DOE quantized to L and frozen
          DesignRunOptions r = run_opts(DesignMode::DO, L, "do-finetune_L" + std::to_string(L), dec);
          r.finetune_from = do_run.out;
          r.epochs = 1;
          r.design.steps_per_epoch = g.finetune_steps;
          r.design.t0_epochs = 0;
          r.design.t1_epochs = 1;
          r.lr_decoder = base.lr_decoder * std::pow(base.design.lr_decay_per_epoch, double(base.epochs - 1));
          r.design.lr_decay_per_epoch = 1;
          ensure_run(rt, r, train_inputs, g.quiet, g.out);
          e.run = r.out;
        } else {
          const DesignRunOptions r = run_opts(design_mode_from_string(m), L, m + "_L" + std::to_string(L), dec);
          ensure_run(rt, r, train_inputs, g.quiet, g.out);
          e.run = r.out;
        }
        eval_cell(name, m + label, L, e);
        cells.back().decoder = dec;
      }
  }
  const DesignRunOptions do_run = read_run_config(first_do);
  // Other encoders with the same decoder family and the DO run's prior.
  const bool fresnel = std::find(g.encoders.begin(), g.encoders.end(), "fresnel") != g.encoders.end();
  const bool cassi = std::find(g.encoders.begin(), g.encoders.end(), "cassi") != g.encoders.end();
  for (const auto& e : g.encoders)
    if (e != "doe" && e != "fresnel" && e != "cassi") reject("grid encoder", e, "doe, fresnel or cassi");
  if (fresnel || cassi) {
    const wiener::SpectralPrior prior = load_prior(RunFolder(do_run.out).prior_path());
    const Eigen::MatrixXd srf = sensor_response(base.cfg);
    const double sigma = base.decoder_noise_sigma;
    std::vector<RealStack> cubes;
    const std::string prior_inputs = run_outputs(do_run.out);
    auto cached = [&](const std::string& name, GridCell& c) {
      c.inputs = cell_inputs({{"cell", name},
                              {"mode", c.mode},
                              {"levels", c.levels},
                              {"fresnel_design_nm", g.fresnel_design_nm},
                              {"cassi_shift_px", g.cassi_shift_px},
                              {"noise_sigma", sigma},
                              {"prior_run", prior_inputs}});
      return read_cached(out / "cells" / name, c.inputs, c);
    };
    // The decoders of the other encoders come from the registry: wiener for the Fresnel lens's PSF,
    // cg for CASSI (any linear encoder), on the DO run's prior.
    DecoderSpec cg;
    cg.kind = DecoderSpec::Kind::Named;
    cg.name = "cg";
    auto decoder_of = [&](const DecoderSpec& spec, RealStack psf, std::shared_ptr<const Encoder> enc) {
      DecoderInputs in;
      in.spec = spec;
      in.psf = std::move(psf);
      in.srf = srf;
      in.encoder = std::move(enc);
      in.prior = prior;
      in.noise_sigma = sigma;
      return make_decoder(in);
    };
    auto finish = [&](GridCell& c, const EncoderEval& ev) {
      c.mean.psnr = ev.psnr_db;
      c.mean.ssim = ev.ssim;
      c.mean.rmse = ev.rmse;
      c.mean.ergas = ev.ergas;
      c.mean.sam_rad = ev.sam_rad;
      write_cell_metrics(out / "cells" / c.name, c);
    };
    if (fresnel)
      for (int L : g.levels) {
        GridCell c;
        c.name = "fresnel_L" + std::to_string(L);
        c.mode = "fresnel";
        c.levels = L;
        if (!cached(c.name, c)) {
          if (cubes.empty()) cubes = test_patches(base.cfg, test, g.eval_synthetic_scenes, base.design.seed);
          Simulator sim(rt, base.cfg, base.precision);
          sim.set_heights(fresnel_lens_heights(base.cfg, g.fresnel_design_nm, L));
          sim.compute_psf();
          const RealStack psf = sim.psf_sensor();
          const DoeEncoder enc(wiener::psf_to_otf(psf, prior.rows, prior.cols), srf);
          finish(c, evaluate_encoder(enc, *decoder_of(DecoderSpec{}, psf, nullptr), cubes, sigma, base.design.seed + 77));
        }
        if (!g.quiet) std::fprintf(stderr, "[sweep] %-16s PSNR %.2f dB\n", c.name.c_str(), c.mean.psnr);
        cells.push_back(c);
      }
    if (cassi) {
      GridCell c;
      c.name = "cassi";
      c.mode = "cassi";
      c.levels = -1;
      if (!cached(c.name, c)) {
        if (cubes.empty()) cubes = test_patches(base.cfg, test, g.eval_synthetic_scenes, base.design.seed);
        const std::size_t s = base.cfg.sensor_size_px();
        auto enc = std::make_shared<CassiEncoder>(random_binary_mask(s, s, 0.5, base.design.seed + 5), base.cfg.bands, g.cassi_shift_px);
        finish(c, evaluate_encoder(*enc, *decoder_of(cg, RealStack(), enc), cubes, sigma, base.design.seed + 77));
      }
      if (!g.quiet) std::fprintf(stderr, "[sweep] %-16s PSNR %.2f dB\n", c.name.c_str(), c.mean.psnr);
      cells.push_back(c);
    }
  }
  // Tables.
  std::ostringstream t1, t2;
  t1 << "| levels | mode | PSNR [dB] | SSIM | RMSE | ERGAS |\n|---|---|---|---|---|---|\n";
  CsvText t1csv({"levels", "mode", "psnr_db", "ssim", "rmse", "ergas", "psnr_h_db", "sam_rad", "inputs"});
  t2 << "| levels | mode | deviation [nm] |\n|---|---|---|\n";
  CsvText t2csv({"levels", "mode", "deviation_nm", "inputs"});
  char buf[128];
  for (const auto& c : cells) {
    const std::string lv = c.levels == 0 ? "full" : c.levels < 0 ? "n/a" : std::to_string(c.levels);
    std::snprintf(buf, sizeof buf, " | %.2f | %.4f | %.4f | %.2f |\n", c.mean.psnr, c.mean.ssim, c.mean.rmse, c.mean.ergas);
    t1 << "| " << lv << " | " << c.mode << buf;
    t1csv.row({lv, c.mode, csv_number(c.mean.psnr), csv_number(c.mean.ssim), csv_number(c.mean.rmse), csv_number(c.mean.ergas),
               csv_number(c.mean.psnr_hyper), csv_number(c.mean.sam_rad), c.inputs});
    if (c.levels > 0 && c.mode != "fresnel") {
      std::snprintf(buf, sizeof buf, " | %.3f |\n", c.deviation_nm);
      t2 << "| " << c.levels << " | " << c.mode << buf;
      t2csv.row({std::to_string(c.levels), c.mode, csv_number(c.deviation_nm), c.inputs});
    }
  }
  write_text_atomic((out / "table1.md").string(), t1.str());
  write_text_atomic((out / "table1.csv").string(), t1csv.str());
  write_text_atomic((out / "table2.md").string(), t2.str());
  write_text_atomic((out / "table2.csv").string(), t2csv.str());
  // PSNR vs levels, one series per mode (levels in the order given).
  std::vector<std::vector<double>> series;
  for (const auto& dec : decoders)
    for (const auto& m : g.modes) {
      const std::string label = m + (dec.network() ? "@" + dec.to_string() : "");
      std::vector<double> s;
      for (int L : g.levels)
        for (const auto& c : cells)
          if (c.mode == label && c.levels == L) s.push_back(c.mean.psnr);
      if (!s.empty()) series.push_back(s);
    }
  write_line_plot_png((out / "psnr_vs_levels.png").string(), series);
  return cells;
}

}  // namespace qdo
