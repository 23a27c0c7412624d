// qdo simulate as a library call (simulate.hpp): the plan from the options, the scene's capture
// through the pipeline (with raw, the raw and demosaic stages) and the psf-sweep capture; the
// varying image is simulate_varying.cpp's.
#include "qdo/asbuilt/simulate.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <string>

#include "qdo/asbuilt/raw_capture.hpp"
#include "qdo/data/figure.hpp"
#include "qdo/data/io.hpp"
#include "qdo/design/option_inputs.hpp"
#include "qdo/design/psf_outputs.hpp"
#include "qdo/physics/camera.hpp"
#include "qdo/physics/cpu_reference.hpp"
#include "qdo/physics/demosaic.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/psf_source.hpp"
#include "qdo/physics/release.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/strprintf.hpp"
#include "qdo/runtime/util.hpp"

namespace qdo {

namespace {

std::string percent(std::size_t n, std::size_t total) {
  return strprintf("%.4g %%", total ? 100.0 * double(n) / double(total) : 0.0);
}

// qdo simulate --capture psf-sweep: the sweep's options checked (psf_sweep_capture.hpp).
void plan_psf_sweep(const TextOptions& a, SimulatePlan& plan) {
  const SystemConfig& cfg = plan.cfg;
  plan.kind = SimulateKind::PsfSweep;
  for (const char* o : {"scene", "key", "resample-bands", "formation", "save", "compress", "raw", "demosaic"})
    if (a.has(o))
      reject(std::string("--") + o, a.get(o, "yes"), "not with --capture psf-sweep (the sweep images a point source)");
  check_raw_capture_config(cfg, "--capture psf-sweep");
  plan.psf = psf_input_from_options(cfg, a);
  const PsfInput& in = plan.psf;
  const std::size_t S = cfg.sensor_size_px();
  PsfSweepCaptureSpec& spec = plan.sweep;
  spec.frame_px = std::size_t(parse_int("--frame-size", a.get("frame-size", to_str(S + 64)), int(S), 8192));
  const std::size_t F = spec.frame_px;
  spec.peak = parse_double("--peak", a.get("peak", "0.6"), 0, 1, "of full well", true);
  spec.darks = std::size_t(parse_int("--darks", a.get("darks", "8"), 1, 1000));
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
}

// The sweep's frames and darks into dir, and its report.
std::string run_psf_sweep(Runtime& rt, const SimulatePlan& plan, const std::string& dir,
                          const std::function<void(const std::string&)>& say) {
  const SystemConfig& cfg = plan.cfg;
  const PsfSweepCaptureSpec& spec = plan.sweep;
  const std::size_t F = spec.frame_px;
  const std::vector<double> wl = cfg.wavelengths_nm();
  const PsfSweepCaptureResult r =
      capture_psf_sweep(rt, cfg, plan.precision, plan.psf, spec, dir, [&](std::size_t b, double secs) {
        if ((b + 1) % 8 == 0 || b + 1 == cfg.bands)
          if (say) say(strprintf("psf-sweep frame %zu of %zu (%g nm, %.1f s)", b + 1, cfg.bands, wl[b], secs));
      });
  const RawCounts& total = r.frames;
  return strprintf(
      "device: %s\nPSF: %s\nsweep: %zu frames of %zu x %zu (cfa %s, %zu-bit, black %g DN, gain %g), axis at (%ld, "
      "%ld), "
      "peak %g of full well, and %zu dark frames in %.3f s\n"
      "raw: %s of frame pixels saturated (%zu of %zu frames hold one: qdo calibrate refuses those), %s floored at 0; "
      "darks: %s floored\n"
      "wrote %s/frames/psf_<nm>nm.png, darks/dark_<k>.png, frames.png, psf.h5 (the PSF stack imaged), sweep.h5\n",
      rt.info().name.c_str(), r.psf_description.c_str(), cfg.bands, F, F, to_string(cfg.cfa).c_str(), cfg.bit_depth,
      cfg.black_level_dn, cfg.gain, r.geometry.centre_row, r.geometry.centre_col, spec.peak, spec.darks, r.seconds,
      percent(total.saturated, total.total).c_str(), r.frames_saturated, cfg.bands,
      percent(total.floored, total.total).c_str(), percent(r.darks.floored, r.darks.total).c_str(), dir.c_str());
}

}  // namespace

SimulatePlan plan_simulate(const TextOptions& a) {
  SimulatePlan plan;
  plan.save_native = save_native_from_option(a.get("save"));  // validated before any work
  plan.compress = a.has("compress");
  plan.design = a.get("design");
  const std::string formation = a.get("formation", "qdo");
  if (formation != "qdo" && formation != "release") reject("--formation", formation, "qdo or release");
  const bool release = formation == "release";
  plan.cfg = config_from_options(a);
  const SystemConfig& cfg = plan.cfg;
  plan.precision = precision_from_string(a.get("precision", "f32"));
  const std::string capture = a.get("capture", "scene");
  if (capture != "scene" && capture != "psf-sweep") reject("--capture", capture, "scene or psf-sweep");
  // A depth map or a field grid: the spatially varying image (simulate_varying.cpp).
  if (varying_requested(a)) {
    plan_varying_simulation(a, plan);
    return plan;
  }
  check_no_orphan_varying_options(a);
  if (capture == "psf-sweep") {
    plan_psf_sweep(a, plan);
    return plan;
  }
  for (const char* o : {"frame-size", "peak", "darks", "centre"})
    if (a.has(o)) reject(std::string("--") + o, a.get(o), "only with --capture psf-sweep");
  const bool raw = a.has("raw");
  if (raw) check_raw_capture_config(cfg, "--raw");
  if (!raw && a.has("demosaic"))
    reject("--demosaic", a.get("demosaic"), "only with --raw (it demosaics the raw capture)");
  const DemosaicMethod demosaic = demosaic_method_from_string(a.get("demosaic", "mhc"), "--demosaic");
  // The capture (capture_pipeline.hpp): the camera, noise, full-scale clip and, with --raw, the
  // raw and demosaic stages. With --raw the PSF source is made with the configuration without noise
  // (psf.h5 records it): the raw stage draws the sensor's noise itself (its own stream), and
  // sensor.h5 gets the configuration's noise added on the host (ref::add_noise, the camera's counters).
  PipelineOptions& capture_opt = plan.capture;
  capture_opt.formation = release ? ImageFormation::Release : ImageFormation::Qdo;
  capture_opt.raw = raw;
  capture_opt.demosaic = demosaic;
  plan.psf = psf_input_from_options(cfg, a);
  const PsfInput& in = plan.psf;
  if (in.from_file() && release)
    reject("--formation", formation,
           "qdo with --psf (the release formation needs the native-grid PSF, which a PSF file does not hold)");
  if (in.from_file() && plan.save_native)
    reject("--save", a.get("save"), "no native output with --psf (the file holds the sensor-grid stack only)");
  plan.scene = scene_from_options(cfg, a);
  const RealStack& scene = plan.scene;
  if (release) {  // the release's geometry needs a square scene and N >= S + 2; checked before any device work
    if (scene.rows != scene.cols)
      reject("--formation release", "a " + to_str(scene.rows) + " x " + to_str(scene.cols) + " scene",
             "a square S x S scene");
    // The release resizes the S x S scene onto the N x N DOE grid, a scale of N / S: the physical
    // one (sensor pitch over DOE pitch) only when S is the configuration's sensor size. Another S
    // would blur with a PSF scaled by the wrong factor, silently.
    if (scene.rows != cfg.sensor_size_px())
      reject("--formation release", "a " + to_str(scene.rows) + " x " + to_str(scene.cols) + " scene",
             "a scene of the configuration's sensor size, " + to_str(cfg.sensor_size_px()) + " x " +
                 to_str(cfg.sensor_size_px()) +
                 " (N x DOE pitch / sensor pitch): the release scales the scene by N / S = " +
                 to_str(double(cfg.n) / double(scene.rows)) + ", the physical scale is " +
                 to_str(cfg.sensor_pitch_m / cfg.pitch_m) + " (use --formation qdo for scenes of any size)");
    (void)release_geometry(scene.rows, cfg.n);
    if (cfg.aperture_edge != ApertureEdge::Strict)
      plan.notes.push_back(
          "--formation release with \"aperture_edge\": \"inclusive\"; the release's aperture is strict "
          "(set it in the configuration for parity)");
  }
  return plan;
}

std::string run_simulate(Runtime& rt, const SimulatePlan& plan, const std::string& dir,
                         const std::function<void(const std::string&)>& say) {
  if (plan.kind == SimulateKind::Varying) return run_varying_simulation(rt, plan, dir, say);
  if (plan.kind == SimulateKind::PsfSweep) return run_psf_sweep(rt, plan, dir, say);
  const SystemConfig& cfg = plan.cfg;
  const Precision p = plan.precision;
  const PsfInput& in = plan.psf;
  const RealStack& scene = plan.scene;
  const bool raw = plan.capture.raw, release = plan.capture.formation == ImageFormation::Release;
  const DemosaicMethod demosaic = plan.capture.demosaic;
  // With raw the PSF source is made with the configuration without noise (psf.h5 records it): the
  // raw stage draws the sensor's noise itself (its own stream), and sensor.h5 gets the
  // configuration's noise added on the host (ref::add_noise, the camera's counters).
  SystemConfig cam_cfg = cfg;
  if (raw) {
    cam_cfg.read_noise_sigma = 0;
    cam_cfg.full_well_photons = 0;
  }
  SpecPsfSource src = make_psf_source(rt, cam_cfg, p, in);
  CapturePipeline pipeline(rt, cfg, p, plan.capture);
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
        write_rgb(dir + "/sensor.h5", shot.rgb,
                  {{"clipped_fraction", shot.clip.fraction()}, {"max_before_clip", shot.clip.max_before}});
        if (src.sim)
          write_psf_h5(*src.sim, SensorStack(psf_s), in.heights, dir, plan.design, plan.save_native, plan.compress);
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
    raw_line = strprintf(
        "raw: cfa %s, %zu-bit, black level %g DN, gain %g: %s of pixels saturated, %s floored at 0; demosaic %s\n",
        to_string(cfg.cfa).c_str(), cfg.bit_depth, cfg.black_level_dn, cfg.gain,
        percent(counts.saturated, counts.total).c_str(), percent(counts.floored, counts.total).c_str(),
        to_string(demosaic).c_str());
  }
  return strprintf(
      "device: %s\nformation: %s\nPSF: %s\nscene %zu x %zu x %zu -> sensor 3 x %zu x %zu in %.3f s (PSF + convolution "
      "+ sensor, %s); "
      "outputs written in %.3f s after it (figures of the PSF, design and scene drawn meanwhile)\n%s\n%s\n"
      "%swrote %s/sensor.h5, sensor.png, scene.png, psf.h5, psf.png%s%s\n",
      rt.info().name.c_str(),
      release ? "release (bilinear up, mirror padding, shifted PSF, bilinear down)"
              : "qdo (camera operator, area-sampled PSF)",
      src.source().describe().c_str(), scene.planes, scene.rows, scene.cols, rgb.rows, rgb.cols, secs,
      to_string(p).c_str(), outputs_s,
      src.sim ? src.sim->sampling().summary().c_str() : "sampling: not known for a PSF read from a file",
      clip_summary(clip).c_str(), raw_line.c_str(), dir.c_str(), in.from_file() ? "" : ", design.png",
      raw ? ", raw.png, raw.h5, raw_demosaiced.png" : "");
}

}  // namespace qdo
