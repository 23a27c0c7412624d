#include "qdo/design/run_folder.hpp"

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "qdo/runtime/error.hpp"
#include "qdo/design/run.hpp"

namespace fs = std::filesystem;

namespace qdo {

RunFolder::RunFolder(std::string dir) : dir_(std::move(dir)) {}

std::string RunFolder::path(const std::string& name) const { return (fs::path(dir_) / name).string(); }

const std::vector<std::string>& RunFolder::file_names() {
  static const std::vector<std::string> names{"config.json", "checkpoint.h5", "checkpoint.prev.h5", "checkpoint.next.h5",
                                              "checkpoint.refused.h5", "log.csv", "prior.h5", "design.h5",
                                              "design_full.h5", "psf.h5", "psf.png", "psf.svg", "design.png",
                                              "design.svg", "loss.png", "loss.svg", "psnr.png", "psnr.svg",
                                              "split.json", "range.csv", "range.png", "range.svg"};
  return names;
}

DesignRunOptions RunFolder::config(const std::string& argument, const std::string& allowed) const {
  return read_run_config(dir_, argument, allowed);
}

Design RunFolder::design() const { return read_design(design_path()); }
Design RunFolder::design_full() const { return read_design(design_full_path()); }

wiener::SpectralPrior RunFolder::prior(std::size_t grid_px) const {
  wiener::SpectralPrior p = load_prior(prior_path());
  if (p.rows != grid_px || p.cols != grid_px)
    reject("prior", prior_path(), "a prior on the S x S sensor grid, S = " + to_str(grid_px) + " (it is " + to_str(p.rows) + " x " + to_str(p.cols) + ")");
  return p;
}

void save_prior(const std::string& path, const wiener::SpectralPrior& p) {
  h5_write(path, {H5Dataset{"/cov", {p.bins, p.bands, p.bands}, p.cov, {{"rows", double(p.rows)}, {"cols", double(p.cols)}},
                            {{"meaning", "E[X(f) X(f)^H] / (H W) per radial bin (qdo/decode/wiener.hpp)"}}}});
}

wiener::SpectralPrior load_prior(const std::string& path) {
  const H5Dataset d = h5_read(path, "/cov");
  if (d.shape.size() != 3 || d.shape[1] != d.shape[2] || !d.num_attrs.count("rows") || !d.num_attrs.count("cols"))
    throw InputError("file '" + path + "': dataset '/cov' must be bins x B x B with attributes rows and cols");
  wiener::SpectralPrior p;
  p.bins = d.shape[0];
  p.bands = d.shape[1];
  p.rows = std::size_t(d.num_attrs.at("rows"));
  p.cols = std::size_t(d.num_attrs.at("cols"));
  p.cov = d.data;
  p.validate();
  return p;
}

DesignRunOptions read_run_options(const std::string& config_path) {
  std::ifstream f(config_path, std::ios::binary);
  if (!f) throw InputError("file '" + config_path + "': cannot be read");
  std::stringstream ss;
  ss << f.rdbuf();
  DesignRunOptions o = design_run_options_from_json(ss.str(), config_path);
  try {
    o.out = "(the run folder)";  // validate() wants one; the caller sets it
    o.validate();
  } catch (const InputError& e) {  // e.g. "argument 'epochs' = 0": a stored value, not an argument
    throw InputError("file '" + config_path + "': " + e.what());
  }
  return o;
}

DesignRunOptions read_run_config(const std::string& run, const std::string& argument, const std::string& allowed,
                                 bool allow_range) {
  const fs::path p = RunFolder(run).config_path();
  if (!fs::is_regular_file(p)) reject(argument, run, allowed);
  std::ifstream f(p, std::ios::binary);
  if (!f) throw InputError("file '" + p.string() + "': cannot be read");
  std::stringstream ss;
  ss << f.rdbuf();
  DesignRunOptions o = design_run_options_from_json(ss.str(), p.string());
  if (!allow_range && o.cfg.point_count() > 1)
    reject(argument, run,
           "a run designed for one object point (this one was trained over " + to_str(o.cfg.point_count()) +
               " object points, see its range.csv; qdo eval-points evaluates such a run; here pass its "
               "design.h5 where the command takes a design file)");
  o.out = run;
  return o;
}

void read_resume_log(const std::string& log_path, long before_step, std::vector<std::string>& rows,
                     std::vector<double>& losses) {
  std::ifstream f(log_path);
  if (!f) throw InputError("file '" + log_path + "': cannot be read");
  std::string line;
  std::getline(f, line);  // header
  for (std::size_t lineno = 2; std::getline(f, line); ++lineno) {
    // step,loss,...: both numbers must parse, or the log is not ours.
    const char* p = line.c_str();
    char* end = nullptr;
    const long st = std::strtol(p, &end, 10);
    double loss = 0;
    bool ok = end != p && *end == ',';
    if (ok) {
      const char* q = end + 1;
      loss = std::strtod(q, &end);
      ok = end != q;
    }
    if (!ok)
      throw InputError("file '" + log_path + "': line " + std::to_string(lineno) + " is not a log row (step,loss,...): '" +
                       line.substr(0, 60) + "'");
    if (st < before_step) {  // rows at or after the checkpoint's step are redone
      // The rows kept are the steps 0, 1, ... in order, each once: a log cut short (or edited)
      // would leave a gap or a repeat in the resumed log.
      const long want = long(rows.size());
      if (st != want)
        throw InputError("file '" + log_path + "': line " + std::to_string(lineno) + " is step " + std::to_string(st) + " where step " +
                         std::to_string(want) + " was expected; the checkpoint is at step " + std::to_string(before_step) +
                         ", so resuming would leave the log with a " + (st > want ? "gap" : "repeated step") +
                         " (restore the log, or start a new run)");
      rows.push_back(line);
      losses.push_back(loss);
    }
  }
  if (!rows.empty() && long(rows.size()) != before_step)
    throw InputError("file '" + log_path + "': ends at step " + std::to_string(long(rows.size()) - 1) + " but the checkpoint is at step " +
                     std::to_string(before_step) + "; steps " + std::to_string(rows.size()) + " to " + std::to_string(before_step - 1) +
                     " are missing, so resuming would leave the log with a gap (restore the log, or start a new run)");
}

ResumeState load_resume_state(const std::string& dir) {
  const RunFolder run(dir);
  const fs::path cfg_path = run.config_path(), ckpt_path = run.checkpoint_path(), log_path = run.log_path();
  const fs::path prev_path = checkpoint_prev_path(ckpt_path.string());
  if (!fs::exists(cfg_path) || (!fs::exists(ckpt_path) && !fs::exists(prev_path)))
    reject("out", dir, "a run folder with config.json and checkpoint.h5 to resume (start without --resume)");
  ResumeState r;
  r.options = read_run_options(cfg_path.string());
  r.options.out = dir;
  const DesignOptions& o = r.options.design;
  const std::size_t levels =
      o.mode == DesignMode::QDOM ? std::size_t(mask_count(o.quantizer.levels)) : std::size_t(o.quantizer.levels);
  auto load = [&](const fs::path& p) {
    return load_checkpoint(p.string(), parameter_count(o.parameterization, r.options.cfg.n), levels, o.mode == DesignMode::QDOM,
                           o.quantizer.pin_top);
  };
  r.checkpoint = ckpt_path.string();
  try {
    if (!fs::exists(ckpt_path)) {
      r.refused = "missing (a kill between keeping the previous checkpoint and writing the new one)";
    } else {
      r.state = load(ckpt_path);
    }
  } catch (const InputError& e) {
    if (!fs::exists(prev_path)) throw;
    r.refused = e.what();
  }
  if (!r.refused.empty()) {  // the previous good checkpoint, or the error about checkpoint.h5
    try {
      r.state = load(prev_path);
    } catch (const InputError&) {
      if (fs::exists(ckpt_path)) load(ckpt_path);  // rethrows the error about checkpoint.h5
      throw;
    }
    r.checkpoint = prev_path.string();
  }
  if (fs::exists(log_path)) read_resume_log(log_path.string(), r.state.step, r.log_rows, r.losses);
  return r;
}

Map2D read_design_heights_for(const SystemConfig& cfg, const std::string& path, const std::string& argument) {
  if (!fs::is_regular_file(path)) reject(argument, path, "an existing design .h5 file");
  const Design d = read_design(path);
  if (d.height_m.rows != cfg.n || d.height_m.cols != cfg.n)
    reject(argument, path, "a height map of N x N = " + to_str(cfg.n) + " x " + to_str(cfg.n) + " samples, the configuration's (the file has " +
                               to_str(d.height_m.rows) + " x " + to_str(d.height_m.cols) + ")");
  if (std::fabs(d.pitch_m - cfg.pitch_m) > 1e-6 * cfg.pitch_m)
    reject(argument, path, "pitch_m = " + to_str(cfg.pitch_m) + " as configured (the file has " + to_str(d.pitch_m) + ")");
  const double hmax = cfg.h_max_m();
  for (std::size_t i = 0; i < d.height_m.data.size(); ++i) {
    const double h = d.height_m.data[i];
    if (!std::isfinite(h) || h < 0 || h > 2 * hmax)
      reject(argument, path,
             "heights in [0, 2 h_max] = [0, " + to_str(2 * hmax) + "] m for this configuration (the file's /height_m[" +
                 to_str(i / d.height_m.cols) + "][" + to_str(i % d.height_m.cols) + "] = " + to_str(h) + " m)");
  }
  return d.height_m;
}

Map2D design_heights_from_spec(const SystemConfig& cfg, const std::string& spec, const std::string& argument) {
  if (spec.empty()) reject(argument, "(missing)", "lens:NM (a diffractive lens for NM nanometres), flat, or a design .h5 file");
  if (spec == "flat") return flat_design(cfg);
  if (spec.rfind("lens:", 0) == 0) {
    char* end = nullptr;
    const double nm = std::strtod(spec.c_str() + 5, &end);
    if (*end || !(nm > 0)) reject(argument, spec, "lens:NM with NM a wavelength in nm, e.g. lens:550");
    return lens_design(cfg, nm);
  }
  return read_design_heights_for(cfg, spec, argument);
}

}  // namespace qdo
