// Simulator (include/qdo/physics/simulator.hpp): the composition of the PSF chain's stages (doe, field,
// propagate, psf, sensor) and the device buffers passed between them.
#include "qdo/physics/simulator.hpp"


#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "physics/device_buffers.hpp"
#include "qdo/runtime/error.hpp"

namespace qdo {

namespace {
// QDO_STAGE_TIMES=1: a queue.finish() after each stage and its time on stderr (diagnostics: the
// finishes cost a little; bench_psf's stage times come from here). Otherwise free.
class StageTimer {
 public:
  StageTimer(cl::CommandQueue& q, const char* chain) : q_(q), chain_(chain) {}
  void operator()(const char* what) {
    if (!enabled()) return;
    q_.finish();
    const auto now = std::chrono::steady_clock::now();
    std::fprintf(stderr, "%s stage %-16s %.4f s\n", chain_, what, std::chrono::duration<double>(now - t_).count());
    t_ = now;
  }

 private:
  static bool enabled() {
    static const bool on = [] {
      const char* e = std::getenv("QDO_STAGE_TIMES");
      return e && std::string(e) == "1";
    }();
    return on;
  }
  cl::CommandQueue& q_;
  const char* chain_;
  std::chrono::steady_clock::time_point t_ = std::chrono::steady_clock::now();
};
}  // namespace

Simulator::~Simulator() = default;

std::string Simulator::describe() const {
  return "simulated (2-D, N = " + to_str(cfg_.n) + (designs_ > 1 ? ", " + to_str(designs_) + " designs" : "") +
         (cfg_.object_points.empty() ? std::string() : ", " + to_str(cfg_.point_count()) + " object points") + ", " +
         to_string(prec_) + ")";
}

SystemConfig Simulator::checked(Runtime& rt, const SystemConfig& cfg, Precision p, std::size_t designs, bool phase_fp64) {
  SystemConfig c = cfg;
  c.validate();
  rt.require(p);
  if (phase_fp64 && p == Precision::F32 && !rt.has_fp64())
    reject("phase_fp64", "true", "false on this device (" + rt.info().name + " has no cl_khr_fp64)");
  if (designs < 1) reject("designs", designs, ">= 1");
  const std::size_t bands = c.bands * designs * c.point_count(), m = PropagationGeometry::from_config(c).m;
  const std::size_t field_bytes = bands * m * m * 2 * real_size(p);
  if (field_bytes > rt.info().max_alloc_bytes)
    reject("n", c.n,
           "a size whose padded field (" + to_str(bands) + " bands x " + to_str(m) + " x " + to_str(m) + " complex " +
               to_string(p) + " = " + to_str(double(field_bytes) / 1048576.0) + " MiB) fits the device's largest allocation (" +
               to_str(double(rt.info().max_alloc_bytes) / 1048576.0) + " MiB); reduce n, padding_px, bands or object points");
  return c;
}

Simulator::Simulator(Runtime& rt, const SystemConfig& cfg, Precision p, std::size_t designs, bool phase_fp64)
    : rt_(rt),
      cfg_(checked(rt, cfg, p, designs, phase_fp64)),
      prec_(p),
      designs_(designs),
      phase_fp64_(phase_fp64 && p == Precision::F32),
      nb_(cfg_.bands * designs * cfg_.point_count()),
      geom_(PropagationGeometry::from_config(cfg_)),
      s_(cfg_.sensor_size_px()),
      rsz_(real_size(p)),
      doe_stage_(rt, cfg_, p),
      field_stage_(rt, cfg_, p, designs, phase_fp64_),
      propagation_(rt, cfg_, p, designs),
      psf_stage_(rt, cfg_, p, designs),
      sensor_stage_(rt, cfg_, p) {
  const std::size_t n = cfg_.n, m = geom_.m;
  const auto& ctx = rt_.context();
  heights_ = cl::Buffer(ctx, CL_MEM_READ_WRITE, designs_ * n * n * rsz_);
  field_ = cl::Buffer(ctx, CL_MEM_READ_WRITE, nb_ * m * m * 2 * rsz_);
  psf_ = cl::Buffer(ctx, CL_MEM_READ_WRITE, nb_ * n * n * rsz_);
  psf_s_ = cl::Buffer(ctx, CL_MEM_READ_WRITE, nb_ * s_ * s_ * rsz_);
  sums_crop_ = cl::Buffer(ctx, CL_MEM_READ_WRITE, nb_ * rsz_);
  sums_sensor_ = cl::Buffer(ctx, CL_MEM_READ_WRITE, nb_ * rsz_);
}

cl::Buffer& Simulator::write_scratch(cl::Buffer& buf, const std::vector<double>& host) {
  if (!buf()) buf = cl::Buffer(rt_.context(), CL_MEM_READ_WRITE, host.size() * rsz_);
  rt_.write_reals(buf, host.data(), host.size(), prec_);
  return buf;
}

void Simulator::set_heights(const Map2D& height_m) { set_heights_batch({height_m}); }

void Simulator::set_heights_batch(const std::vector<Map2D>& maps) {
  if (maps.size() != designs_) reject("height maps", maps.size(), "one per design of this simulator (" + to_str(designs_) + ")");
  doe_stage_.write(heights_, maps);
  heights_set_ = true;
  psf_valid_ = false;
}

void Simulator::set_design(Parameterization kind, const std::vector<double>& params, const Quantizer* q, double alpha) {
  require_single_design("set_design");
  doe_stage_.expand(heights_, kind, params, q, alpha);
  heights_set_ = true;
  psf_valid_ = false;
}

Map2D Simulator::heights() const {
  Map2D h(cfg_.n, cfg_.n);
  h.data = detail::download_real(rt_, heights_, h.data.size(), prec_);
  return h;
}

void Simulator::require_heights() const {
  if (!heights_set_) throw Error("Simulator: set_heights() must be called before computing fields or PSFs");
}

void Simulator::compute_psf() {
  StageTimer stage(rt_.queue(), "compute_psf");
  const bool host = propagation_.host(true);
  const bool streamed = host && !keep_field_ && designs_ == 1 && cfg_.point_count() == 1;
  // Intensity of the N x N crop and its per-band sums (fused into the host propagation, else one
  // kernel pass). The native stack stays unnormalised (normalising it before the linear area
  // resampling would not change the normalised sensor stack); psf_native() and the adjoints
  // normalise it when they need it.
  if (streamed) {
    run_streamed_propagation();  // field, propagation and crop a chunk of planes at a time
    stage("field+propagation+crop (streamed)");
  } else {
    require_heights();
    field_stage_.run(heights_, field_, host);
    stage("field");
    if (propagation_.run(field_, cfg_.sensor_distance_m, true, true, &psf_, &sums_crop_)) {
      stage("propagation+crop");
    } else {
      stage("propagation");
      psf_stage_.intensity_crop_sums(field_, psf_, sums_crop_);
      stage("crop");
    }
  }
  native_normalized_ = false;
  psf_stage_.resample(psf_, psf_s_);
  stage("resample");
  psf_stage_.normalize(psf_s_, s_ * s_, sums_sensor_);
  stage("normalise");
  psf_valid_ = true;
  field_valid_ = !streamed;
  field_streamed_ = streamed;
  ++psf_generation_;
  if (cfg_.strict_sampling) sampling().enforce();
}

void Simulator::run_streamed_propagation() {
  require_heights();
  const std::size_t m = geom_.m, bands = nb_;
  const std::size_t chunk = propagation_.chunk_planes();
  const std::size_t chunks = (bands + chunk - 1) / chunk;
  const std::size_t ring_bytes = chunk * m * m * 2 * rsz_;
  if (!field_ring_() || field_ring_.getInfo<CL_MEM_SIZE>() < ring_bytes)
    field_ring_ = cl::Buffer(rt_.context(), CL_MEM_READ_WRITE, ring_bytes);
  for (std::size_t i = 0; i < chunks; ++i) {
    const std::size_t b0 = i * chunk, c = std::min(chunk, bands - b0);
    field_stage_.run_chunk(heights_, field_ring_, chunk, i);
    propagation_.run_planes(field_ring_, b0, c, psf_, sums_crop_);
  }
}

const SamplingReport& Simulator::sampling() const {
  // The crop sums exist only once compute_psf() has run past propagation.
  return propagation_.sampling(psf_valid_ ? &sums_crop_ : nullptr);
}

void Simulator::ensure_native_normalized() {
  if (native_normalized_) return;
  psf_stage_.scale(psf_, cfg_.n * cfg_.n, sums_crop_);
  native_normalized_ = true;
}

RealStack Simulator::psf_native() const {
  if (!psf_valid_) throw Error("Simulator: compute_psf() has not run for the current heights");
  RealStack out;  // filled straight from the device (no zeroed allocation first)
  out.planes = nb_;
  out.rows = out.cols = cfg_.n;
  out.data = detail::download_real(rt_, psf_, nb_ * cfg_.n * cfg_.n, prec_);
  if (!native_normalized_) {
    // Normalise on the host (in double) with the device's per-band sums, as scale_by_sums.
    const auto sums = detail::download_real(rt_, sums_crop_, nb_, prec_);
    const std::size_t nn = cfg_.n * cfg_.n;
    for (std::size_t b = 0; b < nb_; ++b)
      if (sums[b] > 0)
        for (std::size_t e = 0; e < nn; ++e) out.data[b * nn + e] /= sums[b];
  }
  return out;
}

RealStack Simulator::psf_sensor() const {
  if (!psf_valid_) throw Error("Simulator: compute_psf() has not run for the current heights");
  RealStack out;  // filled straight from the device (no zeroed allocation first)
  out.planes = nb_;
  out.rows = out.cols = s_;
  out.data = detail::download_real(rt_, psf_s_, nb_ * s_ * s_, prec_);
  return out;
}

void Simulator::require_adjoint_state() const {
  if (psf_valid_ && !field_valid_ && field_streamed_)
    throw Error("Simulator: the adjoints need the propagated field, which the last compute_psf() did not keep "
                "(set_keep_field(false)); call set_keep_field(true) and compute_psf() again");
  if (!psf_valid_ || !field_valid_) throw Error("Simulator: compute_psf() must run before an adjoint");
}

void Simulator::require_single_design(const char* what) const {
  if (designs_ != 1)
    throw Error(std::string("Simulator: ") + what + " needs a simulator of one design (this one batches " + to_str(designs_) +
                "); construct one with designs = 1");
}

Map2D Simulator::backward_from_native(const cl::Buffer& g_native) {
  const std::size_t n = cfg_.n, m = geom_.m, bands = nb_;  // one design: points x bands planes
  StageTimer stage(rt_.queue(), "adjoint");
  if (!gfield_()) gfield_ = cl::Buffer(rt_.context(), CL_MEM_READ_WRITE, bands * m * m * 2 * rsz_);
  if (!dh_()) dh_ = cl::Buffer(rt_.context(), CL_MEM_READ_WRITE, n * n * rsz_);
  // The host propagation reads only [0, N)^2: the kernel then covers rows [0, N) and the columns
  // up to N rounded to the work-group size.
  psf_stage_.intensity_vjp(g_native, field_, gfield_, propagation_.host(true));
  stage("intensity_vjp");
  propagation_.run(gfield_, -cfg_.sensor_distance_m, false);  // adjoint of +z propagation
  stage("propagation");
  return phase_vjp_gradient(stage);
}

template <typename Stage>
Map2D Simulator::phase_vjp_gradient(Stage& stage) {
  const std::size_t n = cfg_.n;
  field_stage_.phase_vjp(heights_, gfield_, dh_);
  stage("phase_vjp");
  Map2D out(n, n);
  out.data = detail::download_real(rt_, dh_, n * n, prec_);
  stage("read-back");
  return out;
}

Map2D Simulator::psf_native_vjp(const RealStack& g_psf) {
  require_single_design("psf_native_vjp");
  require_adjoint_state();
  if (g_psf.planes != nb_ || g_psf.rows != cfg_.n || g_psf.cols != cfg_.n)
    reject("g_psf", to_str(g_psf.planes) + " x " + to_str(g_psf.rows) + " x " + to_str(g_psf.cols),
           "planes x N x N = " + to_str(nb_) + " x " + to_str(cfg_.n) + " x " + to_str(cfg_.n) + " (planes = object points x bands)");
  cl::Buffer& g = write_scratch(g_native_, g_psf.data);
  ensure_native_normalized();
  psf_stage_.normalize_vjp(g, psf_, cfg_.n * cfg_.n, sums_crop_);
  return backward_from_native(g);
}

Map2D Simulator::psf_sensor_vjp(const RealStack& g_psf_sensor) {
  require_single_design("psf_sensor_vjp");
  require_adjoint_state();
  if (g_psf_sensor.planes != nb_ || g_psf_sensor.rows != s_ || g_psf_sensor.cols != s_)
    reject("g_psf_sensor", to_str(g_psf_sensor.planes) + " x " + to_str(g_psf_sensor.rows) + " x " + to_str(g_psf_sensor.cols),
           "planes x S x S = " + to_str(nb_) + " x " + to_str(s_) + " x " + to_str(s_) + " (planes = object points x bands)");
  return sensor_vjp_in_scratch(write_scratch(g_sensor_, g_psf_sensor.data));
}

Map2D Simulator::psf_sensor_vjp(const cl::Buffer& g_psf_sensor) {
  require_single_design("psf_sensor_vjp");
  require_adjoint_state();
  const std::size_t bytes = nb_ * s_ * s_ * rsz_;
  if (g_psf_sensor.getInfo<CL_MEM_SIZE>() < bytes)
    reject("g_psf_sensor buffer", to_str(g_psf_sensor.getInfo<CL_MEM_SIZE>()) + " bytes",
           ">= " + to_str(bytes) + " (points x bands x S x S reals of the simulator's precision)");
  // The host path only reads its input; the kernel path works in place on it: a copy into the
  // scratch buffer first (device to device).
  if (propagation_.host(true)) {
    cl::Buffer read_only = g_psf_sensor;  // a second handle to the caller's buffer, not a copy
    return sensor_vjp_in_scratch(read_only);
  }
  if (!g_sensor_()) g_sensor_ = cl::Buffer(rt_.context(), CL_MEM_READ_WRITE, bytes);
  rt_.queue().enqueueCopyBuffer(g_psf_sensor, g_sensor_, 0, 0, bytes);
  return sensor_vjp_in_scratch(g_sensor_);
}

Map2D Simulator::sensor_vjp_in_scratch(cl::Buffer& g_sensor) {
  const std::size_t n = cfg_.n, bands = nb_;  // one design: points x bands planes
  const AreaWeights& wt = psf_stage_.weights_transposed();
  StageTimer stage(rt_.queue(), "adjoint");
  if (propagation_.host(true)) {
    // Fused on the host: normalisation vjp, transposed resampling, |U|² vjp and the -z
    // propagation in one pass (HostPropagator::IntensityAdjointInput), then the phase vjp kernel.
    const std::size_t m = geom_.m;
    if (!gfield_()) gfield_ = cl::Buffer(rt_.context(), CL_MEM_READ_WRITE, bands * m * m * 2 * rsz_);
    if (!dh_()) dh_ = cl::Buffer(rt_.context(), CL_MEM_READ_WRITE, n * n * rsz_);
    HostPropagator::IntensityAdjointInput in;
    in.g_sensor = &g_sensor;
    in.u = &field_;
    in.s = s_;
    in.taps = wt.taps;
    in.col_offset = wt.col_offset;
    in.start = wt.start.data();
    in.w = wt.w.data();
    in.y_sensor = &psf_s_;
    in.sensor_sums = &sums_sensor_;
    propagation_.run_adjoint(gfield_, in);
    stage("normalize+resample+intensity+propagation vjp");
    return phase_vjp_gradient(stage);
  }
  psf_stage_.normalize_vjp(g_sensor, psf_s_, s_ * s_, sums_sensor_);
  stage("normalize_vjp");
  // Transposed area resampling (S -> N).
  if (!g_native_()) g_native_ = cl::Buffer(rt_.context(), CL_MEM_READ_WRITE, bands * n * n * rsz_);
  cl::Buffer& g = g_native_;
  // The forward resampled the unnormalised intensity (the native normalisation cancels in
  // the sensor normalisation), so the transposed resampling already gives dL/d|U|².
  psf_stage_.resample_transposed(g_sensor, g);
  stage("resample_vjp");
  return backward_from_native(g);
}

void Simulator::set_optical_axis(double x_m, double y_m) {
  SystemConfig c = cfg_;
  c.aperture_offset_x_m = x_m;
  c.aperture_offset_y_m = y_m;
  c.validate();
  if (c.aperture_offset_x_m == cfg_.aperture_offset_x_m && c.aperture_offset_y_m == cfg_.aperture_offset_y_m) return;
  field_stage_.set_axis(c);
  psf_stage_.set_sensor_weights(c);
  cfg_ = c;
  psf_valid_ = false;
}

RealStack Simulator::integrate(const RealStack& cube) {
  require_single_design("integrate");
  if (cube.planes != cfg_.bands)
    reject("cube bands", cube.planes, "the configuration's band count (" + to_str(cfg_.bands) + ")");
  const std::size_t hw = cube.plane_size();
  const cl::Buffer in = detail::upload_real(rt_, cube.data, prec_);
  cl::Buffer out_buf(rt_.context(), CL_MEM_READ_WRITE, 3 * hw * rsz_);
  sensor_stage_.run(in, out_buf, hw, 1);
  RealStack out(3, cube.rows, cube.cols);
  out.data = detail::download_real(rt_, out_buf, out.size(), prec_);
  return out;
}

}  // namespace qdo
