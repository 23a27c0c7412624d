// The cells of the sweep's grid (Grid, sweep_internal.hpp): what determines a cell (its inputs
// hash), reading a finished one, and running one (training its runs, then evaluating it).
#include <nlohmann/json.hpp>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <utility>

#include "evaluate/sweep_internal.hpp"
#include "qdo/decode/decoder_registry.hpp"
#include "qdo/design/design_run.hpp"
#include "qdo/decode/encoders.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/hash.hpp"
#include "qdo/data/io.hpp"
#include "qdo/runtime/mpi.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/design/run.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/evaluate/sweep.hpp"

namespace fs = std::filesystem;

namespace qdo {

using namespace sweep_detail;

const std::string& Grid::train_inputs() {
  if (train_inputs_.empty()) train_inputs_ = hash_paths(base_.data);  // every run trains on base.data
  return train_inputs_;
}

std::string Grid::run_outputs(const std::string& run) const {
  const RunFolder folder(run);
  return hash_paths({folder.config_path(), folder.design_path(), folder.design_full_path(), folder.prior_path()});
}

// What determines a cell: its own fields, the test scenes (bytes), and its runs' outputs (bytes).
std::string Grid::cell_inputs(const Job& job) const {
  nlohmann::json j = job.key;
  j["test"] = test_inputs_;
  j["test_files"] = test_.size();  // their bytes and names are in test_inputs_, never their spelling
  j["eval_synthetic_scenes"] = g_.eval_synthetic_scenes;
  j["precision"] = to_string(base_.precision);
  j["system"] = nlohmann::json::parse(config_to_json_text(base_.cfg));
  if (job.kind == CellKind::Eval) j["run"] = run_outputs(job.eval.run);
  else j["prior_run"] = run_outputs(job.prior_run);
  Fnv1a64 f;
  f.add(j.dump());
  return f.hex();
}

// A cell's metrics.json is reused only when the cell's `inputs` file (written after it) holds the
// same hash. Reading changes nothing (--collect only reads); run_cell drops a stale stamp before
// it evaluates again, so that a stamp never vouches for metrics of other inputs.
bool Grid::read_cell(std::size_t k, GridCell& c) const {
  const Job& job = jobs_.at(k);
  c = GridCell{};
  c.name = job.plan.name;
  c.mode = job.plan.mode;
  c.decoder = job.plan.decoder;
  c.levels = job.plan.levels;
  c.seed = job.plan.seed;
  for (const auto& r : job.plan.runs)
    if (!run_finished(r)) return false;
  c.inputs = cell_inputs(job);
  const fs::path dir = out_ / "cells" / job.plan.name, f = dir / "metrics.json", stamp = dir / "inputs";
  std::string held = fs::exists(stamp) ? read_text(stamp) : std::string();
  while (!held.empty() && (held.back() == '\n' || held.back() == ' ')) held.pop_back();
  return held == c.inputs && fs::exists(f) &&
         read_cell_metrics(f.string(), c.mean, c.deviation_nm, job.kind == CellKind::Eval ? &c.scenes : nullptr,
                           &c.deviation_rings_nm);
}

void Grid::run_cell(Runtime& rt, std::size_t k, bool progress) {
  const mpi::Solo alone;  // a cell's runs train in this process alone, whatever the other ranks do
  const Job& job = jobs_.at(k);
  const auto t0 = std::chrono::steady_clock::now();
  const fs::path dir = out_ / "cells" / job.plan.name;
  // Runs of other options or scenes are refused before anything is written (the cell's lock included).
  for (std::size_t i = 0; i < job.runs.size(); ++i) check_run_inputs(job.runs[i], train_inputs(), g_.out, job.ignores[i]);
  fs::create_directories(dir);
  fs::create_directories(out_ / "runs");
  std::unique_ptr<RunLock> lock;
  try {
    lock = std::make_unique<RunLock>(dir.string(), "cell");
  } catch (const RunBusyError& e) {
    throw InputError("cell " + std::to_string(k) + " (" + job.plan.name + ") is being run by another process: " + e.what());
  }
  for (std::size_t i = 0; i < job.runs.size(); ++i) ensure_run_waiting(rt, job.runs[i], train_inputs(), g_.quiet, g_.out, job.ignores[i]);
  GridCell c;
  const bool cached = read_cell(k, c);
  if (!cached) {
    std::error_code ec;
    fs::remove(dir / "inputs", ec);  // the cell's own stale stamp, under its lock: evaluated again below
    if (job.kind == CellKind::Eval) {
      EvalOptions e = job.eval;
      e.out = dir.string();
      const EvalResult r = evaluate_run(rt, e);
      write_text_atomic((dir / "inputs").string(), c.inputs + "\n");
      c.mean = r.mean;
    } else {
      const std::uint64_t seed = job.plan.seed;
      const wiener::SpectralPrior prior = load_prior(RunFolder(job.prior_run).prior_path());
      const Eigen::MatrixXd srf = sensor_response(base_.cfg);
      const double sigma = base_.decoder_noise_sigma;
      const std::vector<RealStack> cubes = test_patches(base_.cfg, test_, g_.eval_synthetic_scenes, base_.design.seed);
      // The decoders of the other encoders come from the registry: wiener for the Fresnel lens's
      // PSF, cg for CASSI (any linear encoder), on the DO run's prior.
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
      EncoderEval ev;
      if (job.kind == CellKind::Fresnel) {
        Simulator sim(rt, base_.cfg, base_.precision);
        sim.set_heights(fresnel_lens_heights(base_.cfg, g_.fresnel_design_nm, job.plan.levels));
        sim.compute_psf();
        const RealStack psf = sim.psf_sensor();
        const DoeEncoder enc(wiener::psf_to_otf(psf, prior.rows, prior.cols), srf);
        ev = evaluate_encoder(enc, *decoder_of(DecoderSpec{}, psf, nullptr), cubes, sigma, seed + 77);
      } else {
        DecoderSpec cg;
        cg.kind = DecoderSpec::Kind::Named;
        cg.name = "cg";
        const std::size_t s = base_.cfg.sensor_size_px();
        auto enc = std::make_shared<CassiEncoder>(random_binary_mask(s, s, 0.5, seed + 5), base_.cfg.bands, g_.cassi_shift_px);
        ev = evaluate_encoder(*enc, *decoder_of(cg, RealStack(), enc), cubes, sigma, seed + 77);
      }
      c.mean.psnr = ev.psnr_db;
      c.mean.ssim = ev.ssim;
      c.mean.rmse = ev.rmse;
      c.mean.ergas = ev.ergas;
      c.mean.sam_rad = ev.sam_rad;
      write_cell_metrics(dir, c);
    }
  }
  if (progress)
    std::fprintf(stderr, "[sweep] cell #%zu of %zu %-22s PSNR %.2f dB%s (%.1f s)\n", k, jobs_.size(), job.plan.name.c_str(), c.mean.psnr,
                 cached ? ", finished earlier" : "",
                 std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
}

}  // namespace qdo
