// qdo simulate: the RGB sensor image of a scene through a design (--design) or a PSF stack file
// (--psf), with --raw also the raw capture and its demosaic; with --capture psf-sweep a simulated
// calibration sweep for `qdo calibrate`; with --depth or --field-grid a spatially varying image.
// The work is the library's (include/qdo/asbuilt/simulate.hpp: plan_simulate checks every option,
// run_simulate computes and writes); this file claims --out, opens the device and prints.
#include <cstdio>
#include <string>

#include "cli.hpp"
#include "qdo/asbuilt/simulate.hpp"
#include "qdo/runtime/runtime.hpp"

namespace qdo::cli {

static int cmd_simulate(const Args& a) {
  const SimulatePlan plan = plan_simulate(a);  // every option checked, the scene and PSF read
  for (const std::string& n : plan.notes) std::fprintf(stderr, "qdo: note: %s\n", n.c_str());
  const std::string dir = out_dir(a);
  Runtime rt(a.get("device"));
  const auto say = [](const std::string& line) { std::fprintf(stderr, "[simulate] %s\n", line.c_str()); };
  std::fputs(run_simulate(rt, plan, dir, say).c_str(), stdout);
  return 0;
}

// qdo simulate: its entry in the command table (help order 80).
const RegisterCommand registered_simulate(80, [] {
  using namespace opts;
  return CommandSpec{"simulate", "the RGB sensor image of a scene through a design: DIR/sensor.h5, sensor.png, scene.png, psf.*; with --raw also "
                   "the raw capture (raw.png, raw.h5); with --capture psf-sweep a simulated calibration sweep for qdo calibrate",
                   "", "",
                   {preset(), config(), design_spec(), psf_file(), levels_post(), placement(), scene(), key(), resample_bands(),
                    opt("formation",
                        "image formation: qdo (the configuration's convolution on the sensor grid, area-sampled PSF) or release "
                        "(the paper release's: bilinear up, mirror padding, PSF one 4 um sample off centre, bilinear down; "
                        "a square scene, N >= S + 2; pair it with \"aperture_edge\": \"strict\")",
                        "qdo"),
                    flag("raw", "also write the capture as the sensor as built records it (the configuration's cfa, black_level_dn, "
                                "gain, bit_depth 8 .. 16, noise): raw.png (16-bit, DN), raw.h5 (/raw, and /rgb_demosaiced), "
                                "raw_demosaiced.png; needs a mosaic and a bit depth"),
                    opt("demosaic", "demosaic of the --raw capture: bilinear or mhc (Malvar-He-Cutler 5 x 5)", "mhc"),
                    opt("capture", "what to capture: scene (the --scene image) or psf-sweep (a point source at every configured band "
                                   "through the sensor as built, and dark frames, for qdo calibrate: DIR/frames/psf_<nm>nm.png, "
                                   "darks/dark_<k>.png, psf.h5 the stack imaged, sweep.h5, frames.png)",
                        "scene"),
                    opt("frame-size", "psf-sweep: frame size F (F x F pixels), an integer in [S, 8192], S the sensor PSF size "
                                      "(default: S + 64)"),
                    opt("peak", "psf-sweep: peak exposure of each band's brightest colour, a fraction of full well in (0, 1]", "0.6"),
                    opt("darks", "psf-sweep: number of dark frames, an integer in [1, 1000]", "8"),
                    opt("centre", "psf-sweep: ROW,COL, the frame pixel of the optical axis, so that the S x S PSF window lies "
                                  "inside the frame (default: F/2,F/2)"),
                    opt("depth", "FILE[:KEY]: a depth map of the scene, H x W metres, for a depth-layered image: an HDF5 dataset "
                                 "(KEY, default /depth_m; values > 0, or inf for infinitely far) or a 16-bit PNG (codes times "
                                 "--depth-scale; code 0 = infinitely far), or builtin (the built-in chart's: patch rows at 4z, 8z, 16z, "
                                 "32z, z the DOE-sensor distance, the rest at infinity); every pixel takes the PSF of its nearest layer "
                                 "in diopters; writes also depth.png, depth.h5, psf_points.h5, varying.json; not with --psf, --raw, "
                                 "--field-grid"),
                    opt("depth-scale", "--depth FILE.png: metres per PNG code, a number > 0", "0.001"),
                    opt("depth-layers", "--depth: the layers D1,D2,... in metres > 0 or inf (default: the map's distinct values when "
                                        "at most 8, else 8 layers evenly spaced in diopters between its nearest and farthest); "
                                        "PSFs are computed at the layers some pixel uses only"),
                    opt("psf-placement", "--depth / --field-grid: source (each scene pixel emits through its own PSF) or output "
                                         "(each sensor pixel takes the image blurred with its own PSF: the release's per-depth rule)",
                        "source"),
                    opt("field-grid", "NX[xNY]: a field-dependent PSF from an NX x NY grid of field angles (integers in [1, 31]) up "
                                      "to the field edge, the image interpolated bilinearly between neighbouring points' recentred "
                                      "PSFs; points whose hats miss the scene are not computed; 1 = the on-axis PSF"),
                    opt("field-edge-deg", "--field-grid: the outermost field angle in degrees, in (0, the sampling limit] "
                                          "(default: min(atan(half the scene's extent on the sensor / z), atan(a quarter of the N x N window / z), the "
                                          "sampling limit); beyond the default, PSFs near the window's edge lose energy (the "
                                          "sampling line says how much)"),
                    opt("field-rank", "--field-grid: use the R leading components of the field PSFs (low-rank form), an integer in "
                                      "[1, computed points] (default: all points, no low-rank form)"),
                    precision(), device(), save_opt(), compress(), out_dir_opt()},
                   cmd_simulate};
});

}  // namespace qdo::cli
