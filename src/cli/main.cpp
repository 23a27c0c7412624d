// qdo command bodies: devices, config, psf, quantize, simulate, demo, design, eval, gradcheck (main() and the command table: commands.cpp).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <future>
#include <iostream>
#include <map>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "qdo/run_folder.hpp"
#include "qdo/config.hpp"
#include "qdo/cpu_reference.hpp"
#include "qdo/design_run.hpp"
#include "qdo/eval.hpp"
#include "qdo/gradcheck.hpp"
#include "qdo/doe.hpp"
#include "qdo/error.hpp"
#include "qdo/camera.hpp"
#include "qdo/io.hpp"
#include "qdo/network_decoder.hpp"
#include "qdo/optics.hpp"
#include "qdo/run.hpp"
#include "qdo/runtime.hpp"
#include "qdo/scenes.hpp"
#include "qdo/release.hpp"
#include "qdo/simulator.hpp"
#include "cli.hpp"

namespace fs = std::filesystem;
using namespace qdo;
using namespace qdo::cli;

namespace qdo::cli {
namespace {

// --save: extra outputs of psf and simulate, comma-separated; today only "native" (the native-grid PSF
// stack /psf in psf.h5, bands x N x N: the largest output, off by default).
bool save_native(const Args& a) {
  bool native = false;
  for (const auto& s : split_list(a.get("save"))) {
    if (s == "native") native = true;
    else reject("--save", s, "a comma-separated list of: native");
  }
  return native;
}

// The sensor PSF stack as the writers below take it (bands x S x S, row-major): a host stack of
// doubles, or the float32 device buffer mapped on the host (no read-back, no conversion).
struct SensorStack {
  std::size_t planes = 0, rows = 0, cols = 0;
  const std::vector<double>* f64 = nullptr;
  const float* f32 = nullptr;
  explicit SensorStack(const RealStack& s) : planes(s.planes), rows(s.rows), cols(s.cols), f64(&s.data) {}
  SensorStack(std::size_t p, std::size_t r, std::size_t c, const float* v) : planes(p), rows(r), cols(c), f32(v) {}
  // The central crop x crop of every plane (the montage's view), as doubles.
  RealStack central(std::size_t crop) const {
    const std::size_t h = std::min(crop, rows), w = std::min(crop, cols), y0 = (rows - h) / 2, x0 = (cols - w) / 2;
    RealStack out(planes, h, w);
    for (std::size_t b = 0; b < planes; ++b)
      for (std::size_t y = 0; y < h; ++y)
        for (std::size_t x = 0; x < w; ++x) {
          const std::size_t at = (b * rows + y0 + y) * cols + x0 + x;
          out(b, y, x) = f32 ? double(f32[at]) : (*f64)[at];
        }
    return out;
  }
};

// DIR/psf.h5: the sensor PSF stack psf_s (bands x S x S), the native-grid stack when `native`,
// wavelengths, sampling, heights. The PSF stacks are stored in the run's precision: float32 for
// an f32 run (exactly the device's values, half the bytes), float64 for f64. Reads the device
// (call it on the thread that owns the simulator).
void write_psf_h5(Simulator& sim, const SensorStack& psf_s, const Map2D& h, const std::string& dir, const std::string& tag,
                  bool native, bool compress) {
  const SystemConfig& cfg = sim.config();
  const bool f32 = sim.precision() == Precision::F32;
  std::vector<H5Dataset> ds;
  if (native) {
    const RealStack psf = sim.psf_native();
    ds.push_back({"/psf", {psf.planes, psf.rows, psf.cols}, psf.data, {{"pitch_m", cfg.pitch_m}}, {{"units", "fraction of band energy per sample"}}});
    ds.back().float32 = f32;
    ds.back().compress = compress;
  }
  ds.push_back({"/psf_sensor", {psf_s.planes, psf_s.rows, psf_s.cols}, {}, {{"pitch_m", cfg.sensor_pitch_m}},
                {{"units", "fraction of band energy per sensor pixel"}}});
  // Written from psf_s itself (the figures read it meanwhile).
  if (psf_s.f32) {
    ds.back().f32_view = psf_s.f32;
    ds.back().f32_count = psf_s.planes * psf_s.rows * psf_s.cols;
  } else {
    ds.back().view = psf_s.f64;
  }
  ds.back().float32 = f32 || psf_s.f32;
  ds.back().compress = compress;
  ds.push_back({"/wavelengths_nm", {cfg.bands}, cfg.wavelengths_nm(), {}, {{"units", "nm"}}});
  std::vector<double> alias, outside;
  for (const auto& b : sim.sampling().bands) {
    alias.push_back(b.aliased_energy_fraction);
    outside.push_back(b.energy_outside_window);
  }
  ds.push_back({"/aliased_energy_fraction", {cfg.bands}, alias, {}, {{"units", "fraction"}}});
  ds.push_back({"/energy_outside_window", {cfg.bands}, outside, {}, {{"units", "fraction"}}});
  ds.push_back({"/height_m", {h.rows, h.cols}, h.data, {{"pitch_m", cfg.pitch_m}}, {{"units", "m"}}});
  ds.back().compress = few_distinct_values(h.data);  // as in design files: quantized maps only
  h5_write(dir + "/psf.h5", ds, {{"config", config_to_json_text(cfg)}, {"design", tag}, {"precision", to_string(sim.precision())}});
}

// DIR/psf.png (montage of the sensor PSF stack) and DIR/design.png (height map). Host only.
// design.png is a preview at most 512 px per side (every k-th sample, k = ceil(N / 512): every
// 2nd at N = 1024); the heights themselves are in the HDF5 files. The two figures are drawn on two
// threads (libpng is reentrant).
void write_psf_figures(const SystemConfig& cfg, const SensorStack& psf_s, const Map2D& h, const std::string& dir) {
  auto montage = std::async(std::launch::async, [&] {
    // The montage shows the central 96 x 96 of each plane: only that part is converted.
    const RealStack crop = psf_s.central(96);
    write_montage_png(dir + "/psf.png", crop, cfg.wavelengths_nm(), 0.5, 0);  // 0: the whole (cropped) stack
  });
  const std::size_t k = (std::max(h.rows, h.cols) + 511) / 512;
  try {
    if (k <= 1) {
      write_map_png(dir + "/design.png", h);
    } else {
      Map2D small((h.rows + k - 1) / k, (h.cols + k - 1) / k);
      for (std::size_t y = 0; y < small.rows; ++y)
        for (std::size_t x = 0; x < small.cols; ++x) small(y, x) = h(y * k, x * k);
      write_map_png(dir + "/design.png", small);
    }
  } catch (...) {
    montage.wait();
    throw;
  }
  montage.get();
}

// Runs `figures` (PNG writers only: libpng is reentrant) on a second thread while `data` (every
// HDF5 writer, one at a time: the HDF5 library is not built thread-safe, and any device read)
// runs on this one; after both have stopped, rethrows the first failure (data's first).
void write_concurrently(const std::function<void()>& data, const std::function<void()>& figures) {
  auto fig = std::async(std::launch::async, figures);
  try {
    data();
  } catch (...) {
    fig.wait();
    throw;
  }
  fig.get();
}

}  // namespace

int cmd_devices(const Args&) {
  const auto devs = list_devices();
  for (const auto& d : devs)
    std::printf("%zu:%zu  %s / %s  [%s]  driver %s  %s  fp64 %s  %u CUs  %.1f GiB\n", d.platform_index, d.device_index,
                d.platform.c_str(), d.name.c_str(), d.type.c_str(), d.driver_version.c_str(), d.version.c_str(),
                d.fp64 ? "yes" : "no", d.compute_units, double(d.global_mem_bytes) / 1073741824.0);
  Runtime rt;
  std::printf("default: %zu:%zu %s\n", rt.info().platform_index, rt.info().device_index, rt.info().name.c_str());
  return 0;
}

int cmd_config(const Args& a) {
  std::cout << config_to_json_text(load_config(a)) << "\n";
  return 0;
}

int cmd_psf(const Args& a) {
  const auto t_cmd = std::chrono::steady_clock::now();
  (void)save_native(a);  // validated before any work
  const SystemConfig cfg = load_config(a);
  const Precision p = precision_from_string(a.get("precision"));
  // The device (context, kernels from the disk cache, FFT plans) starts on a second thread while
  // this one makes the design's heights and the output folder; an error in those inputs is
  // reported first (the device's own error only when the inputs are good). Nothing in the
  // device start touches HDF5, which is not thread-safe here.
  struct Started {
    std::unique_ptr<Runtime> rt;
    std::unique_ptr<Simulator> sim;
    double device_s = 0, setup_s = 0;
  };
  auto starting = std::async(std::launch::async, [&cfg, p, device = a.get("device")] {
    Started st;
    const auto t_dev = std::chrono::steady_clock::now();
    st.rt = std::make_unique<Runtime>(device);
    st.device_s = seconds_since(t_dev);
    const auto t0 = std::chrono::steady_clock::now();
    st.sim = std::make_unique<Simulator>(*st.rt, cfg, p);
    st.setup_s = seconds_since(t0);
    return st;
  });
  Map2D h;
  std::string dir;
  try {
    h = design_heights(cfg, a);
    dir = out_dir(a);
  } catch (...) {
    starting.wait();
    throw;
  }
  const double inputs_s = seconds_since(t_cmd);
  Started st = starting.get();
  Runtime& rt = *st.rt;
  Simulator& sim = *st.sim;
  sim.set_keep_field(false);  // no adjoint follows (Simulator::set_keep_field)
  sim.set_heights(h);
  const auto t1 = std::chrono::steady_clock::now();
  sim.compute_psf();
  rt.queue().finish();
  const double psf_seconds = seconds_since(t1);
  // float32: the files are written from the device buffer mapped on the host (on a CPU device the
  // buffer itself); float64: read back into a host stack.
  const auto t_read = std::chrono::steady_clock::now();
  const std::size_t s = sim.sensor_size(), count = cfg.bands * s * s;
  std::unique_ptr<MappedBuffer> mapped;
  RealStack host;
  std::unique_ptr<SensorStack> psf_s;
  if (p == Precision::F32) {
    mapped = std::make_unique<MappedBuffer>(rt.queue(), sim.psf_sensor_buffer(), CL_MAP_READ, count * sizeof(float));
    psf_s = std::make_unique<SensorStack>(cfg.bands, s, s, mapped->as<const float>());
  } else {
    host = sim.psf_sensor();
    psf_s = std::make_unique<SensorStack>(host);
  }
  const double read_s = seconds_since(t_read);
  const auto t_write = std::chrono::steady_clock::now();
  write_concurrently([&] { write_psf_h5(sim, *psf_s, h, dir, a.get("design"), save_native(a), a.has("compress")); },
                     [&] { write_psf_figures(cfg, *psf_s, h, dir); });
  const double write_s = seconds_since(t_write);
  std::printf("device: %s (%s)\nPSF stack: %zu bands x %zu x %zu (window %zu), %s, %.3f s (setup %.3f s: kernels %.3f s, FFT plans %.3f s)\n%s\nwrote %s/psf.h5, psf.png, design.png\n",
              rt.info().name.c_str(), rt.info().platform.c_str(), cfg.bands, cfg.n, cfg.n, sim.geometry().m,
              to_string(p).c_str(), psf_seconds, st.setup_s, rt.build_seconds(), rt.fft_bake_seconds(), sim.sampling().summary().c_str(),
              dir.c_str());
  std::printf("time: inputs %.3f s, device %.3f s, setup %.3f s (both on a second thread during the inputs), PSF %.3f s, "
              "read-back %.3f s, files %.3f s; command %.3f s\n",
              inputs_s, st.device_s, st.setup_s, psf_seconds, read_s, write_s, seconds_since(t_cmd));
  return 0;
}

int cmd_quantize(const Args& a) {
  const SystemConfig cfg = load_config(a);
  if (!a.has("levels")) reject("--levels", "(missing)", "the number of levels L >= 2");
  const std::string out = a.get("out");
  if (out.empty()) reject("--out", "(missing)", "an output .h5 file");
  const Map2D full = load_design(cfg, a.get("design"));
  const QuantSpec qs = load_quantizer(a);
  const Map2D hq = quantize_heights(full, cfg.h_max_m(), qs.q);
  Design d;
  d.height_m = hq;
  d.pitch_m = cfg.pitch_m;
  d.levels_m = qs.q.level_heights_m(cfg.h_max_m());
  if (fs::path(out).has_parent_path()) make_output_dir(fs::path(out).parent_path().string(), "--out");
  write_design(out, d, {{"source", a.get("design")}, {"mode", "DO (post-hoc uniform quantization)"},
                        {"levels", std::to_string(qs.q.levels)}, {"placement", to_string(qs.q.placement)}});
  std::printf("quantized to %d levels (%s): mean |H_q - H_f| = %.3f nm; levels (nm):", qs.q.levels,
              to_string(qs.q.placement).c_str(), quantization_deviation_m(hq, full) * 1e9);
  for (double l : d.levels_m) std::printf(" %.1f", l * 1e9);
  std::printf("\nwrote %s\n", out.c_str());
  return 0;
}


int cmd_simulate(const Args& a) {
  (void)save_native(a);  // validated before any work
  const std::string formation = a.get("formation");
  if (formation != "qdo" && formation != "release") reject("--formation", formation, "qdo or release");
  const bool release = formation == "release";
  const SystemConfig cfg = load_config(a);
  const Precision p = precision_from_string(a.get("precision"));
  const Map2D h = design_heights(cfg, a);
  const RealStack scene = scene_from_args(cfg, a);
  if (release) {  // the release's geometry needs a square scene and N >= S + 2; checked before any device work
    if (scene.rows != scene.cols)
      reject("--formation release", "a " + to_str(scene.rows) + " x " + to_str(scene.cols) + " scene", "a square S x S scene");
    (void)release_geometry(scene.rows, cfg.n);
    if (cfg.aperture_edge != ApertureEdge::Strict)
      std::fprintf(stderr, "qdo: note: --formation release with \"aperture_edge\": \"inclusive\"; the release's aperture is strict "
                           "(set it in the configuration for parity)\n");
  }
  const std::string dir = out_dir(a);
  Runtime rt(a.get("device"));
  Simulator sim(rt, cfg, p);
  sim.set_keep_field(false);  // no adjoint follows (Simulator::set_keep_field)
  sim.set_heights(h);
  const auto t0 = std::chrono::steady_clock::now();
  sim.compute_psf();
  const RealStack psf_s = sim.psf_sensor();
  const RealStack scene_rgb = ref::sensor_integrate(scene, sim.srf());  // the same camera without the DOE blur
  RealStack rgb;
  SensorClip clip;
  double secs = 0, outputs_s = 0;
  // The figures that need only the PSF, the design and the scene are drawn on a second thread
  // while the camera runs and the HDF5 files are written on this one.
  write_concurrently(
      [&] {
        // The camera through Camera's exact reorganisation with every skipping tolerance at 0: only
        // what contributes exactly nothing is skipped (bands the camera does not see or the scene
        // leaves dark, PSF rings holding no energy), so the error bound is 0 and the image is
        // Simulator::sensor_image's to the rounding of the precision, with fewer transforms.
        if (release) {
          // The release's pipeline on the DOE grid with the native PSF, then the sensor response and
          // qdo's noise model (the release adds its noise on the DOE grid, before the sensor).
          ReleaseImager imager(rt, p, cfg.bands, scene.rows, cfg.n);
          imager.set_psf(sim.psf_native());
          rgb = ref::sensor_integrate(imager.blur(scene), sim.srf());
          ref::add_noise(rgb, cfg.read_noise_sigma, cfg.full_well_photons, cfg.noise_seed, 0);
        } else {
          Camera camera(sim);
          rgb = camera.images({scene}, SkipOptions::split(0.0)).front();
        }
        secs = seconds_since(t0);
        clip = clip_to_full_scale(rgb, "sensor image");
        const auto t1 = std::chrono::steady_clock::now();
        write_rgb(dir + "/sensor.h5", rgb, {{"clipped_fraction", clip.fraction()}, {"max_before_clip", clip.max_before}});
        write_psf_h5(sim, SensorStack(psf_s), h, dir, a.get("design"), save_native(a), a.has("compress"));
        write_rgb_png(dir + "/sensor.png", rgb);
        outputs_s = seconds_since(t1);
      },
      [&] {
        write_rgb_png(dir + "/scene.png", scene_rgb);
        write_montage_png(dir + "/psf.png", psf_s, cfg.wavelengths_nm(), 0.5, std::min<std::size_t>(psf_s.rows, 96));
        write_map_png(dir + "/design.png", h);
      });
  std::printf("device: %s\nformation: %s\nscene %zu x %zu x %zu -> sensor 3 x %zu x %zu in %.3f s (PSF + convolution + sensor, %s); "
              "outputs written in %.3f s after it (figures of the PSF, design and scene drawn meanwhile)\n%s\n%s\n"
              "wrote %s/sensor.h5, sensor.png, scene.png, psf.h5, psf.png, design.png\n",
              rt.info().name.c_str(),
              release ? "release (bilinear up, mirror padding, shifted PSF, bilinear down)" : "qdo (camera operator, area-sampled PSF)",
              scene.planes, scene.rows, scene.cols, rgb.rows, rgb.cols, secs, to_string(p).c_str(),
              outputs_s, sim.sampling().summary().c_str(), clip_summary(clip).c_str(), dir.c_str());
  return 0;
}

namespace {
int print_gradcheck(const std::vector<GradcheckRow>& rows) {
  bool ok = true;
  std::printf("%-78s %12s %10s  %s\n", "parameter group", "max rel err", "tolerance", "");
  for (const auto& r : rows) {
    std::printf("%-78s %12.3e %10.1e  %s\n", r.group.c_str(), r.max_rel_error, r.tolerance, r.ok() ? "ok" : "FAIL");
    ok = ok && r.ok();
  }
  return ok ? 0 : 5;
}

}  // namespace

namespace {
// qdo design --mode do-finetune --from RUN: the options of the do run RUN with this run's levels
// and placement, frozen optics, finetune-steps network steps in one epoch at the do run's last
// network learning rate (or --lr-decoder), constant. Options that would be dropped are refused.
DesignRunOptions finetune_options(const Args& a) {
  static const std::set<std::string> allowed = {"mode",  "from", "levels", "placement", "finetune-steps", "lr-decoder", "checkpoint-every",
                                                "max-steps", "device", "out", "precision"};
  for (const auto& [k, v] : a.opt)
    if (!allowed.count(k))
      reject("--" + k, v, "not with --mode do-finetune (it takes the do run's options; allowed: --from --levels --placement "
                          "--finetune-steps --lr-decoder --checkpoint-every --max-steps --precision --device --out)");
  if (!a.has("from")) reject("--from", "(missing)", "the network do run folder to fine-tune (--mode do-finetune)");
  const std::string from = a.get("from");
  DesignRunOptions o = read_run_config(from, "--from", "a run folder written by qdo design (config.json missing)");
  if (o.design.mode != DesignMode::DO || !o.decoder.network())
    reject("--from", from, "a do run with a network decoder (it is a " + to_string(o.design.mode) + " run, decoder " + o.decoder.to_string() +
                               "); with the Wiener decoder the refit is qdo eval --decoder matched");
  const double last_lr = o.lr_decoder * std::pow(o.design.lr_decay_per_epoch, double(o.epochs - 1));
  o.finetune_from = from;
  if (a.has("levels")) o.design.quantizer.levels = parse_int("--levels", a.get("levels"), 2, 65536);
  if (a.has("placement")) o.design.quantizer.placement = placement_from_string(a.get("placement"));
  o.design.steps_per_epoch = std::size_t(parse_int("--finetune-steps", a.get("finetune-steps", "200"), 1, 100000000));
  o.epochs = 1;
  o.design.t0_epochs = 0;
  o.design.t1_epochs = 1;
  o.design.lr_decay_per_epoch = 1;
  o.lr_decoder = a.has("lr-decoder") ? parse_double("--lr-decoder", a.get("lr-decoder")) : last_lr;
  o.checkpoint_every = std::size_t(parse_int("--checkpoint-every", a.get("checkpoint-every", "10"), 1, 100000000));
  o.max_steps = a.has("max-steps") ? parse_int("--max-steps", a.get("max-steps"), 0, 2147483647) : -1;
  if (a.has("precision")) o.precision = precision_from_string(a.get("precision"));
  o.out = a.get("out");
  return o;
}
}  // namespace

int cmd_design(const Args& a) {
  const bool finetune = a.get("mode") == "do-finetune";
  if (finetune && a.has("resume")) {  // a do-finetune run resumes like any run: its stored options
    Args b = a;
    b.opt.erase("mode");
    b.opt.erase("from");
    return cmd_design(b);
  }
  DesignRunOptions o = finetune ? finetune_options(a) : design_options(a);
  const bool resume = a.has("resume");
  if (!resume) o.validate();
  else check_resume_options(a, o);
  Runtime rt(a.get("device"));
  if (a.has("check-gradients")) {
    std::printf("gradient check on this run's configuration (reduced to N <= 64):\n");
    if (const int rc = print_gradcheck(gradcheck(rt, o, o.design.seed)); rc != 0) return rc;
  }
  const auto t0 = std::chrono::steady_clock::now();
  const DesignRunResult r = run_design(rt, o, resume);
  std::printf("design: %ld steps, final loss %.6g, %.1f s; levels (nm):", r.steps_done, r.final_loss, seconds_since(t0));
  for (double l : r.levels_m) std::printf(" %.1f", l * 1e9);
  std::printf("\nwrote %s/ (config.json checkpoint.h5 log.csv design.h5 psf.h5 design.png psf.png loss.png)\n", o.out.c_str());
  return 0;
}

int cmd_eval(const Args& a) {
  EvalOptions e;
  e.run = a.positional;
  e.data = split_list(a.get("data"));
  e.levels = a.has("levels") ? parse_int("--levels", a.get("levels"), 2, 65536) : 0;
  e.placement = placement_from_string(a.get("placement"));
  e.decoder = decoder_fit_from_string(a.get("decoder"), "--decoder");
  if (a.has("decoder-kind")) e.decoder_kind = decoder_spec_from_string(a.get("decoder-kind"));
  e.noise_sigma = a.has("noise-sigma") ? parse_double("--noise-sigma", a.get("noise-sigma")) : -1;
  e.renders = std::size_t(parse_int("--renders", a.get("renders"), 0, 1000));
  e.synthetic_scenes = std::size_t(parse_int("--synthetic-scenes", a.get("synthetic-scenes"), 1, 100000));
  for (const auto& p : split_list(a.get("pixels"))) {
    const auto c = p.find(':');
    if (c == std::string::npos) reject("--pixels", p, "y:x pairs separated by commas");
    e.pixels.push_back({std::size_t(parse_int("--pixels", p.substr(0, c), 0, 1 << 20)),
                        std::size_t(parse_int("--pixels", p.substr(c + 1), 0, 1 << 20))});
  }
  e.precision = precision_from_string(a.get("precision"));
  e.out = a.get("out");
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

int cmd_gradcheck(const Args& a) {
  Args b = a;
  b.opt["out"] = "(unused)";
  b.opt["epochs"] = "10";
  DesignRunOptions o = design_options(b);
  o.validate();  // every option checked before the device is opened
  Runtime rt(a.get("device"));
  return print_gradcheck(gradcheck(rt, o, o.design.seed));
}

}  // namespace qdo::cli
