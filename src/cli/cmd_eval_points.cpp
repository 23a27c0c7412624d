// qdo eval-points RUN: a design's quality against object distance and field angle, its depth of
// field and its valid field of view (eval_points.hpp) -> OUT/points.json, points.csv and figures.
// The options are read and the report written by the library (eval_points_options_from_options,
// eval_points_report); this file claims --out, opens the device and prints.
#include <cstdio>

#include "cli.hpp"
#include "qdo/decode/decoder_spec.hpp"
#include "qdo/evaluate/eval_points.hpp"
#include "qdo/runtime/runtime.hpp"

namespace qdo::cli {

static int cmd_eval_points(const Args& a) {
  const EvalPointsOptions o = eval_points_options_from_options(a.positional, a);  // every value checked
  claim_out(a, o.out);
  Runtime rt(a.get("device"));
  std::fputs(eval_points_report(o, evaluate_points(rt, o)).c_str(), stdout);
  return 0;
}

// qdo eval-points: its entry in the command table (help order 130).
const RegisterCommand registered_eval_points(130, [] {
  using namespace opts;
  return CommandSpec{"eval-points", "a run's design against object distance and field angle: quality, depth of field and valid field of view",
                   "RUN", "run folder written by qdo design",
                   {opt("design", "the design evaluated in place of RUN/design.h5: a design .h5 (N x N at the run's pitch), lens:NM or flat"),
                    opt("distances", "object distances in metres, comma-separated, each > 0 or inf (a point at infinity); the "
                                     "nominal distance (--nominal) is always added", "0.3,0.5,0.7,1,1.5,2,3,5,10,inf"),
                    opt("nominal", "the distance the camera is focused at, metres > 0 or inf: the mismatch decoder is built for "
                                   "the PSF there and the field angles are evaluated there (default: the run's one object point, "
                                   "else its scene_distance_m)"),
                    opt("angles", "field angles along x in degrees, comma-separated, each in [0, the sampling limit at the nominal "
                                  "distance] (default: 0 to the field edge, min(atan(half the sensor window / z), that limit), in "
                                  "--angle-steps steps); 0 is always added"),
                    opt("angle-steps", "steps of the default angle grid, an integer in [1, 1000]", "8"),
                    data("test scenes (default: synthetic held-out scenes, as qdo eval)"), data_root(), synthetic_scenes("6"),
                    opt("fov-tolerance", "largest model error ||I_theta - I_0|| / ||I_0|| (field-dependent image against the "
                                         "shift-invariant model's) inside the valid field of view, a number in (0, 10]; 0.05: a 5 % "
                                         "relative image error, about 26 dB of model PSNR", "0.05"),
                    opt("dof-margin-db", "depth of field: the distances where the mismatch PSNR stays within this many dB of the "
                                         "nominal's, a number in (0, 100]", "1"),
                    opt("noise-sigma", "sensor noise std, in units of full scale, in [0, 10] (default: the run's)"),
                    opt("decoder-kind", "decoder built from the PSF: wiener (default) or cg[:tolerance=T,max_iterations=N]", DecoderSpec{}.to_string()),
                    precision(), device(), out_dir_opt()},
                   cmd_eval_points};
});

}  // namespace qdo::cli
