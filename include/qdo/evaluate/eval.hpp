// `qdo eval` as a library call: reconstruct test scenes through a run's design with a decoder of
// the registry (decoder_registry.hpp; by default the run's own: the Wiener decoder, or the run's
// network) and score them (the metrics of testset.hpp).
#pragma once
#include <cstddef>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "qdo/decode/decoder_spec.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/runtime/parse.hpp"
#include "qdo/runtime/runtime.hpp"

namespace qdo {

// Which design the decoder is built for: matched, the evaluated design; mismatch, the
// full-precision design H_f (the paper's DO: a decoder trained for H_f, measurements through the
// quantized DOE).
enum class DecoderFit { Matched, Mismatch };
// InputError "argument '<argument>' = S: matched or mismatch" for any other S.
DecoderFit decoder_fit_from_string(const std::string& s, const std::string& argument = "decoder");
std::string to_string(DecoderFit f);

struct EvalOptions {
  std::string run;                     // the run folder
  std::vector<std::string> data;       // test scenes; empty: held-out synthetic scenes
  std::string data_format = "auto";
  std::size_t synthetic_scenes = 6;
  int levels = 0;                      // > 0: re-quantize design_full.h5 uniformly to L levels (DO at L)
  bool full_precision = false;         // evaluate design_full.h5 itself (the unquantized reference)
  Placement placement = Placement::Inclusive;
  // Network runs: mismatch is the network as trained; matched only where the evaluated design
  // is the one it was trained with (see evaluate_run).
  DecoderFit decoder = DecoderFit::Matched;
  // The decoder that reconstructs, by its registry name (decoder_spec.hpp); empty: the run's own
  // (its config.json "decoder": wiener, or its trained network). A decoder trained with the
  // optics (resunet) must be the run's own.
  std::optional<DecoderSpec> decoder_kind;
  // A PSF stack file (`qdo psf`'s psf.h5: /psf_sensor, bands x S x S, with /wavelengths_nm; a
  // measured stack in the same layout) through which the test scenes are measured instead of the
  // evaluated design's simulated PSF; checked against the run's bands and sensor grid before any
  // work. Empty: the design's PSF. With it, `levels` and `full_precision` (which pick heights) are
  // refused; a matched Wiener decoder is built for the file's PSF, a mismatch one for H_f; a
  // network run needs mismatch (its network as trained, measured through the file's PSF).
  std::string psf_file;
  // A fitted as-built design .h5 (N x N at the run's pitch) whose simulated PSF measures the test
  // scenes in place of the run's design (a matched Wiener decoder is refit for it); the same rules
  // as psf_file, and not with it. A run fine-tuned for the camera as built (do-finetune with
  // finetune_psf or finetune_design) is evaluated through that PSF when neither is given, and its
  // network counts as matched to it. metrics.json's "psf" names the PSF used.
  std::string design_file;
  double noise_sigma = -1;             // measurement noise; < 0: the run's decoder sigma
  std::vector<std::pair<std::size_t, std::size_t>> pixels;  // spectral curves at (y, x); empty: centre
  std::size_t renders = 4;             // scenes rendered as PNG and stored as HDF5
  std::string out;
  Precision precision = Precision::F32;
};
struct EvalRow {
  std::string scene;
  double psnr = 0, psnr_hyper = 0, ssim = 0, rmse = 0, ergas = 0, sam_rad = 0;
};
struct EvalResult {
  std::vector<EvalRow> rows;
  EvalRow mean;
  double deviation_nm = 0;             // mean |H_eval - H_f| over the N x N map (Table 2)
  double deviation_rings_nm = 0;       // the same over the ring profile (ring_heights_of_map): the release's Table 2
};
// Writes OUT/metrics.csv, metrics.json, reconstructions.h5, render_K.png and spectra_K.png. A
// decoder trained with the optics cannot be refit in closed form: for it, matched needs the
// evaluated design to be the one it was trained with (the run's own design; H_f for full and for
// do at full precision; a do-finetune run's quantized DOE), else an InputError asks for mismatch.
EvalResult evaluate_run(Runtime& rt, const EvalOptions& e);
// qdo eval's options as a user typed them (TextOptions: the run is `run`; data, levels,
// placement, decoder, decoder-kind, psf, design, noise-sigma, renders, synthetic-scenes, pixels
// (y:x pairs), precision, out), each checked (InputError naming the option as typed); a fitted
// --design is read against the run's configuration. Nothing on the device, no folder claimed.
EvalOptions eval_options_from_options(const std::string& run, const TextOptions& a);
// The per-scene table (PSNR, PSNR-H, SSIM, RMSE, ERGAS, SAM), the mean row, the quantization
// deviation and the files written into `out`. Lines end with "\n".
std::string eval_report(const EvalResult& r, const std::string& out);

}  // namespace qdo
