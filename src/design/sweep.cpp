#include "qdo/sweep.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <cstdint>
#include <fstream>
#include <iterator>
#include <set>
#include <sstream>

#include "qdo/run_folder.hpp"
#include "qdo/datasets.hpp"
#include "qdo/encoders.hpp"
#include "qdo/optics.hpp"
#include "qdo/error.hpp"
#include "data/json_strict.hpp"
#include "qdo/hash.hpp"
#include "qdo/io.hpp"
#include "qdo/run.hpp"
#include "qdo/simulator.hpp"

namespace fs = std::filesystem;

namespace qdo {

double encircled_energy_radius(const RealStack& psf, std::size_t plane, double fraction, double pitch_m) {
  const std::size_t s = psf.rows;
  std::vector<std::pair<double, double>> rv;  // (radius in pixels, energy)
  double total = 0;
  for (std::size_t y = 0; y < s; ++y)
    for (std::size_t x = 0; x < psf.cols; ++x) {
      const double dy = double(y) - double(s / 2), dx = double(x) - double(psf.cols / 2);
      rv.push_back({std::sqrt(dy * dy + dx * dx), psf(plane, y, x)});
      total += psf(plane, y, x);
    }
  if (!(total > 0)) return 0;
  std::sort(rv.begin(), rv.end());
  double acc = 0, prev_r = 0, prev_acc = 0;
  for (const auto& [r, e] : rv) {
    acc += e / total;
    if (acc >= fraction) {
      const double t = acc > prev_acc ? (fraction - prev_acc) / (acc - prev_acc) : 1.0;
      return (prev_r + t * (r - prev_r)) * pitch_m;
    }
    prev_r = r;
    prev_acc = acc;
  }
  return rv.back().first * pitch_m;
}

std::vector<PsfSweepRow> sweep_psf(Runtime& rt, const PsfSweepOptions& o) {
  o.cfg.validate();
  if (o.design_full_m.rows != o.cfg.n || o.design_full_m.cols != o.cfg.n)
    reject("design", to_str(o.design_full_m.rows) + " x " + to_str(o.design_full_m.cols), "N x N = " + to_str(o.cfg.n));
  for (const auto& v : o.variants) v.quantizer.validate();
  const double hmax = o.cfg.h_max_m();
  // Height maps: the reference first, then every variant.
  std::vector<Map2D> maps{o.design_full_m};
  std::vector<std::string> labels{"full"};
  std::vector<int> levels{0};
  for (const auto& v : o.variants) {
    maps.push_back(quantize_heights(o.design_full_m, hmax, v.quantizer));
    labels.push_back(v.label);
    levels.push_back(v.quantizer.levels);
  }
  // How many designs fit one pass: the field buffer (designs x bands x M x M complex).
  const auto g = PropagationGeometry::from_config(o.cfg);
  const std::size_t per_design = o.cfg.bands * g.m * g.m * 2 * real_size(o.precision);
  std::size_t per_pass = o.max_designs_per_pass;
  if (per_pass == 0) per_pass = std::max<std::size_t>(1, rt.info().max_alloc_bytes / per_design);
  per_pass = std::min(per_pass, maps.size());
  const std::size_t bands = o.cfg.bands;
  std::vector<RealStack> psfs(maps.size());
  std::vector<std::vector<double>> outside(maps.size());
  for (std::size_t first = 0; first < maps.size(); first += per_pass) {
    const std::size_t count = std::min(per_pass, maps.size() - first);
    Simulator sim(rt, o.cfg, o.precision, count);
    sim.set_heights_batch(std::vector<Map2D>(maps.begin() + long(first), maps.begin() + long(first + count)));
    sim.compute_psf();
    const RealStack all = sim.psf_sensor();
    for (std::size_t d = 0; d < count; ++d) {
      RealStack p(bands, all.rows, all.cols);
      std::copy(all.plane(d * bands), all.plane(d * bands) + p.size(), p.data.begin());
      psfs[first + d] = std::move(p);
      for (std::size_t b = 0; b < bands; ++b) outside[first + d].push_back(sim.sampling().bands[d * bands + b].energy_outside_window);
    }
  }
  std::vector<PsfSweepRow> rows;
  const RealStack& ref = psfs[0];
  for (std::size_t k = 0; k < maps.size(); ++k) {
    PsfSweepRow r;
    r.label = labels[k];
    r.levels = levels[k];
    r.deviation_nm = quantization_deviation_m(maps[k], maps[0]) * 1e9;
    r.energy_outside = outside[k];
    for (std::size_t b = 0; b < bands; ++b) {
      double num = 0, den = 0, pk = 0, pk0 = 0;
      for (std::size_t i = 0; i < ref.plane_size(); ++i) {
        const double a = psfs[k].plane(b)[i], c = ref.plane(b)[i];
        num += (a - c) * (a - c);
        den += c * c;
        pk = std::max(pk, a);
        pk0 = std::max(pk0, c);
      }
      r.rel_l2.push_back(den > 0 ? std::sqrt(num / den) : 0.0);
      r.peak_ratio.push_back(pk0 > 0 ? pk / pk0 : 0.0);
      r.ee80_um.push_back(encircled_energy_radius(psfs[k], b, 0.8, o.cfg.sensor_pitch_m) * 1e6);
    }
    rows.push_back(r);
  }
  if (!o.out.empty()) {
    fs::create_directories(o.out);
    const auto wl = o.cfg.wavelengths_nm();
    std::ostringstream csv;
    csv.precision(8);
    csv << "variant,levels,deviation_nm,wavelength_nm,rel_l2,peak_ratio,ee80_um,energy_outside_window\n";
    nlohmann::json j = nlohmann::json::array();
    std::vector<H5Dataset> h5;
    auto mean = [](const std::vector<double>& v) {
      double s = 0;
      for (double x : v) s += x;
      return v.empty() ? 0.0 : s / double(v.size());
    };
    for (std::size_t k = 0; k < rows.size(); ++k) {
      const auto& r = rows[k];
      for (std::size_t b = 0; b < bands; ++b)
        csv << r.label << "," << r.levels << "," << r.deviation_nm << "," << wl[b] << "," << r.rel_l2[b] << "," << r.peak_ratio[b] << ","
            << r.ee80_um[b] << "," << r.energy_outside[b] << "\n";
      j.push_back({{"variant", r.label},
                   {"levels", r.levels},
                   {"deviation_nm", r.deviation_nm},
                   {"mean_rel_l2", mean(r.rel_l2)},
                   {"mean_peak_ratio", mean(r.peak_ratio)},
                   {"mean_ee80_um", mean(r.ee80_um)},
                   {"rel_l2", r.rel_l2},
                   {"peak_ratio", r.peak_ratio},
                   {"ee80_um", r.ee80_um},
                   {"energy_outside_window", r.energy_outside}});
      h5.push_back({"/psf_" + r.label, {bands, psfs[k].rows, psfs[k].cols}, psfs[k].data, {{"pitch_m", o.cfg.sensor_pitch_m}}, {}});
      write_montage_png((fs::path(o.out) / ("psf_" + r.label + ".png")).string(), psfs[k], wl, 0.5,
                        std::min<std::size_t>(psfs[k].rows, 96));
    }
    h5.push_back({"/wavelengths_nm", {bands}, wl, {}, {{"units", "nm"}}});
    h5_write((fs::path(o.out) / "psf.h5").string(), h5, {{"config", config_to_json_text(o.cfg)}});
    write_text_atomic((fs::path(o.out) / "sweep.csv").string(), csv.str());
    write_text_atomic((fs::path(o.out) / "sweep.json").string(), j.dump(2) + "\n");
    // Metric vs variant (in the order given, reference first), mean over bands.
    std::vector<double> l2, peak, ee;
    for (const auto& r : rows) {
      l2.push_back(mean(r.rel_l2));
      peak.push_back(mean(r.peak_ratio));
      ee.push_back(mean(r.ee80_um));
    }
    write_line_plot_png((fs::path(o.out) / "rel_l2_vs_variant.png").string(), {std::vector<double>(l2.begin() + 1, l2.end())});
    write_line_plot_png((fs::path(o.out) / "peak_ratio_vs_variant.png").string(), {peak});
    write_line_plot_png((fs::path(o.out) / "ee80_vs_variant.png").string(), {ee});
  }
  return rows;
}

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
  const std::string what = "a sweep folder whose run '" + dir.filename().string() + "' was made with this call's options";
  const fs::path cfg = RunFolder(o.out).config_path();
  if (fs::exists(cfg)) {
    const DesignRunOptions stored = read_run_config(dir.string());
    std::vector<std::string> diffs;
    json_diffs(nlohmann::json::parse(design_run_options_to_json(stored)), nlohmann::json::parse(design_run_options_to_json(o)), "",
               ignore, diffs);
    if (!diffs.empty()) {
      std::string list;
      for (const auto& d : diffs) list += (list.empty() ? "" : "; ") + d;
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

std::vector<GridCell> run_grid(Runtime& rt, const GridOptions& g) {
  if (g.out.empty()) reject("out", "(missing)", "an output folder");
  for (const auto& m : g.modes)
    if (m != "do" && m != "do-refit" && m != "do-finetune" && m != "qdo" && m != "qdo+a" && m != "ste" && m != "qdo+m")
      reject("grid mode", m, "do, do-refit, do-finetune, qdo, qdo+a, ste or qdo+m");
  std::vector<std::string> decoders;
  for (const auto& d : g.decoders.empty() ? std::vector<std::string>{g.base.decoder} : g.decoders) {
    const std::string spec = decoder_spec_from_string(d).to_string();  // refused by name when bad
    if (std::find(decoders.begin(), decoders.end(), spec) == decoders.end()) decoders.push_back(spec);
  }
  if (g.finetune_steps < 1) reject("finetune_steps", g.finetune_steps, ">= 1");
  for (int l : g.levels)
    if (l < 2 || l > 256) reject("grid levels", l, "integers in [2, 256]");
  DesignRunOptions base = g.base;
  base.out = "(set per run)";
  base.decoder = "wiener";
  if (base.objective == "network") base.objective = "wiener";
  base.validate();
  for (const auto& d : decoders) {  // every decoder's runs validated before any work
    DesignRunOptions o = base;
    o.decoder = d;
    if (d != "wiener") o.objective = "network";
    o.validate();
    if (d != "wiener" && !network_decoder_available())
      reject("grid decoder", d, "wiener: " + network_decoder_unavailable_reason());
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
  auto tag_of = [](const std::string& dec) {
    if (dec == "wiener") return std::string();
    std::string t = "_";
    for (char ch : dec) t += ch == ':' || ch == ',' ? '-' : ch == '=' ? '\0' : ch;
    t.erase(std::remove(t.begin(), t.end(), '\0'), t.end());
    return t;
  };
  auto run_opts = [&](DesignMode mode, int levels, const std::string& name, const std::string& dec) {
    DesignRunOptions o = base;
    o.design.mode = mode;
    o.design.quantizer.levels = levels;
    o.decoder = dec;
    if (dec != "wiener") o.objective = "network";
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
      try {  // a torn, foreign or mistyped file is evaluated again, never half-read
        const nlohmann::json j = parse_json_strict(read_text(f), "file '" + f.string() + "'");
        const nlohmann::json& m = j.at("mean");
        GridCell r = c;
        r.mean.psnr = m.at("psnr_db").get<double>();
        r.mean.psnr_hyper = m.value("psnr_h_db", 0.0);
        r.mean.ssim = m.at("ssim").get<double>();
        r.mean.rmse = m.at("rmse").get<double>();
        r.mean.ergas = m.at("ergas").get<double>();
        r.mean.sam_rad = m.at("sam_rad").get<double>();
        r.deviation_nm = j.at("deviation_nm").get<double>();
        c = r;
      } catch (const nlohmann::json::exception&) {
        ok = false;
      }
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
                            {"decoder", e.decoder},
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
  for (const std::string& dec : decoders) {
    const bool network = dec != "wiener";
    const std::string tag = tag_of(dec), label = network ? "@" + dec : "";
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
          e.decoder = m == "do" ? "mismatch" : "matched";
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
          const ComplexStack otf = wiener::psf_to_otf(sim.psf_sensor(), prior.rows, prior.cols);
          finish(c, evaluate_encoder(DoeEncoder(otf, srf), WienerDecoder(otf, srf, prior, sigma), cubes, sigma,
                                     base.design.seed + 77));
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
        finish(c, evaluate_encoder(*enc, CgDecoder(enc, prior, sigma), cubes, sigma, base.design.seed + 77));
      }
      if (!g.quiet) std::fprintf(stderr, "[sweep] %-16s PSNR %.2f dB\n", c.name.c_str(), c.mean.psnr);
      cells.push_back(c);
    }
  }
  // Tables.
  std::ostringstream t1, t1csv, t2, t2csv;
  t1 << "| levels | mode | PSNR [dB] | SSIM | RMSE | ERGAS |\n|---|---|---|---|---|---|\n";
  t1csv << "levels,mode,psnr_db,ssim,rmse,ergas,psnr_h_db,sam_rad,inputs\n";
  t2 << "| levels | mode | deviation [nm] |\n|---|---|---|\n";
  t2csv << "levels,mode,deviation_nm,inputs\n";
  char buf[256];
  for (const auto& c : cells) {
    const std::string lv = c.levels == 0 ? "full" : c.levels < 0 ? "n/a" : std::to_string(c.levels);
    std::snprintf(buf, sizeof buf, "| %s | %s | %.2f | %.4f | %.4f | %.2f |\n", lv.c_str(), c.mode.c_str(), c.mean.psnr, c.mean.ssim,
                  c.mean.rmse, c.mean.ergas);
    t1 << buf;
    std::snprintf(buf, sizeof buf, "%s,%s,%.6g,%.6g,%.6g,%.6g,%.6g,%.6g,%s\n", lv.c_str(), c.mode.c_str(), c.mean.psnr, c.mean.ssim,
                  c.mean.rmse, c.mean.ergas, c.mean.psnr_hyper, c.mean.sam_rad, c.inputs.c_str());
    t1csv << buf;
    if (c.levels > 0 && c.mode != "fresnel") {
      std::snprintf(buf, sizeof buf, "| %d | %s | %.3f |\n", c.levels, c.mode.c_str(), c.deviation_nm);
      t2 << buf;
      std::snprintf(buf, sizeof buf, "%d,%s,%.6g,%s\n", c.levels, c.mode.c_str(), c.deviation_nm, c.inputs.c_str());
      t2csv << buf;
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
      const std::string label = m + (dec == "wiener" ? "" : "@" + dec);
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
