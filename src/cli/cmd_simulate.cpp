// qdo simulate and qdo image: the RGB sensor image of a scene through a PSF source, either a design
// simulated on the device (--design) or a PSF stack file written by `qdo psf` (--psf FILE; a
// measured or otherwise computed stack in the same layout), and the camera operator (camera.hpp).
#include <chrono>
#include <cstdio>
#include <memory>
#include <string>

#include "cli.hpp"
#include "psf_outputs.hpp"
#include "qdo/camera.hpp"
#include "qdo/cpu_reference.hpp"
#include "qdo/error.hpp"
#include "qdo/io.hpp"
#include "qdo/psf_source.hpp"
#include "qdo/release.hpp"
#include "qdo/scenes.hpp"
#include "qdo/simulator.hpp"

namespace qdo::cli {

namespace {

// The PSF of simulate and image, decided and checked before any device work: --psf FILE (the
// file's stack, checked against the configuration's bands and sensor grid) or --design (heights,
// simulated once the device is up). Exactly one of the two.
struct PsfInput {
  bool from_file = false;
  std::string path;
  RealStack file_stack;  // bands x S x S (from_file)
  Map2D h;               // N x N heights, metres (design)
};

PsfInput psf_input(const SystemConfig& cfg, const Args& a) {
  PsfInput in;
  if (a.has("psf")) {
    in.path = a.get("psf");
    if (a.has("design")) reject("--psf", in.path, "either --psf or --design, not both (the PSF comes from one of them)");
    if (a.has("levels")) reject("--levels", a.get("levels"), "no --levels with --psf (the PSF file is used as it is)");
    in.from_file = true;
    in.file_stack = read_psf_stack_for(cfg, in.path, "--psf");
    return in;
  }
  if (!a.has("design")) reject("--design", "(missing)", "lens:NM, flat, or a design .h5 file (or --psf FILE: a PSF stack)");
  in.h = design_heights(cfg, a);
  return in;
}

// The device source for a checked input: a Simulator with the design's heights (no adjoint
// follows: the field is not kept; compute() makes the PSF), or the file's stack on the device.
struct PsfSourceHolder {
  std::unique_ptr<Simulator> sim;
  std::unique_ptr<StackPsfSource> file;
  const PsfSource& source() const { return sim ? static_cast<const PsfSource&>(*sim) : *file; }
  // The design's PSF on the device (nothing to compute for a file).
  void compute() {
    if (sim) sim->compute_psf();
  }
};

PsfSourceHolder make_source(Runtime& rt, const SystemConfig& cfg, Precision p, const PsfInput& in) {
  PsfSourceHolder s;
  if (in.from_file) {
    s.file = std::make_unique<StackPsfSource>(rt, cfg, p, in.file_stack, "PSF file '" + in.path + "'");
  } else {
    s.sim = std::make_unique<Simulator>(rt, cfg, p);
    s.sim->set_keep_field(false);  // no adjoint follows (Simulator::set_keep_field)
    s.sim->set_heights(in.h);
  }
  return s;
}

}  // namespace

int cmd_simulate(const Args& a) {
  (void)save_native(a);  // validated before any work
  const std::string formation = a.get("formation");
  if (formation != "qdo" && formation != "release") reject("--formation", formation, "qdo or release");
  const bool release = formation == "release";
  const SystemConfig cfg = load_config(a);
  const Precision p = precision_from_string(a.get("precision"));
  const PsfInput in = psf_input(cfg, a);
  if (in.from_file && release)
    reject("--formation", formation, "qdo with --psf (the release formation needs the native-grid PSF, which a PSF file does not hold)");
  if (in.from_file && save_native(a)) reject("--save", a.get("save"), "no native output with --psf (the file holds the sensor-grid stack only)");
  const RealStack scene = scene_from_args(cfg, a);
  if (release) {  // the release's geometry needs a square scene and N >= S + 2; checked before any device work
    if (scene.rows != scene.cols)
      reject("--formation release", "a " + to_str(scene.rows) + " x " + to_str(scene.cols) + " scene", "a square S x S scene");
    // The release resizes the S x S scene onto the N x N DOE grid, a scale of N / S: the physical
    // one (sensor pitch over DOE pitch) only when S is the configuration's sensor size. Another S
    // would blur with a PSF scaled by the wrong factor, silently (issue 31, class 1).
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
  PsfSourceHolder src = make_source(rt, cfg, p, in);
  const auto t0 = std::chrono::steady_clock::now();
  src.compute();
  const RealStack psf_s = src.source().psf_sensor();
  const Eigen::MatrixXd srf = sensor_response(cfg);
  const RealStack scene_rgb = ref::sensor_integrate(scene, srf);  // the same camera without the DOE blur
  RealStack rgb;
  SensorClip clip;
  double secs = 0, outputs_s = 0;
  // The figures that need only the PSF, the design and the scene are drawn on a second thread
  // while the camera runs and the HDF5 files are written on this one.
  write_concurrently(
      [&] {
        // The camera through Camera's exact reorganisation with every skipping tolerance at 0: only
        // what contributes exactly nothing is skipped (bands the camera does not see or the scene
        // leaves dark, PSF rings holding no energy), so the error bound is 0 and the image is the
        // unskipped camera's to the rounding of the precision, with fewer transforms.
        if (release) {
          // The release's pipeline on the DOE grid with the native PSF, then the sensor response and
          // qdo's noise model (the release adds its noise on the DOE grid, before the sensor).
          ReleaseImager imager(rt, p, cfg.bands, scene.rows, cfg.n);
          imager.set_psf(src.sim->psf_native());
          rgb = ref::sensor_integrate(imager.blur(scene), srf);
          ref::add_noise(rgb, cfg.read_noise_sigma, cfg.full_well_photons, cfg.noise_seed, 0);
        } else {
          Camera camera(src.source());
          rgb = camera.images({scene}, SkipOptions::split(0.0)).front();
        }
        secs = seconds_since(t0);
        clip = clip_to_full_scale(rgb, "sensor image");
        const auto t1 = std::chrono::steady_clock::now();
        write_rgb(dir + "/sensor.h5", rgb, {{"clipped_fraction", clip.fraction()}, {"max_before_clip", clip.max_before}});
        if (src.sim)
          write_psf_h5(*src.sim, SensorStack(psf_s), in.h, dir, a.get("design"), save_native(a), a.has("compress"));
        else
          write_psf(dir + "/psf.h5", psf_s, cfg.wavelengths_nm(), cfg.sensor_pitch_m);
        write_rgb_png(dir + "/sensor.png", rgb);
        outputs_s = seconds_since(t1);
      },
      [&] {
        write_rgb_png(dir + "/scene.png", scene_rgb);
        write_montage_png(dir + "/psf.png", psf_s, cfg.wavelengths_nm(), 0.5, std::min<std::size_t>(psf_s.rows, 96));
        if (!in.from_file) write_map_png(dir + "/design.png", in.h);
      });
  std::printf("device: %s\nformation: %s\nPSF: %s\nscene %zu x %zu x %zu -> sensor 3 x %zu x %zu in %.3f s (PSF + convolution + sensor, %s); "
              "outputs written in %.3f s after it (figures of the PSF, design and scene drawn meanwhile)\n%s\n%s\n"
              "wrote %s/sensor.h5, sensor.png, scene.png, psf.h5, psf.png%s\n",
              rt.info().name.c_str(),
              release ? "release (bilinear up, mirror padding, shifted PSF, bilinear down)" : "qdo (camera operator, area-sampled PSF)",
              src.source().describe().c_str(), scene.planes, scene.rows, scene.cols, rgb.rows, rgb.cols, secs, to_string(p).c_str(),
              outputs_s, src.sim ? src.sim->sampling().summary().c_str() : "sampling: not known for a PSF read from a file",
              clip_summary(clip).c_str(), dir.c_str(), in.from_file ? "" : ", design.png");
  return 0;
}

// qdo image: the RGB sensor image of one scene with the skipping rules of Camera
// (include/qdo/camera.hpp) and a JSON report of what was skipped and the bound.
int cmd_image(const Args& a) {
  const SystemConfig cfg = load_config(a);
  const Precision p = precision_from_string(a.get("precision"));
  SkipOptions opt = SkipOptions::split(parse_double("--tolerance", a.get("tolerance"), 0, 1, "(units of full scale)"),
                                       tile_mode_from_string(a.get("tiles")),
                                       std::size_t(parse_int("--tile-px", a.get("tile-px"), 8, 4096)));
  opt.exact = a.has("exact");
  opt.validate();
  const PsfInput in = psf_input(cfg, a);
  const RealStack scene = scene_from_args(cfg, a);
  const std::string dir = out_dir(a);
  Runtime rt(a.get("device"));
  PsfSourceHolder src = make_source(rt, cfg, p, in);
  src.compute();
  Camera im(src.source());
  const auto t0 = std::chrono::steady_clock::now();
  RealStack rgb = im.images({scene}, opt).front();
  const double secs = seconds_since(t0);
  const SkipReport& r = im.last_report();
  const SensorClip clip = clip_to_full_scale(rgb, "sensor image");
  write_rgb_png(dir + "/sensor.png", rgb);
  write_text_atomic(dir + "/skip.json", r.to_json() + "\n");
  std::printf("PSF: %s\nscene %zu x %zu x %zu -> sensor 3 x %zu x %zu in %.3f s (%s)\n"
              "skipped: %zu/%zu bands, PSF crop radius %zu of %zu px, %zu/%zu tiles; FFT grid %zu x %zu\n"
              "error bound %.3g (bands %.3g, crop %.3g, tiles %.3g; tolerance %.3g) in units of full scale\n"
              "%s\n"
              "wrote %s/sensor.png, skip.json\n",
              src.source().describe().c_str(), scene.planes, scene.rows, scene.cols, rgb.rows, rgb.cols, secs,
              to_string(p).c_str(), r.bands_skipped.size(), r.bands, r.crop_radius_px, r.sensor_psf_px / 2, r.tiles_skipped,
              r.tiles_total, r.grid_rows, r.grid_cols, r.total_bound, r.band_bound, r.crop_bound, r.tile_bound, r.tolerance,
              clip_summary(clip).c_str(), dir.c_str());
  return 0;
}

}  // namespace qdo::cli
