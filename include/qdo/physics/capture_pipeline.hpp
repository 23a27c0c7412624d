// The capture chain of a simulated camera as one object: scene -> optics -> noise -> full-scale
// clip -> raw (mosaic, noise, black level, gain, clipping, bit depth) -> demosaic. Each step is a
// CaptureStage run in order over one CaptureFrame; a new sensor effect is one CaptureStage class
// and one line where CapturePipeline's constructor lists its stages (or insert_after() from
// outside). The chain `qdo simulate` writes (sensor.h5, raw.h5) is this pipeline's.
//
// The stages, by name, in order:
//   "camera"   (formation Qdo) the camera operator (camera.hpp) without noise, every skipping
//              tolerance as PipelineOptions::skip (default 0: only what contributes exactly nothing
//              is skipped): clean = rgb = the noiseless 3 x H x W sensor image;
//   "release"  (formation Release, instead of "camera") the release's image formation
//              (release.hpp, the native-grid PSF of a Simulator source) and the sensor response
//              (ref::sensor_integrate): clean = rgb;
//   "noise"    (options.noise) the configuration's shot and read noise added to rgb, scene 0's
//              counters: on the device in the working precision with the camera's noise kernel
//              (sensor.cl, the values Camera::images returns with that noise) for formation Qdo
//              without raw, else on the host in double (ref::add_noise). The two draw the same
//              counters and agree to the rounding of the precision;
//   "clip"     rgb clipped at full scale 1 (clip_to_full_scale; a NaN or Inf is a NumericalError);
//   "raw"      (options.raw) clean through RawStage (raw.hpp): raw_dn, raw_counts, and raw_dn in
//              linear units (raw_to_linear): raw_linear; the raw stage draws the sensor's noise
//              itself (its own counters) when options.noise;
//   "demosaic" (options.raw) raw_linear through DemosaicStage (demosaic.hpp): demosaiced.
//
// A measured raw frame is developed by the same stages: develop() runs the stages after "raw" on
// it (qdo reconstruct develops its captures so), so a stage added after "raw" acts on simulated
// and measured frames alike.
//
// Adjoints (vjp): "camera" (Camera::vjp: to the sensor PSF stack and the scene), "noise" (additive
// and independent of the inputs: the identity), "raw" (RawStage::adjoint: the clip mask at the
// forward's point, rounding straight-through), "demosaic" (DemosaicStage::adjoint times the slope
// of raw_to_linear). "clip" has none: a gradient on rgb is refused (give it on clean, the image
// before noise and clip). "release" has none: vjp refuses a Release pipeline.
#pragma once
#include <cstddef>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/physics/camera.hpp"
#include "qdo/physics/demosaic_reference.hpp"
#include "qdo/physics/psf_source.hpp"
#include "qdo/physics/raw_reference.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

// How the optics form the sensor image: qdo's camera operator (area-sampled sensor PSF, linear or
// circular convolution) or the paper release's formation (release.hpp; square S x S scenes of the
// configuration's sensor size, a Simulator source).
enum class ImageFormation { Qdo, Release };
std::string to_string(ImageFormation f);  // "qdo", "release"

struct PipelineOptions {
  ImageFormation formation = ImageFormation::Qdo;
  // The configuration's shot and read noise, in the noise stage and in the raw stage; false: no
  // noise anywhere (the noise stage is left out, the raw stage runs without noise).
  bool noise = true;
  // The raw and demosaic stages; the configuration's "cfa" must then be a mosaic.
  bool raw = false;
  DemosaicMethod demosaic = DemosaicMethod::Bilinear;
  // The camera stage's skipping (formation Qdo): tolerances 0, untiled, as `qdo simulate`.
  SkipOptions skip = SkipOptions::split(0.0);
};

// What one run() is given: the scene and the PSF, either a source followed on the device or a host
// stack. The pointers are not owned; a source must outlive the vjp() that follows the run().
struct CaptureInput {
  const RealStack* scene = nullptr;       // bands x H x W, finite, row-major
  const PsfSource* source = nullptr;      // the sensor-grid stack (psf_source.hpp), or
  const RealStack* psf_sensor = nullptr;  // a host stack: bands x S x S, axis at (S/2, S/2)
};

// What the stages leave, all row-major 3-D stacks of the scene's H x W. Empty where no stage
// writes it (raw_dn and demosaiced without raw).
struct CaptureFrame {
  RealStack clean;       // 3 x H x W: the sensor image before noise and clip (linear, 1 = full well)
  RealStack rgb;         // 3 x H x W: with noise, clipped at full scale (what sensor.h5 holds)
  SensorClip clip;       // what the clip stage clipped of rgb, and its largest value before
  RealStack raw_dn;      // raw_channels(cfa) x H x W (1 with a mosaic): code values, DN
  RawCounts raw_counts;  // the raw stage's saturated and floored elements
  RealStack raw_linear;  // raw_channels(cfa) x H x W: raw_dn in linear units (1 = full well), the demosaic's input
  RealStack demosaiced;  // 3 x H x W: the demosaic of raw_dn in linear units (1 = full well)
  // Wall-clock seconds of each stage that ran, in order: (name, seconds).
  std::vector<std::pair<std::string, double>> stage_seconds;
  // The seconds of the stages that ran before the one named `stage` (all of them when it did not run).
  double seconds_before(const std::string& stage) const;
};

// Gradients of a loss on a frame's arrays (in: an empty stack is a zero gradient, else the frame
// array's shape) and on the inputs (out). The stages' vjp() run in reverse order; each reads the
// gradient on what it wrote and adds into the gradient on what it read.
struct CaptureGradient {
  RealStack clean, rgb, raw_dn, demosaiced;  // in: dL/d(frame array), shapes as in CaptureFrame
  RealStack psf;                             // out: dL/d(sensor PSF stack), bands x S x S
  RealStack scene;                           // out: dL/d(scene), bands x H x W
};

// One step of the chain. run() reads the input and what earlier stages left in the frame and writes
// its own fields; vjp() (after the pipeline's run, with that run's final frame) maps the gradient on
// what it wrote to the gradient on what it read. The default vjp() throws Error: no adjoint.
class CaptureStage {
 public:
  virtual ~CaptureStage() = default;
  virtual std::string name() const = 0;
  virtual void run(const CaptureInput& in, CaptureFrame& frame) = 0;
  virtual void vjp(const CaptureFrame& frame, CaptureGradient& g);
};

// One scene at a time (noise counters of scene 0 of a batch, as `qdo simulate`), stages as listed
// above. The configuration is validated and the precision checked against the device on
// construction; the raw stages need a mosaic (cfg.cfa not "none").
class CapturePipeline {
 public:
  CapturePipeline(Runtime& rt, const SystemConfig& cfg, Precision p, const PipelineOptions& opt = {});
  CapturePipeline(const CapturePipeline&) = delete;
  CapturePipeline& operator=(const CapturePipeline&) = delete;

  // The frame of `scene` (cfg.bands x H x W, finite; H, W >= 3 with raw) through the PSF of
  // `source` (its precision the pipeline's; its bands, wavelengths and sensor size the
  // configuration's; one design, one object point; formation Release: a Simulator) or of a host
  // stack `psf_sensor` (cfg.bands x S x S, S = cfg.sensor_size_px(), finite; formation Qdo only).
  // Rejects bad shapes and sources before any device work.
  CaptureFrame run(const PsfSource& source, const RealStack& scene);
  CaptureFrame run(const RealStack& psf_sensor, const RealStack& scene);

  // The adjoint of the last run() (once per run: the camera's adjoint consumes its batch):
  // g.clean, g.rgb, g.raw_dn, g.demosaiced (each empty or the last frame's shape, finite) ->
  // g.psf (bands x S x S) and g.scene (bands x H x W), filled in the returned gradient. Refused
  // (InputError) without a run, for a gradient on rgb (the clip has no adjoint), and (Error) for
  // a stage without an adjoint (the release formation).
  CaptureGradient vjp(CaptureGradient g);

  // The development of a measured raw frame: the stages after "raw" (the demosaic, and any stage
  // inserted after it) run on `raw_linear` as on the raw_linear a run() leaves. raw_linear:
  // raw_channels(cfa) x H x W (one plane with a mosaic), H, W >= 3, finite, in linear units (the
  // signal above the dark over gain x (white - black), flat-fielded: 1 = full well). The stages
  // see a CaptureInput without scene or PSF. Returns the frame with raw_linear and what those
  // stages wrote (demosaiced, ...). InputError without the raw stages (options.raw) or for a bad
  // frame, before any work. No vjp follows a develop().
  CaptureFrame develop(const RealStack& raw_linear);

  // The stages' names in run order.
  std::vector<std::string> stage_names() const;
  // Adds `stage` right after the stage named `after` (one of stage_names(); InputError otherwise).
  void insert_after(const std::string& after, std::unique_ptr<CaptureStage> stage);

  const SystemConfig& config() const { return cfg_; }
  Precision precision() const { return prec_; }
  const PipelineOptions& options() const { return opt_; }

 private:
  CaptureFrame run_stages(const CaptureInput& in);

  Runtime& rt_;
  SystemConfig cfg_;
  Precision prec_;
  PipelineOptions opt_;
  std::vector<std::unique_ptr<CaptureStage>> stages_;
  CaptureFrame last_;
  bool have_last_ = false;
};

}  // namespace qdo
