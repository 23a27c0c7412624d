// CapturePipeline (include/qdo/physics/capture_pipeline.hpp): the capture stages, the order the
// constructor lists them in, and the run and adjoint passes over them.
#include "qdo/physics/capture_pipeline.hpp"

#include <Eigen/Dense>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <utility>

#include "physics/device_buffers.hpp"
#include "qdo/physics/demosaic.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/raw.hpp"
#include "qdo/physics/release.hpp"
#include "qdo/physics/sensor_reference.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/util.hpp"

namespace qdo {

namespace {

// acc += v element by element (acc empty: acc = v). Same shapes (checked by the callers).
void add_into(RealStack& acc, const RealStack& v) {
  if (acc.size() == 0) {
    acc = v;
    return;
  }
  for (std::size_t i = 0; i < acc.size(); ++i) acc.data[i] += v.data[i];
}

// The configuration without noise (read noise and shot noise off).
SystemConfig noiseless(SystemConfig cfg) {
  cfg.read_noise_sigma = 0;
  cfg.full_well_photons = 0;
  return cfg;
}

// A PSF source seen with another configuration: the stack, its generation and description are
// the wrapped source's; config() is `cfg` (the pipeline's, without noise), so a Camera bound to
// it images with the pipeline's sensor and adds no noise. No parameters of its own.
class SourceView final : public PsfSource {
 public:
  SourceView(const PsfSource& source, const SystemConfig& cfg) : src_(source), cfg_(cfg) {}
  Runtime& runtime() const override { return src_.runtime(); }
  const SystemConfig& config() const override { return cfg_; }
  Precision precision() const override { return src_.precision(); }
  std::size_t sensor_size() const override { return src_.sensor_size(); }
  std::size_t psf_planes() const override { return src_.psf_planes(); }
  bool psf_ready() const override { return src_.psf_ready(); }
  const cl::Buffer& psf_sensor_buffer() const override { return src_.psf_sensor_buffer(); }
  std::uint64_t psf_generation() const override { return src_.psf_generation(); }
  RealStack psf_sensor() const override { return src_.psf_sensor(); }
  std::size_t parameter_count() const override { return 0; }
  std::vector<double> parameter_vjp(const cl::Buffer&) override {
    throw Error("capture pipeline: its view of the PSF source " + src_.describe() + " has no parameters");
  }
  std::string describe() const override { return src_.describe(); }

 private:
  const PsfSource& src_;
  SystemConfig cfg_;
};

// "camera": the camera operator without noise (cfg is the pipeline's without noise). A source is
// followed through a SourceView and a Camera bound to it, made anew for each run (a source is
// not known to be the same object from one run to the next); a host stack goes to a standalone
// Camera kept between runs, uploaded again only when it changes (the OTFs are then reused).
class CameraCaptureStage final : public CaptureStage {
 public:
  CameraCaptureStage(Runtime& rt, const SystemConfig& cfg, Precision p, const SkipOptions& skip)
      : rt_(rt), cfg_(cfg), prec_(p), skip_(skip) {}
  std::string name() const override { return "camera"; }

  void run(const CaptureInput& in, CaptureFrame& f) override {
    if (in.source) {
      bound_.reset();  // the camera refers to the view: dropped first
      view_ = std::make_unique<SourceView>(*in.source, cfg_);
      bound_ = std::make_unique<Camera>(*view_);
      active_ = bound_.get();
    } else {
      if (!own_) own_ = std::make_unique<Camera>(rt_, cfg_, prec_);
      if (!have_stack_ || own_stack_.data != in.psf_sensor->data) {
        have_stack_ = false;
        own_->set_psf(*in.psf_sensor);
        own_stack_ = *in.psf_sensor;
        have_stack_ = true;
      }
      active_ = own_.get();
    }
    f.clean = active_->images({*in.scene}, skip_).front();
    f.rgb = f.clean;
  }

  // rgb left this stage as a copy of clean: both gradients reach the camera's image.
  void vjp(const CaptureFrame& f, CaptureGradient& g) override {
    if (!active_) throw Error("capture stage 'camera': vjp without a run");
    RealStack total = g.clean;
    if (g.rgb.size()) add_into(total, g.rgb);
    if (total.size() == 0) total = RealStack(3, f.clean.rows, f.clean.cols);
    Camera::Gradient r = active_->vjp({total}, true);
    g.psf = std::move(r.psf);
    g.scene = std::move(r.scenes.front());
  }

 private:
  Runtime& rt_;
  SystemConfig cfg_;
  Precision prec_;
  SkipOptions skip_;
  std::unique_ptr<SourceView> view_;  // declared before bound_: destroyed after it
  std::unique_ptr<Camera> bound_, own_;
  Camera* active_ = nullptr;          // the camera of the last run
  RealStack own_stack_;               // the stack own_ holds
  bool have_stack_ = false;
};

// "release": the release's formation on the DOE grid with a Simulator's native PSF, then the
// sensor response. No adjoint.
class ReleaseCaptureStage final : public CaptureStage {
 public:
  ReleaseCaptureStage(Runtime& rt, const SystemConfig& cfg, Precision p) : rt_(rt), cfg_(cfg), prec_(p), srf_(sensor_response(cfg)) {}
  std::string name() const override { return "release"; }

  void run(const CaptureInput& in, CaptureFrame& f) override {
    const auto* sim = dynamic_cast<const Simulator*>(in.source);
    if (!sim)
      reject("PSF", in.source ? in.source->describe() : std::string("a host PSF stack"),
             "a simulated design (a Simulator source): the release formation needs the native-grid PSF");
    ReleaseImager imager(rt_, prec_, cfg_.bands, in.scene->rows, cfg_.n);
    imager.set_psf(sim->psf_native());
    f.clean = ref::sensor_integrate(imager.blur(*in.scene), srf_);
    f.rgb = f.clean;
  }

 private:
  Runtime& rt_;
  SystemConfig cfg_;
  Precision prec_;
  Eigen::MatrixXd srf_;
};

// "noise" on the device: the camera's noise kernel (sensor.cl's integration with the identity
// response, which reproduces each value exactly and adds the noise) on rgb in the working
// precision, scene 0's counters: the values a Camera with this noise returns.
class DeviceNoiseStage final : public CaptureStage {
 public:
  DeviceNoiseStage(Runtime& rt, const SystemConfig& cfg, Precision p)
      : rt_(rt), cfg_(cfg), prec_(p), k_noise_(rt.kernel("sensor.cl", "sensor_integrate", p)),
        eye_(detail::upload_real(rt, {1, 0, 0, 0, 1, 0, 0, 0, 1}, p)) {}
  std::string name() const override { return "noise"; }

  void run(const CaptureInput&, CaptureFrame& f) override {
    if (!(cfg_.read_noise_sigma > 0 || cfg_.full_well_photons > 0)) return;
    const std::size_t hw = f.rgb.plane_size();
    const cl::Buffer in = detail::upload_real(rt_, f.rgb.data, prec_);
    const cl::Buffer out(rt_.context(), CL_MEM_READ_WRITE, std::max<std::size_t>(3 * hw * real_size(prec_), 8));
    rt_.launch_1d(k_noise_, 3 * hw, prec_, in, eye_, out, int(hw), 3, Real{cfg_.read_noise_sigma}, Real{cfg_.full_well_photons},
                  cl_uint(cfg_.noise_seed & 0xffffffffull), cl_uint(cfg_.noise_seed >> 32), 1);
    rt_.read_reals(out, f.rgb.data.data(), 3 * hw, prec_);
  }
  // Additive and independent of the image: the identity on the gradient of rgb.
  void vjp(const CaptureFrame&, CaptureGradient&) override {}

 private:
  Runtime& rt_;
  SystemConfig cfg_;
  Precision prec_;
  cl::Kernel k_noise_;
  cl::Buffer eye_;  // 3 x 3 identity response, reals of the precision
};

// "noise" on the host, in double: ref::add_noise with scene 0's counters.
class HostNoiseStage final : public CaptureStage {
 public:
  explicit HostNoiseStage(const SystemConfig& cfg) : cfg_(cfg) {}
  std::string name() const override { return "noise"; }
  void run(const CaptureInput&, CaptureFrame& f) override {
    ref::add_noise(f.rgb, cfg_.read_noise_sigma, cfg_.full_well_photons, cfg_.noise_seed, 0);
  }
  void vjp(const CaptureFrame&, CaptureGradient&) override {}

 private:
  SystemConfig cfg_;
};

// "clip": rgb at full scale. No adjoint: a gradient on rgb is refused.
class ClipStage final : public CaptureStage {
 public:
  std::string name() const override { return "clip"; }
  void run(const CaptureInput&, CaptureFrame& f) override { f.clip = clip_to_full_scale(f.rgb, "sensor image"); }
  void vjp(const CaptureFrame&, CaptureGradient& g) override {
    if (g.rgb.size())
      reject("g.rgb", shape(g.rgb),
             "an empty stack: the full-scale clip has no adjoint (give the gradient on g.clean, the image before noise and clip)");
  }
};

// "raw": clean through the sensor as built (RawStage, cfg's noise or none). Keeps its input, the
// point its adjoint is taken at.
class RawCaptureStage final : public CaptureStage {
 public:
  RawCaptureStage(Runtime& rt, const SystemConfig& cfg, Precision p) : cfg_(cfg), raw_(rt, cfg, p) {}
  std::string name() const override { return "raw"; }
  void run(const CaptureInput&, CaptureFrame& f) override {
    point_ = f.clean;
    RawStage::Frames fr = raw_.run(std::vector<RealStack>{f.clean});
    f.raw_dn = std::move(fr.raw.front());
    f.raw_counts = fr.counts;
    f.raw_linear = raw_to_linear(f.raw_dn, cfg_);
  }
  void vjp(const CaptureFrame&, CaptureGradient& g) override {
    if (g.raw_dn.size() == 0) return;
    add_into(g.clean, raw_.adjoint(std::vector<RealStack>{point_}, std::vector<RealStack>{g.raw_dn}).front());
  }

 private:
  SystemConfig cfg_;
  RawStage raw_;
  RealStack point_;  // 3 x H x W: the last run's input
};

// "demosaic": raw_linear (raw_dn in linear units, raw_to_linear: (dn - black) / span, span = gain
// (white - black); or a measured frame, develop()) through DemosaicStage. Linear: the adjoint to
// raw_dn is the transpose divided by span.
class DemosaicCaptureStage final : public CaptureStage {
 public:
  DemosaicCaptureStage(Runtime& rt, const SystemConfig& cfg, DemosaicMethod method, Precision p)
      : cfg_(cfg), dm_(rt, cfg.cfa, method, p) {}
  std::string name() const override { return "demosaic"; }
  void run(const CaptureInput&, CaptureFrame& f) override {
    f.demosaiced = dm_.run(std::vector<RealStack>{f.raw_linear}).front();
  }
  void vjp(const CaptureFrame&, CaptureGradient& g) override {
    if (g.demosaiced.size() == 0) return;
    RealStack t = dm_.adjoint(std::vector<RealStack>{g.demosaiced}).front();
    const double span = cfg_.gain * (cfg_.white_level_dn() - cfg_.black_level_dn);
    for (double& v : t.data) v /= span;
    add_into(g.raw_dn, t);
  }

 private:
  SystemConfig cfg_;
  DemosaicStage dm_;
};

// A gradient (empty, or the frame array's shape, finite) named `name`.
void check_gradient(const std::string& name, const RealStack& g, const RealStack& frame) {
  if (g.size() == 0) return;
  if (frame.size() == 0)
    reject(name, shape(g), "an empty stack: the pipeline's last run wrote no such array (its stages do not include the one that writes it)");
  if (g.planes != frame.planes || g.rows != frame.rows || g.cols != frame.cols)
    reject(name, shape(g), "the last run's shape, " + shape(frame) + ", or an empty stack");
  for (std::size_t i = 0; i < g.size(); ++i)
    if (!std::isfinite(g.data[i])) reject(name + "[" + to_str(i) + "]", g.data[i], "finite values");
}

}  // namespace

std::string to_string(ImageFormation f) { return f == ImageFormation::Release ? "release" : "qdo"; }

double CaptureFrame::seconds_before(const std::string& stage) const {
  double s = 0;
  for (const auto& [name, secs] : stage_seconds) {
    if (name == stage) break;
    s += secs;
  }
  return s;
}

void CaptureStage::vjp(const CaptureFrame&, CaptureGradient&) {
  throw Error("capture stage '" + name() + "' has no adjoint");
}

CapturePipeline::CapturePipeline(Runtime& rt, const SystemConfig& cfg, Precision p, const PipelineOptions& opt)
    : rt_(rt), cfg_(cfg), prec_(p), opt_(opt) {
  cfg_.validate();
  rt_.require(p);
  opt_.skip.validate();
  if (opt_.raw && cfg_.cfa == Cfa::None)
    reject("cfa", "none", "a colour filter mosaic (rggb, grbg, gbrg or bggr) for the raw and demosaic stages: a raw frame is one plane");
  const bool qdo = opt_.formation == ImageFormation::Qdo;
  const SystemConfig quiet = noiseless(cfg_);
  const SystemConfig& sensor = opt_.noise ? cfg_ : quiet;
  // The stages, in run order (a new sensor effect: one line here).
  if (qdo) stages_.push_back(std::make_unique<CameraCaptureStage>(rt_, quiet, p, opt_.skip));
  else stages_.push_back(std::make_unique<ReleaseCaptureStage>(rt_, cfg_, p));
  if (opt_.noise && qdo && !opt_.raw) stages_.push_back(std::make_unique<DeviceNoiseStage>(rt_, cfg_, p));
  if (opt_.noise && !(qdo && !opt_.raw)) stages_.push_back(std::make_unique<HostNoiseStage>(cfg_));
  stages_.push_back(std::make_unique<ClipStage>());
  if (opt_.raw) stages_.push_back(std::make_unique<RawCaptureStage>(rt_, sensor, p));
  if (opt_.raw) stages_.push_back(std::make_unique<DemosaicCaptureStage>(rt_, cfg_, opt_.demosaic, p));
}

CaptureFrame CapturePipeline::run(const PsfSource& source, const RealStack& scene) {
  const std::string what = source.describe();
  if (source.precision() != prec_)
    reject("PSF source precision", to_string(source.precision()), "the pipeline's, " + to_string(prec_) + " (" + what + ")");
  if (source.psf_planes() != cfg_.bands)
    reject("PSF source planes", source.psf_planes(), "one design and one object point: the configuration's " + to_str(cfg_.bands) + " bands (" + what + ")");
  if (source.sensor_size() != cfg_.sensor_size_px())
    reject("PSF source sensor size", source.sensor_size(), "the configuration's " + to_str(cfg_.sensor_size_px()) + " px (" + what + ")");
  const std::vector<double> want = cfg_.wavelengths_nm(), got = source.config().wavelengths_nm();
  for (std::size_t b = 0; b < want.size(); ++b)
    if (got.size() != want.size() || std::fabs(got[b] - want[b]) > 1e-9)
      reject("PSF source wavelengths", to_str(got.front()) + " ... " + to_str(got.back()) + " nm",
             "the configuration's " + to_str(want.front()) + " ... " + to_str(want.back()) + " nm (" + what + ")");
  CaptureInput in;
  in.scene = &scene;
  in.source = &source;
  return run_stages(in);
}

CaptureFrame CapturePipeline::run(const RealStack& psf_sensor, const RealStack& scene) {
  if (opt_.formation != ImageFormation::Qdo)
    reject("psf_sensor", "a host PSF stack", "a Simulator source with the release formation (it needs the native-grid PSF)");
  const std::size_t s = cfg_.sensor_size_px();
  if (psf_sensor.planes != cfg_.bands || psf_sensor.rows != s || psf_sensor.cols != s)
    reject("psf_sensor", shape(psf_sensor), "bands x S x S = " + shape(cfg_.bands, s, s));
  for (std::size_t i = 0; i < psf_sensor.size(); ++i)
    if (!std::isfinite(psf_sensor.data[i])) reject("psf_sensor[" + to_str(i) + "]", psf_sensor.data[i], "finite values");
  CaptureInput in;
  in.scene = &scene;
  in.psf_sensor = &psf_sensor;
  return run_stages(in);
}

CaptureFrame CapturePipeline::run_stages(const CaptureInput& in) {
  const RealStack& scene = *in.scene;
  if (scene.planes != cfg_.bands) reject("scene bands", scene.planes, "the configuration's band count (" + to_str(cfg_.bands) + ")");
  if (scene.rows < 1 || scene.cols < 1) reject("scene", shape(scene), "at least 1 x 1 pixels");
  if (opt_.raw && (scene.rows < 3 || scene.cols < 3))
    reject("scene", shape(scene), "at least 3 x 3 pixels with the raw stages (the demosaic's filters)");
  for (std::size_t i = 0; i < scene.size(); ++i)
    if (!std::isfinite(scene.data[i])) reject("scene[" + to_str(i) + "]", scene.data[i], "finite values");
  if (opt_.formation == ImageFormation::Release) {
    if (scene.rows != scene.cols || scene.rows != cfg_.sensor_size_px())
      reject("scene", shape(scene),
             "with the release formation, a square scene of the configuration's sensor size, " + to_str(cfg_.sensor_size_px()) + " x " +
                 to_str(cfg_.sensor_size_px()));
    (void)release_geometry(scene.rows, cfg_.n);
  }
  have_last_ = false;
  CaptureFrame f;
  for (const auto& stage : stages_) {
    const auto t0 = std::chrono::steady_clock::now();
    stage->run(in, f);
    f.stage_seconds.emplace_back(stage->name(), seconds_since(t0));
  }
  last_ = f;
  have_last_ = true;
  return f;
}

CaptureGradient CapturePipeline::vjp(CaptureGradient g) {
  if (!have_last_) reject("vjp", "without a preceding run()", "run() first (one vjp per run)");
  check_gradient("g.clean", g.clean, last_.clean);
  check_gradient("g.rgb", g.rgb, last_.rgb);
  check_gradient("g.raw_dn", g.raw_dn, last_.raw_dn);
  check_gradient("g.demosaiced", g.demosaiced, last_.demosaiced);
  g.psf = RealStack();
  g.scene = RealStack();
  for (auto it = stages_.rbegin(); it != stages_.rend(); ++it) (*it)->vjp(last_, g);
  have_last_ = false;
  return g;
}

CaptureFrame CapturePipeline::develop(const RealStack& raw_linear) {
  const auto raw = std::find_if(stages_.begin(), stages_.end(), [](const auto& st) { return st->name() == "raw"; });
  if (raw == stages_.end())
    reject("develop", "a pipeline without the raw stages", "one made with options.raw (a mosaic's raw and demosaic stages)");
  const std::size_t planes = raw_channels(cfg_.cfa);
  if (raw_linear.planes != planes || raw_linear.rows < 3 || raw_linear.cols < 3)
    reject("raw_linear", shape(raw_linear), to_str(planes) + " x H x W with H, W >= 3 (a raw frame of the " + to_string(cfg_.cfa) + " mosaic)");
  for (std::size_t i = 0; i < raw_linear.size(); ++i)
    if (!std::isfinite(raw_linear.data[i])) reject("raw_linear[" + to_str(i) + "]", raw_linear.data[i], "finite values");
  have_last_ = false;
  CaptureFrame f;
  f.raw_linear = raw_linear;
  const CaptureInput none;
  for (auto it = raw + 1; it != stages_.end(); ++it) {
    const auto t0 = std::chrono::steady_clock::now();
    (*it)->run(none, f);
    f.stage_seconds.emplace_back((*it)->name(), seconds_since(t0));
  }
  return f;
}

std::vector<std::string> CapturePipeline::stage_names() const {
  std::vector<std::string> names;
  for (const auto& s : stages_) names.push_back(s->name());
  return names;
}

void CapturePipeline::insert_after(const std::string& after, std::unique_ptr<CaptureStage> stage) {
  if (!stage) reject("stage", "null", "a CaptureStage");
  for (auto it = stages_.begin(); it != stages_.end(); ++it)
    if ((*it)->name() == after) {
      stages_.insert(it + 1, std::move(stage));
      have_last_ = false;
      return;
    }
  std::string names;
  for (const auto& s : stages_) names += (names.empty() ? "" : ", ") + s->name();
  reject("after", after, "the name of one of the pipeline's stages: " + names);
}

}  // namespace qdo
