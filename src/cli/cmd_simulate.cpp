// qdo simulate: the RGB sensor image of a scene through a PSF source, either a design
// simulated on the device (--design) or a PSF stack file written by `qdo psf` (--psf FILE; a
// measured or otherwise computed stack in the same layout), through the capture pipeline
// (capture_pipeline.hpp: the camera operator, noise, the full-scale clip). With --raw, also the
// capture as the sensor as built writes it (raw.hpp: mosaic, black level, gain, bit depth, noise)
// and its demosaic (demosaic.hpp), the pipeline's raw stages; with --capture psf-sweep, instead of a
// scene, a simulated monochromator sweep of a point source and dark frames for `qdo calibrate`.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>

#include "cli.hpp"
#include "options.hpp"
#include "psf_outputs.hpp"
#include "simulate_varying.hpp"
#include "qdo/data/figure.hpp"
#include "qdo/physics/camera.hpp"
#include "qdo/physics/capture_pipeline.hpp"
#include "qdo/physics/cpu_reference.hpp"
#include "qdo/physics/demosaic.hpp"
#include "qdo/design/psf_outputs.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/psf_source.hpp"
#include "qdo/physics/raw_reference.hpp"
#include "qdo/physics/release.hpp"
#include "qdo/data/scenes.hpp"
#include "qdo/design/psf_spec.hpp"
#include "qdo/asbuilt/psf_sweep_capture.hpp"
#include "qdo/asbuilt/raw_capture.hpp"
#include "qdo/physics/simulator.hpp"

namespace qdo::cli {

namespace {

std::string percent(std::size_t n, std::size_t total) {
  char b[64];
  std::snprintf(b, sizeof b, "%.4g %%", total ? 100.0 * double(n) / double(total) : 0.0);
  return b;
}

// qdo simulate --capture psf-sweep: the simulated monochromator sweep of a point source and its dark
// frames for `qdo calibrate` (psf_sweep_capture.hpp).
int simulate_psf_sweep(const Args& a, const SystemConfig& cfg, Precision p) {
  for (const char* o : {"scene", "key", "resample-bands", "formation", "save", "compress", "raw", "demosaic"})
    if (a.has(o)) reject(std::string("--") + o, a.get(o, "yes"), "not with --capture psf-sweep (the sweep images a point source)");
  check_raw_capture_config(cfg, "--capture psf-sweep");
  const PsfInput in = psf_input(cfg, a);
  const std::size_t S = cfg.sensor_size_px();
  PsfSweepCaptureSpec spec;
  spec.frame_px = std::size_t(parse_int("--frame-size", a.get("frame-size", to_str(S + 64)), int(S), 8192));
  const std::size_t F = spec.frame_px;
  spec.peak = parse_double("--peak", a.get("peak"), 0, 1, "of full well", true);
  spec.darks = std::size_t(parse_int("--darks", a.get("darks"), 1, 1000));
  if (a.has("centre")) {
    const auto v = split_items(a.get("centre"));
    if (v.size() != 2) reject("--centre", a.get("centre"), "ROW,COL: the frame pixel of the optical axis");
    const long cy = parse_int("--centre", v[0], 0, int(F) - 1);
    const long cx = parse_int("--centre", v[1], 0, int(F) - 1);
    spec.centre = std::make_pair(cy, cx);
  }
  spec.design = in.from_file() ? in.spec.value : a.get("design");
  spec.provenance = "qdo simulate --capture psf-sweep";
  spec.centre_label = {"--centre", ""};
  spec.psf_label = {"--design", a.get("design", a.get("psf"))};
  spec.config_label = {"--capture psf-sweep", ""};
  (void)plan_psf_sweep_capture(cfg, spec);  // every refusal before the output folder and the device
  const std::string dir = out_dir(a);
  Runtime rt(a.get("device"));
  const std::vector<double> wl = cfg.wavelengths_nm();
  const PsfSweepCaptureResult r = capture_psf_sweep(rt, cfg, p, in, spec, dir, [&](std::size_t b, double secs) {
    if ((b + 1) % 8 == 0 || b + 1 == cfg.bands)
      std::fprintf(stderr, "[simulate] psf-sweep frame %zu of %zu (%g nm, %.1f s)\n", b + 1, cfg.bands, wl[b], secs);
  });
  const RawCounts& total = r.frames;
  std::printf("device: %s\nPSF: %s\nsweep: %zu frames of %zu x %zu (cfa %s, %zu-bit, black %g DN, gain %g), axis at (%ld, %ld), "
              "peak %g of full well, and %zu dark frames in %.3f s\n"
              "raw: %s of frame pixels saturated (%zu of %zu frames hold one: qdo calibrate refuses those), %s floored at 0; "
              "darks: %s floored\n"
              "wrote %s/frames/psf_<nm>nm.png, darks/dark_<k>.png, frames.png, psf.h5 (the PSF stack imaged), sweep.h5\n",
              rt.info().name.c_str(), r.psf_description.c_str(), cfg.bands, F, F, to_string(cfg.cfa).c_str(), cfg.bit_depth,
              cfg.black_level_dn, cfg.gain, r.geometry.centre_row, r.geometry.centre_col, spec.peak, spec.darks, r.seconds,
              percent(total.saturated, total.total).c_str(), r.frames_saturated, cfg.bands, percent(total.floored, total.total).c_str(),
              percent(r.darks.floored, r.darks.total).c_str(), dir.c_str());
  return 0;
}

}  // namespace

static int cmd_simulate(const Args& a) {
  (void)save_native(a);  // validated before any work
  const std::string formation = a.get("formation");
  if (formation != "qdo" && formation != "release") reject("--formation", formation, "qdo or release");
  const bool release = formation == "release";
  const SystemConfig cfg = load_config(a);
  const Precision p = precision_from_string(a.get("precision"));
  const std::string capture = a.get("capture");
  if (capture != "scene" && capture != "psf-sweep") reject("--capture", capture, "scene or psf-sweep");
  // A depth map or a field grid: the spatially varying image (simulate_varying.cpp).
  if (varying_requested(a)) return simulate_varying(a, cfg, p);
  check_no_orphan_varying_options(a);
  if (capture == "psf-sweep") return simulate_psf_sweep(a, cfg, p);
  for (const char* o : {"frame-size", "peak", "darks", "centre"})
    if (a.has(o)) reject(std::string("--") + o, a.get(o), "only with --capture psf-sweep");
  const bool raw = a.has("raw");
  if (raw) check_raw_capture_config(cfg, "--raw");
  if (!raw && a.has("demosaic")) reject("--demosaic", a.get("demosaic"), "only with --raw (it demosaics the raw capture)");
  const DemosaicMethod demosaic = demosaic_method_from_string(a.get("demosaic"), "--demosaic");
  // The capture (capture_pipeline.hpp): the camera, noise, full-scale clip and, with --raw, the
  // raw and demosaic stages. With --raw the PSF source is made with the configuration without noise
  // (psf.h5 records it): the raw stage draws the sensor's noise itself (its own stream), and
  // sensor.h5 gets the configuration's noise added on the host (ref::add_noise, the camera's counters).
  PipelineOptions capture_opt;
  capture_opt.formation = release ? ImageFormation::Release : ImageFormation::Qdo;
  capture_opt.raw = raw;
  capture_opt.demosaic = demosaic;
  SystemConfig cam_cfg = cfg;
  if (raw) {
    cam_cfg.read_noise_sigma = 0;
    cam_cfg.full_well_photons = 0;
  }
  const PsfInput in = psf_input(cfg, a);
  if (in.from_file() && release)
    reject("--formation", formation, "qdo with --psf (the release formation needs the native-grid PSF, which a PSF file does not hold)");
  if (in.from_file() && save_native(a)) reject("--save", a.get("save"), "no native output with --psf (the file holds the sensor-grid stack only)");
  const RealStack scene = scene_from_args(cfg, a);
  if (release) {  // the release's geometry needs a square scene and N >= S + 2; checked before any device work
    if (scene.rows != scene.cols)
      reject("--formation release", "a " + to_str(scene.rows) + " x " + to_str(scene.cols) + " scene", "a square S x S scene");
    // The release resizes the S x S scene onto the N x N DOE grid, a scale of N / S: the physical
    // one (sensor pitch over DOE pitch) only when S is the configuration's sensor size. Another S
    // would blur with a PSF scaled by the wrong factor, silently.
    if (scene.rows != cfg.sensor_size_px())
      reject("--formation release", "a " + to_str(scene.rows) + " x " + to_str(scene.cols) + " scene",
             "a scene of the configuration's sensor size, " + to_str(cfg.sensor_size_px()) + " x " + to_str(cfg.sensor_size_px()) +
                 " (N x DOE pitch / sensor pitch): the release scales the scene by N / S = " + to_str(double(cfg.n) / double(scene.rows)) +
                 ", the physical scale is " + to_str(cfg.sensor_pitch_m / cfg.pitch_m) +
                 " (use --formation qdo for scenes of any size)");
    (void)release_geometry(scene.rows, cfg.n);
    if (cfg.aperture_edge != ApertureEdge::Strict)
      std::fprintf(stderr, "qdo: note: --formation release with \"aperture_edge\": \"inclusive\"; the release's aperture is strict "
                           "(set it in the configuration for parity)\n");
  }
  const std::string dir = out_dir(a);
  Runtime rt(a.get("device"));
  SpecPsfSource src = make_psf_source(rt, cam_cfg, p, in);
  CapturePipeline pipeline(rt, cfg, p, capture_opt);
  const auto t0 = std::chrono::steady_clock::now();
  src.compute();
  const RealStack psf_s = src.source().psf_sensor();
  const Eigen::MatrixXd srf = sensor_response(cfg);
  const RealStack scene_rgb = ref::sensor_integrate(scene, srf);  // the same camera without the DOE blur
  CaptureFrame shot;
  double secs = 0, outputs_s = 0;
  // The figures that need only the PSF, the design and the scene are drawn on a second thread
  // while the capture runs and the HDF5 files are written on this one.
  write_concurrently(
      [&] {
        // qdo: the camera through Camera's exact reorganisation with every skipping tolerance at 0:
        // only what contributes exactly nothing is skipped (bands the camera does not see or the
        // scene leaves dark, PSF rings holding no energy), so the error bound is 0 and the image is
        // the unskipped camera's to the rounding of the precision, with fewer transforms. release:
        // the release's pipeline on the DOE grid with the native PSF, then the sensor response and
        // qdo's noise model (the release adds its noise on the DOE grid, before the sensor).
        const double psf_secs = seconds_since(t0);
        shot = pipeline.run(src.source(), scene);
        secs = psf_secs + shot.seconds_before("clip");  // PSF, convolution, sensor and noise
        const auto t1 = std::chrono::steady_clock::now();
        write_rgb(dir + "/sensor.h5", shot.rgb, {{"clipped_fraction", shot.clip.fraction()}, {"max_before_clip", shot.clip.max_before}});
        if (src.sim)
          write_psf_h5(*src.sim, SensorStack(psf_s), in.heights, dir, a.get("design"), save_native(a), a.has("compress"));
        else
          write_psf(dir + "/psf.h5", psf_s, cfg.wavelengths_nm(), cfg.sensor_pitch_m);
        write_rgb_png(dir + "/sensor.png", shot.rgb);
        outputs_s = seconds_since(t1);
      },
      [&] {
        write_rgb_png(dir + "/scene.png", scene_rgb);
        write_psf_figure(dir + "/psf.png", "PSF stack on the sensor", psf_s, cfg.wavelengths_nm(), cfg.sensor_pitch_m,
                         std::min<std::size_t>(psf_s.rows, 96));
        if (!in.from_file()) write_height_figure(dir + "/design.png", "DOE height map", in.heights, cfg.pitch_m);
      });
  const RealStack& rgb = shot.rgb;
  const SensorClip& clip = shot.clip;
  std::string raw_line;
  if (raw) {
    // The capture as the sensor as built writes it, and its demosaic (in linear units: black
    // removed, divided by gain (white - black)): raw_capture.hpp.
    const RawCounts& counts = shot.raw_counts;
    write_raw_capture_outputs(dir, cfg, shot, demosaic, "qdo simulate --raw");
    char b[400];
    std::snprintf(b, sizeof b,
                  "raw: cfa %s, %zu-bit, black level %g DN, gain %g: %s of pixels saturated, %s floored at 0; demosaic %s\n",
                  to_string(cfg.cfa).c_str(), cfg.bit_depth, cfg.black_level_dn, cfg.gain,
                  percent(counts.saturated, counts.total).c_str(), percent(counts.floored, counts.total).c_str(),
                  to_string(demosaic).c_str());
    raw_line = b;
  }
  std::printf("device: %s\nformation: %s\nPSF: %s\nscene %zu x %zu x %zu -> sensor 3 x %zu x %zu in %.3f s (PSF + convolution + sensor, %s); "
              "outputs written in %.3f s after it (figures of the PSF, design and scene drawn meanwhile)\n%s\n%s\n"
              "%swrote %s/sensor.h5, sensor.png, scene.png, psf.h5, psf.png%s%s\n",
              rt.info().name.c_str(),
              release ? "release (bilinear up, mirror padding, shifted PSF, bilinear down)" : "qdo (camera operator, area-sampled PSF)",
              src.source().describe().c_str(), scene.planes, scene.rows, scene.cols, rgb.rows, rgb.cols, secs, to_string(p).c_str(),
              outputs_s, src.sim ? src.sim->sampling().summary().c_str() : "sampling: not known for a PSF read from a file",
              clip_summary(clip).c_str(), raw_line.c_str(), dir.c_str(), in.from_file() ? "" : ", design.png",
              raw ? ", raw.png, raw.h5, raw_demosaiced.png" : "");
  return 0;
}

namespace {
// qdo simulate: its entry in the command table (help order 80).
const RegisterCommand registered_simulate(80, [] {
  using namespace opts;
  CommandSpec c{"simulate", "the RGB sensor image of a scene through a design: DIR/sensor.h5, sensor.png, scene.png, psf.*; with --raw also "
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
  return c;
});
}  // namespace

}  // namespace qdo::cli
