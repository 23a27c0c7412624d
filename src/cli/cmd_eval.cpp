// qdo eval RUN: a run's design and decoder on the test scenes (eval.hpp) -> OUT/metrics.csv,
// metrics.json, reconstructions.h5 and figures.
#include <cstdio>
#include <string>

#include "cli.hpp"
#include "options.hpp"
#include "qdo/decode/decoder_spec.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/evaluate/eval.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/runtime/util.hpp"

namespace qdo::cli {

static int cmd_eval(const Args& a) {
  EvalOptions e;
  e.run = a.positional;
  e.data = scene_paths(a, "data");
  e.levels = a.has("levels") ? parse_int("--levels", a.get("levels"), 2, 65536) : 0;
  e.placement = placement_from_string(a.get("placement"));
  e.decoder = decoder_fit_from_string(a.get("decoder"), "--decoder");
  if (a.has("decoder-kind")) e.decoder_kind = decoder_spec_from_string(a.get("decoder-kind"));
  e.psf_file = a.get("psf");
  if (a.has("psf") && a.has("levels")) reject("--levels", a.get("levels"), "no --levels with --psf (the PSF file is the measured camera)");
  e.design_file = a.get("design");
  if (a.has("design") && a.has("psf")) reject("--design", e.design_file, "either --psf or --design, not both (the camera as built is one of them)");
  if (a.has("design") && a.has("levels")) reject("--levels", a.get("levels"), "no --levels with --design (the fitted design is used as it is)");
  if (a.has("design")) (void)read_design_heights_for(read_run_config(e.run, "RUN").cfg, e.design_file, "--design");
  e.noise_sigma = a.has("noise-sigma") ? parse_double("--noise-sigma", a.get("noise-sigma"), 0, 10, "(units of full scale)") : -1;
  e.renders = std::size_t(parse_int("--renders", a.get("renders"), 0, 1000));
  e.synthetic_scenes = std::size_t(parse_int("--synthetic-scenes", a.get("synthetic-scenes"), 1, 100000));
  for (const auto& p : split_items(a.get("pixels"))) {
    const auto c = p.find(':');
    if (c == std::string::npos) reject("--pixels", p, "y:x pairs separated by commas");
    e.pixels.push_back({std::size_t(parse_int("--pixels", p.substr(0, c), 0, 1 << 20)),
                        std::size_t(parse_int("--pixels", p.substr(c + 1), 0, 1 << 20))});
  }
  e.precision = precision_from_string(a.get("precision"));
  e.out = a.get("out");
  claim_out(a, e.out);
  Runtime rt(a.get("device"));
  const EvalResult r = evaluate_run(rt, e);
  std::printf("%-28s %8s %8s %7s %8s %8s %8s\n", "scene", "PSNR", "PSNR-H", "SSIM", "RMSE", "ERGAS", "SAM");
  for (const auto& row : r.rows)
    std::printf("%-28s %8.2f %8.2f %7.4f %8.4f %8.2f %8.4f\n", row.scene.c_str(), row.psnr, row.psnr_hyper, row.ssim, row.rmse,
                row.ergas, row.sam_rad);
  std::printf("%-28s %8.2f %8.2f %7.4f %8.4f %8.2f %8.4f\n", "mean", r.mean.psnr, r.mean.psnr_hyper, r.mean.ssim, r.mean.rmse,
              r.mean.ergas, r.mean.sam_rad);
  std::printf("quantization deviation %.3f nm; wrote %s/ (metrics.csv metrics.json reconstructions.h5 render_*.png spectra_*.png)\n",
              r.deviation_nm, e.out.c_str());
  return 0;
}

namespace {
// qdo eval: its entry in the command table (help order 120).
const RegisterCommand registered_eval(120, [] {
  using namespace opts;
  CommandSpec c{"eval", "evaluate a run's design: metrics, reconstructions and figures", "RUN", "run folder written by qdo design",
                   {data("test scenes (default: synthetic scenes)"), data_root(),
                    opt("levels", "re-quantize the full-precision design to L levels, an integer in [2, 65536] (default: the run's)"),
                    placement(), opt("decoder", "decoder: matched (refit to the evaluated design) or mismatch (fit to the full-precision design)", "matched"),
                    opt("decoder-kind", "the decoder that reconstructs: wiener, cg[:tolerance=T,max_iterations=N] (conjugate-gradient MAP) or "
                                        "another registered one (default: the run's own, its Wiener decoder or its trained network)"),
                    opt("psf", "PSF stack file through which the scenes are measured in place of the design's PSF: psf.h5 as qdo psf "
                               "writes it (a measured stack in that layout), for the run's bands and sensor grid (checked); not with --levels"),
                    opt("design", "a fitted as-built design .h5 (N x N at the run's pitch) whose simulated PSF measures the scenes in place "
                                  "of the run's design (a matched Wiener decoder is refit for it); not with --psf or --levels"),
                    noise_sigma("sensor noise std, in units of full scale, in [0, 10] (default: the run's)", ""),
                    opt("pixels", "pixels whose spectra are plotted: y:x pairs, comma-separated"),
                    opt("renders", "number of reconstructions rendered as PNG, an integer in [0, 1000]", "4"), synthetic_scenes("6"),
                    precision(), device(), out_dir_opt()},
                   cmd_eval};
  return c;
});
}  // namespace

}  // namespace qdo::cli
