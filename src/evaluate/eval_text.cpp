// qdo eval's options read from text and its report (eval.hpp).
#include "qdo/evaluate/eval.hpp"

#include "qdo/design/option_inputs.hpp"
#include "qdo/design/psf_spec.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/strprintf.hpp"
#include "qdo/runtime/util.hpp"

namespace qdo {

EvalOptions eval_options_from_options(const std::string& run, const TextOptions& a) {
  EvalOptions e;
  e.run = run;
  e.data = scene_paths_from_options(a, "data");
  e.levels = a.has("levels") ? parse_int("--levels", a.get("levels"), 2, 65536) : 0;
  e.placement = placement_from_string(a.get("placement", "inclusive"));
  e.decoder = decoder_fit_from_string(a.get("decoder", "matched"), "--decoder");
  if (a.has("decoder-kind")) e.decoder_kind = decoder_spec_from_string(a.get("decoder-kind"));
  e.psf_file = a.get("psf");
  if (a.has("psf") && a.has("levels"))
    reject("--levels", a.get("levels"), "no --levels with --psf (the PSF file is the measured camera)");
  e.design_file = a.get("design");
  (void)psf_spec_from_options(e.psf_file, e.design_file, "--psf", "--design",
                              "the camera as built is one of them");  // both: refused
  if (a.has("design") && a.has("levels"))
    reject("--levels", a.get("levels"), "no --levels with --design (the fitted design is used as it is)");
  if (a.has("design")) (void)read_design_heights_for(read_run_config(e.run, "RUN").cfg, e.design_file, "--design");
  e.noise_sigma =
      a.has("noise-sigma") ? parse_double("--noise-sigma", a.get("noise-sigma"), 0, 10, "(units of full scale)") : -1;
  e.renders = std::size_t(parse_int("--renders", a.get("renders", "4"), 0, 1000));
  e.synthetic_scenes = std::size_t(parse_int("--synthetic-scenes", a.get("synthetic-scenes", "6"), 1, 100000));
  for (const auto& p : split_items(a.get("pixels"))) {
    const auto c = p.find(':');
    if (c == std::string::npos) reject("--pixels", p, "y:x pairs separated by commas");
    e.pixels.push_back({std::size_t(parse_int("--pixels", p.substr(0, c), 0, 1 << 20)),
                        std::size_t(parse_int("--pixels", p.substr(c + 1), 0, 1 << 20))});
  }
  e.precision = precision_from_string(a.get("precision", "f32"));
  e.out = a.get("out");
  return e;
}

std::string eval_report(const EvalResult& r, const std::string& out) {
  std::string s =
      strprintf("%-28s %8s %8s %7s %8s %8s %8s\n", "scene", "PSNR", "PSNR-H", "SSIM", "RMSE", "ERGAS", "SAM");
  for (const auto& row : r.rows)
    s += strprintf("%-28s %8.2f %8.2f %7.4f %8.4f %8.2f %8.4f\n", row.scene.c_str(), row.psnr, row.psnr_hyper, row.ssim,
                   row.rmse, row.ergas, row.sam_rad);
  s += strprintf("%-28s %8.2f %8.2f %7.4f %8.4f %8.2f %8.4f\n", "mean", r.mean.psnr, r.mean.psnr_hyper, r.mean.ssim,
                 r.mean.rmse, r.mean.ergas, r.mean.sam_rad);
  s += strprintf(
      "quantization deviation %.3f nm; wrote %s/ (metrics.csv metrics.json reconstructions.h5 render_*.png "
      "spectra_*.png)\n",
      r.deviation_nm, out.c_str());
  return s;
}

}  // namespace qdo
