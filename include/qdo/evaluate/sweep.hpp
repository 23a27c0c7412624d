// Sweeps across quantization levels: PSF metrics per level (`qdo sweep-psf`) and the experiment
// grid of the paper's comparisons (`qdo sweep`).
#pragma once
#include <cmath>
#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "qdo/decode/decoder_spec.hpp"
#include "qdo/design/design_run_options.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/evaluate/eval.hpp"
#include "qdo/runtime/runtime.hpp"

namespace qdo {

// ---------- PSF sweep ----------
struct PsfSweepVariant {
  std::string label;                   // e.g. "L4", "L4-adaptive"
  Quantizer quantizer;                 // applied (alpha = 1) to the full-precision design
};
struct PsfSweepOptions {
  SystemConfig cfg;
  Map2D design_full_m;                 // N x N full-precision heights
  std::vector<PsfSweepVariant> variants;
  std::size_t max_designs_per_pass = 0;  // 0: as many as fit the device's largest allocation
  Precision precision = Precision::F32;
  std::string out;                     // empty: no files
};
// Per variant and band, on the sensor-grid PSF (bands x S x S) against the full-precision one:
struct PsfSweepRow {
  std::string label;
  int levels = 0;                      // 0 for the full-precision reference
  double deviation_nm = 0;             // mean |H_q - H_f| (Table 2's measure)
  std::vector<double> rel_l2;          // ||P_q - P_f|| / ||P_f||
  std::vector<double> peak_ratio;      // max P_q / max P_f (Strehl-like)
  std::vector<double> ee80_um;         // radius around the axis holding 80 % of the band's energy
  std::vector<double> energy_outside;  // fraction of propagated energy outside the N x N window
};
// The full-precision reference comes first. All PSF stacks of a pass are computed in one batched
// pass on the device (designs x bands planes); the transfer functions, FFT plan and kernels are
// built once. Writes sweep.csv, sweep.json, psf.h5, psf_<label>.png and metric plots when out is set.
std::vector<PsfSweepRow> sweep_psf(Runtime& rt, const PsfSweepOptions& o);
// The learned-offset variant of a qdo+a run folder: its quantizer with the checkpoint's level
// offsets, labelled "L<levels>-adaptive". An InputError naming `argument` (value `run`) for a run of
// another mode; the run's configuration and checkpoint are read and checked (read_run_config,
// load_checkpoint).
PsfSweepVariant adaptive_psf_sweep_variant(const std::string& run, const std::string& argument = "adaptive_from");

// Radius (in units of the sensor pitch x pitch_m) around (S/2, S/2) within which `fraction` of
// the plane's energy lies; pixel centres sorted by radius, linearly interpolated.
double encircled_energy_radius(const RealStack& psf, std::size_t plane, double fraction, double pitch_m);

// ---------- Experiment grid ----------
struct GridOptions {
  DesignRunOptions base;               // system, optimiser and objective settings of every run
  std::vector<int> levels{2, 4, 8, 16, 32};
  std::vector<std::string> modes{"do", "do-refit", "qdo", "qdo+a"};
  // Decoders (decoder_spec.hpp): every mode is run with each. Empty: base.decoder alone. A network
  // decoder trains with the optics (objective network); its runs and cells are named with the
  // spec (e.g. qdo+a_L4_resunet-depth4-root16) and its modes labelled mode@spec in the tables.
  // do-refit is the Wiener decoder's closed-form refit (skipped for networks); do-finetune is the
  // network's counterpart (the do run's network trained on for finetune_steps steps with the DOE
  // quantized to L levels and frozen), and for the Wiener decoder the same cell as do-refit.
  std::vector<DecoderSpec> decoders;
  std::size_t finetune_steps = 100;
  // Training scenes are base.data (empty: synthetic scenes). Test scenes: test_data when given
  // (all of it); else the test part of base.data's scene-level 80/10/10 split by
  // base.design.seed; else held-out synthetic scenes.
  std::vector<std::string> test_data;
  std::size_t eval_synthetic_scenes = 4;
  // Encoders (Table 3): doe (the trained DOEs above), fresnel (a wrapped diffractive lens for
  // fresnel_design_nm, quantized to each level count, Wiener decoder), cassi (single-disperser
  // CASSI, random binary mask, cassi_shift_px per band, monochrome detector, prior-regularised
  // conjugate-gradient decoder). All share the DO run's scene prior and noise sigma.
  std::vector<std::string> encoders{"doe"};
  double fresnel_design_nm = 550;
  std::size_t cassi_shift_px = 1;
  // Seeds: every cell is trained and evaluated once per seed (design.seed). Empty:
  // base.design.seed alone, with the folder names of a sweep without a seed axis (runs/NAME,
  // cells/NAME); else runs/NAME_sSEED and cells/NAME_sSEED. The test scenes do not depend on it
  // (base.design.seed's split), so every seed is measured on the same scenes.
  std::vector<std::uint64_t> seeds;
  std::string out;
  bool quiet = true;
};
struct GridCell {
  std::string name, mode;              // mode: full, do, do-refit, do-finetune, qdo, qdo+a, ..., fresnel, cassi
                                       // (with @spec for a network decoder)
  DecoderSpec decoder;                 // the decoder's spec (wiener by default)
  int levels = 0;                      // 0: full precision; -1: not applicable (cassi)
  std::uint64_t seed = 0;              // the training seed of the cell's runs
  EvalRow mean;
  std::vector<EvalRow> scenes;         // per test scene (empty for fresnel and cassi cells)
  double deviation_nm = 0;             // mean |H_q - H_f| over the N x N map
  double deviation_rings_nm = NAN;     // over the ring profile (the release's Table 2); NaN where not recorded
  // "fnv1a64:<16 hex digits>": a hash of everything that determines the cell: its evaluation
  // options, the training run's options and output files (bytes), the test scenes' bytes.
  std::string inputs;
};

// The grid as a list of cells, each with the run folders it trains or reads (a DO run shared by
// several cells first). The order is the tables' order and never depends on what is finished:
// `qdo sweep --plan` prints it, `--cell K` and `--shard i/n` index it. No device work.
struct PlannedCell {
  std::size_t index = 0;
  std::string name;                    // cells/NAME (NAME_sSEED with a seed axis)
  std::string mode;                    // as GridCell::mode
  DecoderSpec decoder;
  int levels = 0;
  std::uint64_t seed = 0;
  std::vector<std::string> runs;       // run folders (absolute or as given under g.out), in training order
};
std::vector<PlannedCell> plan_grid(const GridOptions& g);

// Runs the cells `which` (indices into plan_grid(g)): trains the runs each needs, skipping finished
// ones and resuming interrupted ones, and evaluates the cell unless its metrics hold the same
// inputs. A run another process is training (its RUN/.lock) is waited for; a cell another process
// is running (cells/NAME/.lock) is refused with an InputError naming it. Writes no tables.
// `progress`: a line per cell on stderr.
void run_grid_cells(Runtime& rt, const GridOptions& g, const std::vector<std::size_t>& which, bool progress = true);

// The tables from finished cells alone (nothing is trained or evaluated): table1, table2,
// comparisons and the figures, as run_grid writes them. An InputError listing the cells that are
// not finished (or whose inputs changed since), and then no table is written.
std::vector<GridCell> collect_grid(const GridOptions& g);

// Runs every cell (training runs resume from their checkpoints and are skipped when finished;
// evaluated cells are skipped when their metrics exist), evaluates on the test split, and writes
// table1.md/.csv (PSNR, SSIM, RMSE, ERGAS per cell), table2.md/.csv (deviation in nm),
// comparisons.md/.csv with differences.png (the paper's comparisons as paired differences with
// 95 % intervals, sweep_stats.hpp) and psnr_vs_levels.png. DO is trained once per seed at full
// precision and quantized per level. With a seed axis (g.seeds), table1/table2 give mean ± sd over
// seeds and table1_seeds.csv every seed's row.
// Reuse is checked, not assumed: a training run folder (runs/NAME) whose config.json differs
// from the options of this call (other epochs, lr, system, ...) is an InputError naming each
// difference, and so is one whose training scenes' bytes changed (runs/NAME/sweep_inputs holds
// their hash); a cell is reused only when metrics.json holds the same `inputs` hash, else it is
// evaluated again. table1.csv and table2.csv carry each cell's `inputs` hash.
// Under an MPI world of N > 1 ranks (mpi.hpp): rank 0 hands out cells dynamically to every rank,
// itself included (a cell whose DO run another rank is training waits for it), and writes the
// tables once all are done; the other ranks return an empty list. A rank that fails ends the job;
// a rerun (with or without MPI) resumes where it stopped.
std::vector<GridCell> run_grid(Runtime& rt, const GridOptions& g);

// A finished cell's metrics.json as run_grid reuses it: the mean metrics (psnr_db, ssim, rmse,
// ergas, sam_rad; psnr_h_db optional) and deviation_nm, every one a finite number. Returns false
// for a torn, foreign or mistyped file (the cell is then evaluated again); never half-reads.
// With `scenes`, the file must also hold its per-scene rows ("per_scene", as qdo eval writes them),
// every value finite; a file without them is then not reused (the cell is evaluated again).
// With `deviation_rings_nm`, the file's deviation_rings_nm when it holds a finite one (else NaN).
bool read_cell_metrics(const std::string& metrics_json_path, EvalRow& mean, double& deviation_nm,
                       std::vector<EvalRow>* scenes = nullptr, double* deviation_rings_nm = nullptr);

}  // namespace qdo
