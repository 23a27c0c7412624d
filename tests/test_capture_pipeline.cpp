// The capture pipeline (include/qdo/physics/capture_pipeline.hpp), in suite `camera`: its sensor
// image is the camera operator's (noise and clip included, from a source and from a host stack),
// its raw frame and demosaic are RawStage's and DemosaicStage's run by hand, a stage added from
// outside (a toy constant gain) changes only what follows it, develop() runs the stages after the
// sensor on a measured raw frame as on its own, and its adjoint is the transpose of its Jacobian (dot-product test in float64 against the CPU references' Jacobian products).
#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include "common.hpp"
#include "qdo/physics/capture_pipeline.hpp"
#include "qdo/physics/cpu_reference.hpp"
#include "qdo/physics/demosaic.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/psf_source.hpp"
#include "qdo/physics/raw.hpp"
#include "qdo/physics/release.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/runtime/error.hpp"

using namespace qdo;
using namespace qdo::test;

namespace {

// Scenes of 20 x 18 pixels; tiny_config(32, 3): 3 bands, sensor PSF S = 16.
constexpr std::size_t kRows = 20, kCols = 18;

// A configuration with shot and read noise, a mosaic (or none), a black level and 12-bit codes.
SystemConfig capture_config(Cfa cfa) {
  SystemConfig c = tiny_config(32, 3);
  c.read_noise_sigma = 0.02;
  c.full_well_photons = 2000;
  c.noise_seed = 29;
  c.cfa = cfa;
  c.black_level_dn = 64;
  c.gain = 1.0;
  c.bit_depth = 12;
  c.validate();
  return c;
}

SystemConfig without_noise(SystemConfig c) {
  c.read_noise_sigma = 0;
  c.full_well_photons = 0;
  return c;
}

// Non-negative, each band summing to 1, every ring of the window holding energy (so the camera's
// crop rule keeps the whole window): bands x S x S.
RealStack random_psf(const SystemConfig& c, unsigned seed) {
  const std::size_t s = c.sensor_size_px();
  RealStack p = random_cube(c.bands, s, s, seed);
  for (std::size_t b = 0; b < c.bands; ++b) {
    double sum = 0;
    for (std::size_t i = 0; i < s * s; ++i) sum += p.plane(b)[i];
    for (std::size_t i = 0; i < s * s; ++i) p.plane(b)[i] /= sum;
  }
  return p;
}

// Mostly a point: 0.95 at the axis (S/2, S/2) plus 0.05 of random_psf, so bright and dark parts
// of a scene stay bright and dark on the sensor; every ring still holds energy. bands x S x S.
RealStack peaked_psf(const SystemConfig& c, unsigned seed) {
  const std::size_t s = c.sensor_size_px();
  RealStack p = random_psf(c, seed);
  for (double& v : p.data) v *= 0.05;
  for (std::size_t b = 0; b < c.bands; ++b) p(b, s / 2, s / 2) += 0.95;
  return p;
}

// Blocks of 4 x 4 pixels, all bands alike: dark (0), bright (1) or random in [0.2, 0.7]. bands x H x W.
RealStack block_scene(std::size_t bands, std::size_t h, std::size_t w, unsigned seed) {
  const RealStack mid = random_cube(bands, h, w, seed);
  RealStack s(bands, h, w);
  for (std::size_t b = 0; b < bands; ++b)
    for (std::size_t y = 0; y < h; ++y)
      for (std::size_t x = 0; x < w; ++x) {
        const std::size_t kind = (y / 4 + x / 4) % 3;
        s(b, y, x) = kind == 0 ? 0.0 : kind == 1 ? 1.0 : 0.2 + 0.5 * mid(b, y, x);
      }
  return s;
}

RealStack scaled(RealStack s, double k) {
  for (double& v : s.data) v *= k;
  return s;
}

double dot(const RealStack& a, const RealStack& b) {
  REQUIRE(a.size() == b.size());
  double s = 0;
  for (std::size_t i = 0; i < a.size(); ++i) s += a.data[i] * b.data[i];
  return s;
}
double abs_dot(const RealStack& a, const RealStack& b) {
  double s = 0;
  for (std::size_t i = 0; i < a.size(); ++i) s += std::fabs(a.data[i] * b.data[i]);
  return s;
}

// A toy sensor effect: a constant gain k on rgb alone ("display gain") or on clean and rgb alike
// ("exposure", before the noise and raw stages read them). Its adjoint scales the same gradients.
class GainStage final : public CaptureStage {
 public:
  GainStage(double k, bool on_clean) : k_(k), on_clean_(on_clean) {}
  std::string name() const override { return on_clean_ ? "exposure" : "display gain"; }
  void run(const CaptureInput&, CaptureFrame& f) override {
    if (on_clean_) scale(f.clean);
    scale(f.rgb);
  }
  void vjp(const CaptureFrame&, CaptureGradient& g) override {
    if (on_clean_) scale(g.clean);
    scale(g.rgb);
  }

 private:
  void scale(RealStack& s) const {
    for (double& v : s.data) v *= k_;
  }
  double k_;
  bool on_clean_;
};

// A toy stage after the demosaic: a constant gain k on the developed image (demosaiced).
class DevelopedGain final : public CaptureStage {
 public:
  explicit DevelopedGain(double k) : k_(k) {}
  std::string name() const override { return "developed gain"; }
  void run(const CaptureInput&, CaptureFrame& f) override {
    for (double& v : f.demosaiced.data) v *= k_;
  }

 private:
  double k_;
};

// The frame a raw pipeline must give for a clean image, by hand: host noise and clip on rgb,
// RawStage on clean, DemosaicStage on raw_to_linear of the raw frame.
struct ByHand {
  RealStack rgb, raw_dn, demosaiced;
  SensorClip clip;
  RawCounts counts;
};
ByHand raw_by_hand(const RealStack& clean, const SystemConfig& cfg, Precision p, DemosaicMethod method, bool noise) {
  ByHand h;
  h.rgb = clean;
  if (noise) ref::add_noise(h.rgb, cfg.read_noise_sigma, cfg.full_well_photons, cfg.noise_seed, 0);
  h.clip = clip_to_full_scale(h.rgb, "by hand");
  RawStage raw(runtime(), noise ? cfg : without_noise(cfg), p);
  const RawStage::Frames fr = raw.run(std::vector<RealStack>{clean});
  h.raw_dn = fr.raw.front();
  h.counts = fr.counts;
  DemosaicStage dm(runtime(), cfg.cfa, method, p);
  h.demosaiced = dm.run(std::vector<RealStack>{raw_to_linear(h.raw_dn, cfg)}).front();
  return h;
}

void check_frame_by_hand(const CaptureFrame& f, const ByHand& h) {
  CHECK(f.rgb.data == h.rgb.data);
  CHECK(f.clip.clipped == h.clip.clipped);
  CHECK(f.clip.max_before == h.clip.max_before);
  CHECK(f.raw_dn.planes == 1);
  CHECK(f.raw_dn.data == h.raw_dn.data);
  CHECK(f.raw_counts.saturated == h.counts.saturated);
  CHECK(f.raw_counts.floored == h.counts.floored);
  CHECK(f.raw_counts.total == h.counts.total);
  CHECK(f.demosaiced.data == h.demosaiced.data);
}

}  // namespace

TEST_SUITE("capture-pipeline") {
  TEST_CASE("capture pipeline: its sensor image is the camera operator's, noise and clip included (source and host stack)") {
    const SystemConfig cfg = capture_config(Cfa::None);
    const RealStack psf = random_psf(cfg, 11);
    const RealStack scene = random_cube(cfg.bands, kRows, kCols, 12);
    for (const Precision p : device_precisions(runtime())) {
      CAPTURE(to_string(p));
      const StackPsfSource src(runtime(), cfg, p, psf, "random PSF");
      const StackPsfSource quiet_src(runtime(), without_noise(cfg), p, psf, "random PSF");
      CapturePipeline pipe(runtime(), cfg, p);
      CHECK(pipe.stage_names() == std::vector<std::string>{"camera", "noise", "clip"});
      const CaptureFrame f = pipe.run(src, scene);
      // The camera alone, with the configuration's noise on the device, then clipped: the same
      // kernels on the same values, so equal to the last bit.
      Camera noisy(src);
      RealStack want = noisy.images({scene}, SkipOptions::split(0.0)).front();
      const SensorClip want_clip = clip_to_full_scale(want, "camera");
      CHECK(f.rgb.data == want.data);
      CHECK(f.clip.clipped == want_clip.clipped);
      CHECK(f.clip.max_before == want_clip.max_before);
      Camera quiet(quiet_src);
      CHECK(f.clean.data == quiet.images({scene}, SkipOptions::split(0.0)).front().data);
      CHECK(f.raw_dn.size() == 0);
      CHECK(f.demosaiced.size() == 0);
      REQUIRE(f.stage_seconds.size() == 3);
      CHECK(f.seconds_before("clip") == f.stage_seconds[0].second + f.stage_seconds[1].second);
      // The host stack gives the same frame, and again on a second run (its OTFs reused).
      for (int k = 0; k < 2; ++k) {
        const CaptureFrame h = pipe.run(psf, scene);
        CHECK(h.rgb.data == f.rgb.data);
        CHECK(h.clean.data == f.clean.data);
      }
      // Without noise: no noise stage, rgb is the clean image clipped.
      PipelineOptions o;
      o.noise = false;
      CapturePipeline silent(runtime(), cfg, p, o);
      CHECK(silent.stage_names() == std::vector<std::string>{"camera", "clip"});
      const CaptureFrame s = silent.run(src, scene);
      RealStack clipped = f.clean;
      (void)clip_to_full_scale(clipped, "clean");
      CHECK(s.clean.data == f.clean.data);
      CHECK(s.rgb.data == clipped.data);
    }
  }

  TEST_CASE("capture pipeline: the release formation is ReleaseImager and the sensor response, with host noise") {
    const SystemConfig cfg = capture_config(Cfa::None);
    const std::size_t s = cfg.sensor_size_px();
    const Precision p = Precision::F32;
    Simulator sim(runtime(), cfg, p);
    sim.set_heights(random_heights(cfg.n, cfg.h_max_m(), 13));
    sim.compute_psf();
    const RealStack scene = random_cube(cfg.bands, s, s, 14);
    PipelineOptions o;
    o.formation = ImageFormation::Release;
    CapturePipeline pipe(runtime(), cfg, p, o);
    CHECK(pipe.stage_names() == std::vector<std::string>{"release", "noise", "clip"});
    const CaptureFrame f = pipe.run(sim, scene);
    ReleaseImager imager(runtime(), p, cfg.bands, s, cfg.n);
    imager.set_psf(sim.psf_native());
    const RealStack clean = ref::sensor_integrate(imager.blur(scene), sensor_response(cfg));
    RealStack rgb = clean;
    ref::add_noise(rgb, cfg.read_noise_sigma, cfg.full_well_photons, cfg.noise_seed, 0);
    (void)clip_to_full_scale(rgb, "by hand");
    CHECK(f.clean.data == clean.data);
    CHECK(f.rgb.data == rgb.data);
    // No host stack (the formation needs the native PSF), no other scene size, no adjoint.
    CHECK(input_error_of([&] { pipe.run(sim.psf_sensor(), scene); }).find("native-grid PSF") != std::string::npos);
    CHECK(input_error_of([&] { pipe.run(sim, random_cube(cfg.bands, s - 2, s - 2, 15)); }).find("sensor size") != std::string::npos);
    CaptureGradient g;
    g.clean = random_cube(3, s, s, 16);
    CHECK_THROWS_WITH_AS(pipe.vjp(g), doctest::Contains("'release' has no adjoint"), Error);
  }

  TEST_CASE("capture pipeline: the raw frame and its demosaic are RawStage's and DemosaicStage's run by hand") {
    struct Case {
      Cfa cfa;
      DemosaicMethod method;
    };
    for (const Case cs : {Case{Cfa::RGGB, DemosaicMethod::MHC}, Case{Cfa::GRBG, DemosaicMethod::Bilinear}}) {
      CAPTURE(to_string(cs.cfa));
      const SystemConfig cfg = capture_config(cs.cfa);
      const RealStack psf = random_psf(cfg, 21);
      const RealStack scene = random_cube(cfg.bands, kRows, kCols, 22);
      for (const Precision p : device_precisions(runtime())) {
        CAPTURE(to_string(p));
        for (const bool noise : {true, false}) {
          CAPTURE(noise);
          PipelineOptions o;
          o.raw = true;
          o.demosaic = cs.method;
          o.noise = noise;
          CapturePipeline pipe(runtime(), cfg, p, o);
          CHECK(pipe.stage_names() == (noise ? std::vector<std::string>{"camera", "noise", "clip", "raw", "demosaic"}
                                             : std::vector<std::string>{"camera", "clip", "raw", "demosaic"}));
          const CaptureFrame f = pipe.run(psf, scene);
          Camera quiet(runtime(), without_noise(cfg), p);
          quiet.set_psf(psf);
          CHECK(f.clean.data == quiet.images({scene}, SkipOptions::split(0.0)).front().data);
          check_frame_by_hand(f, raw_by_hand(f.clean, cfg, p, cs.method, noise));
        }
      }
    }
  }

  TEST_CASE("capture pipeline: a sensor effect is one stage; a gain added after a stage changes only what follows it") {
    const SystemConfig cfg = capture_config(Cfa::RGGB);
    const RealStack psf = random_psf(cfg, 31);
    const RealStack scene = random_cube(cfg.bands, kRows, kCols, 32);
    const Precision p = Precision::F32;
    const double k = 0.5;  // a power of two: every product below is exact
    PipelineOptions o;
    o.raw = true;
    CapturePipeline base(runtime(), cfg, p, o);
    const CaptureFrame a = base.run(psf, scene);
    // After the last stage, on rgb: rgb scaled, nothing else moved.
    CapturePipeline display(runtime(), cfg, p, o);
    display.insert_after("demosaic", std::make_unique<GainStage>(k, false));
    CHECK(display.stage_names() == std::vector<std::string>{"camera", "noise", "clip", "raw", "demosaic", "display gain"});
    const CaptureFrame d = display.run(psf, scene);
    CHECK(d.rgb.data == scaled(a.rgb, k).data);
    CHECK(d.clip.clipped == a.clip.clipped);
    CHECK(d.clean.data == a.clean.data);
    CHECK(d.raw_dn.data == a.raw_dn.data);
    CHECK(d.demosaiced.data == a.demosaiced.data);
    // Right after the camera, on clean and rgb: the camera's image is scaled, and every later stage
    // sees the scaled image (noise, clip, raw and demosaic as by hand on it).
    CapturePipeline exposure(runtime(), cfg, p, o);
    exposure.insert_after("camera", std::make_unique<GainStage>(k, true));
    CHECK(exposure.stage_names() == std::vector<std::string>{"camera", "exposure", "noise", "clip", "raw", "demosaic"});
    const CaptureFrame e = exposure.run(psf, scene);
    CHECK(e.clean.data == scaled(a.clean, k).data);
    check_frame_by_hand(e, raw_by_hand(e.clean, cfg, p, o.demosaic, true));
    CHECK(e.raw_dn.data != a.raw_dn.data);
    // Names that are no stage, and no stage at all, are refused.
    CHECK(input_error_of([&] { exposure.insert_after("sensor", std::make_unique<GainStage>(k, false)); }).find("camera, exposure, noise") !=
          std::string::npos);
    CHECK_THROWS_AS(exposure.insert_after("camera", nullptr), InputError);
  }

  TEST_CASE("capture pipeline: develop() runs the stages after the sensor on a measured raw frame, as on the pipeline's own") {
    const SystemConfig cfg = capture_config(Cfa::RGGB);
    const RealStack psf = random_psf(cfg, 41);
    const RealStack scene = random_cube(cfg.bands, kRows, kCols, 42);
    for (const Precision p : device_precisions(runtime())) {
      CAPTURE(to_string(p));
      PipelineOptions o;
      o.raw = true;
      o.demosaic = DemosaicMethod::MHC;
      CapturePipeline pipe(runtime(), cfg, p, o);
      const CaptureFrame f = pipe.run(psf, scene);
      CHECK(f.raw_linear.data == raw_to_linear(f.raw_dn, cfg).data);
      // The simulated frame's raw_linear, developed: the run's own demosaic, bit for bit.
      const CaptureFrame d = pipe.develop(f.raw_linear);
      CHECK(d.demosaiced.data == f.demosaiced.data);
      CHECK(d.stage_seconds.size() == 1);
      CHECK(d.stage_seconds.front().first == "demosaic");
      CHECK(d.clean.size() == 0);
      // A measured frame (any values, negative ones below a dark included): DemosaicStage's result.
      RealStack measured = random_cube(1, kRows, kCols, 43);
      for (double& v : measured.data) v = 1.2 * v - 0.1;
      DemosaicStage dm(runtime(), cfg.cfa, DemosaicMethod::MHC, p);
      CHECK(pipe.develop(measured).demosaiced.data == dm.run(std::vector<RealStack>{measured}).front().data);
      // A stage inserted after "demosaic" acts on measured frames too; one before "raw" does not run.
      pipe.insert_after("demosaic", std::make_unique<DevelopedGain>(0.5));
      pipe.insert_after("camera", std::make_unique<GainStage>(0.5, true));
      const CaptureFrame g = pipe.develop(measured);
      CHECK(g.demosaiced.data == scaled(dm.run(std::vector<RealStack>{measured}).front(), 0.5).data);
      REQUIRE(g.stage_seconds.size() == 2);
      CHECK(g.stage_seconds.back().first == "developed gain");
    }
    // Refusals: no raw stages; a frame of the wrong planes, too small, or not finite; nothing is run.
    CapturePipeline plain(runtime(), cfg, Precision::F32, PipelineOptions{});
    CHECK(input_error_of([&] { plain.develop(RealStack(1, kRows, kCols, 0.1)); }).find("options.raw") != std::string::npos);
    PipelineOptions o;
    o.raw = true;
    CapturePipeline pipe(runtime(), cfg, Precision::F32, o);
    CHECK(input_error_of([&] { pipe.develop(RealStack(3, kRows, kCols, 0.1)); }).find("1 x H x W") != std::string::npos);
    CHECK(input_error_of([&] { pipe.develop(RealStack(1, 2, kCols, 0.1)); }).find("H, W >= 3") != std::string::npos);
    RealStack nan(1, kRows, kCols, 0.1);
    nan.data[5] = std::nan("");
    CHECK(input_error_of([&] { pipe.develop(nan); }).find("raw_linear[5]") != std::string::npos);
  }

  TEST_CASE("capture pipeline: vjp is the transpose of the Jacobian, <J x, y> = <x, J^T y> in float64 (camera, raw, demosaic)") {
    if (!skip_unless(runtime().has_fp64(), "the capture pipeline's dot-product test needs float64")) return;
    // bit_depth 0 (the rounding is straight-through, not a derivative), read noise only (part of
    // the point), a black level and a gain under which the bright blocks saturate (code > white
    // for v > 0.83) and the dark ones' negative noise floors (code < 0 for v < -0.044): the raw
    // stage's mask is exercised.
    SystemConfig cfg = capture_config(Cfa::RGGB);
    cfg.bit_depth = 0;
    cfg.black_level_dn = 0.05;
    cfg.gain = 1.2;
    cfg.read_noise_sigma = 0.05;
    cfg.full_well_photons = 0;
    cfg.validate();
    const Precision p = Precision::F64;
    const RealStack psf = peaked_psf(cfg, 41);
    const RealStack scene = block_scene(cfg.bands, kRows, kCols, 42);
    const Eigen::MatrixXd srf = sensor_response(cfg);
    const double span = cfg.gain * (cfg.white_level_dn() - cfg.black_level_dn);
    for (const bool with_exposure : {false, true}) {
      CAPTURE(with_exposure);
      const double k = with_exposure ? 0.75 : 1.0;
      PipelineOptions o;
      o.raw = true;
      o.demosaic = DemosaicMethod::MHC;
      CapturePipeline pipe(runtime(), cfg, p, o);
      if (with_exposure) pipe.insert_after("camera", std::make_unique<GainStage>(k, true));
      const CaptureFrame f = pipe.run(psf, scene);
      CHECK(f.raw_counts.saturated > 0);
      CHECK(f.raw_counts.floored > 0);
      // x = (d_psf, d_scene); J x by the CPU references: the camera is bilinear in (PSF, scene).
      const RealStack dp = uniform_stack(cfg.bands, psf.rows, psf.cols, 43);
      const RealStack ds = uniform_stack(cfg.bands, kRows, kCols, 44);
      RealStack blur = ref::convolve(scene, dp, cfg.convolution);
      const RealStack blur2 = ref::convolve(ds, psf, cfg.convolution);
      for (std::size_t i = 0; i < blur.size(); ++i) blur.data[i] += blur2.data[i];
      const RealStack j_clean = scaled(ref::sensor_integrate(blur, srf), k);
      const RealStack j_raw = ref::raw_jvp(f.clean, j_clean, cfg);
      const RealStack j_dm = ref::demosaic(scaled(j_raw, 1.0 / span), cfg.cfa, o.demosaic);
      // y on every differentiable output.
      CaptureGradient y;
      y.clean = uniform_stack(3, kRows, kCols, 45);
      y.raw_dn = uniform_stack(1, kRows, kCols, 46);
      y.demosaiced = uniform_stack(3, kRows, kCols, 47);
      const double lhs = dot(j_clean, y.clean) + dot(j_raw, y.raw_dn) + dot(j_dm, y.demosaiced);
      const double mag = abs_dot(j_clean, y.clean) + abs_dot(j_raw, y.raw_dn) + abs_dot(j_dm, y.demosaiced);
      const CaptureGradient g = pipe.vjp(y);
      REQUIRE(g.psf.size() == dp.size());
      REQUIRE(g.scene.size() == ds.size());
      const double rhs = dot(dp, g.psf) + dot(ds, g.scene);
      CAPTURE(lhs);
      CAPTURE(rhs);
      // The device's float64 FFT convolution against the reference's: a few hundred roundings
      // per element of relative size 2^-53, well inside 1e-10 of the sum of the terms' magnitudes.
      CHECK(std::fabs(lhs - rhs) <= 1e-10 * mag);
      // One vjp per run.
      CHECK(input_error_of([&] { pipe.vjp(y); }).find("without a preceding run()") != std::string::npos);
    }
  }

  TEST_CASE("capture pipeline: refusals name the argument, the value and what is allowed") {
    const SystemConfig none = capture_config(Cfa::None);
    const Precision p = Precision::F32;
    PipelineOptions raw;
    raw.raw = true;
    CHECK(input_error_of([&] { CapturePipeline(runtime(), none, p, raw); }).find("'cfa' = none") != std::string::npos);
    const SystemConfig cfg = capture_config(Cfa::RGGB);
    CapturePipeline pipe(runtime(), cfg, p, raw);
    const RealStack psf = random_psf(cfg, 51);
    CHECK(input_error_of([&] { pipe.run(psf, random_cube(cfg.bands + 1, kRows, kCols, 52)); }).find("'scene bands' = 4") != std::string::npos);
    CHECK(input_error_of([&] { pipe.run(psf, random_cube(cfg.bands, 2, 8, 53)); }).find("at least 3 x 3") != std::string::npos);
    RealStack bad = random_cube(cfg.bands, kRows, kCols, 54);
    bad.data[7] = std::nan("");
    CHECK(input_error_of([&] { pipe.run(psf, bad); }).find("'scene[7]'") != std::string::npos);
    CHECK(input_error_of([&] { pipe.run(random_cube(cfg.bands, 8, 8, 55), bad); }).find("'psf_sensor'") != std::string::npos);
    CHECK(input_error_of([&] { pipe.vjp(CaptureGradient{}); }).find("without a preceding run()") != std::string::npos);
    if (runtime().has_fp64()) {
      const StackPsfSource f64(runtime(), cfg, Precision::F64, psf, "random PSF");
      CHECK(input_error_of([&] { pipe.run(f64, random_cube(cfg.bands, kRows, kCols, 56)); }).find("PSF source precision") !=
            std::string::npos);
    }
    const CaptureFrame f = pipe.run(psf, random_cube(cfg.bands, kRows, kCols, 57));
    CaptureGradient g;
    g.rgb = random_cube(3, kRows, kCols, 58);  // the clip has no adjoint
    CHECK(input_error_of([&] { pipe.vjp(g); }).find("full-scale clip has no adjoint") != std::string::npos);
    g = CaptureGradient{};
    g.raw_dn = random_cube(1, kRows + 1, kCols, 59);
    CHECK(input_error_of([&] { pipe.vjp(g); }).find("'g.raw_dn' = 1 x 21 x 18") != std::string::npos);
    CapturePipeline plain(runtime(), cfg, p);
    (void)plain.run(psf, random_cube(cfg.bands, kRows, kCols, 60));
    g = CaptureGradient{};
    g.demosaiced = random_cube(3, kRows, kCols, 61);
    CHECK(input_error_of([&] { plain.vjp(g); }).find("wrote no such array") != std::string::npos);
    CHECK(f.raw_dn.size() == kRows * kCols);
  }
}  // TEST_SUITE
