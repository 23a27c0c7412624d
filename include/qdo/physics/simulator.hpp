// The OpenCL forward model: PSF stack, per-band convolution and RGB sensor, with every
// buffer kept on the device between stages. One Simulator per (configuration, precision): a
// composition of one launcher per kernel file, which owns the device buffers passed between them.
//
//   heights (N x N) [DoeStage, doe.hpp] --doe_field [FieldStage, field.hpp]--> field (bands x M x M)
//     --FFT, TF, IFFT [PropagationStage, propagate.hpp]--> field --intensity_crop_sums, normalise,
//     resample_area [PsfStage, psf.hpp]--> psf (bands x N x N), psf_sensor (bands x S x S)
// The simulator is a HeightMapPsfSource (psf_source.hpp): the camera (camera.hpp: per-band
// convolution, sensor integration, noise) takes it, or any other PSF source, and follows its stack
// (psf_sensor_buffer(), psf_generation()); the simulator knows no camera. integrate() runs
// SensorStage (sensor.hpp) alone.
#pragma once
#include <CL/opencl.hpp>

#include <Eigen/Dense>

#include <cstdint>
#include <memory>

#include "qdo/data/config.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/physics/field.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/propagate.hpp"
#include "qdo/physics/psf.hpp"
#include "qdo/physics/psf_source.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/physics/sensor.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {


// A HeightMapPsfSource (psf_source.hpp): its parameters are the N x N height map (metres, row-major).
class Simulator final : public HeightMapPsfSource {
 public:
  // Validates cfg (InputError) and the precision against the device (DeviceError); builds
  // or loads the kernels, bakes the FFT plan and uploads the per-band tables.
  // designs > 1 batches that many height maps through the PSF chain in one pass (planes =
  // designs x bands, design-major: plane d * bands + b); adjoints, convolution and the sensor
  // need designs = 1. Object points (cfg.object_points, config.hpp) are a second batch axis:
  // planes = designs x points x bands, design-major then point-major (plane (d * points + p) *
  // bands + b), all in the same one pass; the adjoints take a gradient on every point's planes
  // (points x bands x S x S) and sum the points' contributions into dL/dH. Every plane is
  // reported on the fixed sensor window centred on the optical axis (the off-axis PSF sits near its
  // chief-ray image point (-z tan θx, -z tan θy), sampling().bands[i].chief_ray_*_m); the camera
  // takes one point (psf_planes() == bands).
  // phase_fp64 (float32 only; needs cl_khr_fp64): evaluate the DOE phase and its sine/cosine in
  // double before rounding the field to float ("float32 with float64 phase"; the adjoint's
  // phase recomputation stays float32). Ignored for Precision::F64.
  Simulator(Runtime& rt, const SystemConfig& cfg, Precision p, std::size_t designs = 1, bool phase_fp64 = false);
  ~Simulator();
  Simulator(const Simulator&) = delete;
  Simulator& operator=(const Simulator&) = delete;
  bool phase_fp64() const { return phase_fp64_; }
  // The fused host propagation (HostPropagator, host_propagator.hpp) on CPU devices with the FFTW
  // backend: on by default; off runs the same propagation as FFT plan + transfer-function kernel +
  // crop kernel, as on every other backend (tests compare the two, benchmarks time both).
  void set_host_fusion(bool on) { propagation_.set_host_fusion(on); }
  bool host_fusion() const { return propagation_.host_fusion(); }
  // Whether compute_psf() and psf_sensor_vjp() propagate on the host (fusion on, FFTW backend,
  // N < M).
  bool uses_host_propagation() const { return propagation_.host(true); }
  std::size_t designs() const { return designs_; }
  // Whether compute_psf() keeps the propagated field (bands x M x M complex) for the adjoints:
  // on by default. Off, with the host propagation and one design, the field is made and
  // propagated a few planes at a time (HostPropagator::threads() of them) in one small reused
  // buffer: the PSF, its sums and the sampling report are bit-identical, the run touches
  // ~2 x N x M complex values instead of bands x N x M (390 MB at the paper preset, whose first
  // touch and release cost ~0.2 s in a fresh process), and the adjoints refuse until a
  // compute_psf() with it on. For commands that need only the PSF (`qdo psf`, `qdo simulate`).
  // Elsewhere (kernel path, batches) it changes nothing.
  void set_keep_field(bool keep) { keep_field_ = keep; }
  bool keep_field() const { return keep_field_; }

  const SystemConfig& config() const override { return cfg_; }
  Runtime& runtime() const override { return rt_; }
  const PropagationGeometry& geometry() const { return geom_; }
  Precision precision() const override { return prec_; }
  std::size_t sensor_size() const override { return s_; }
  // PsfSource: designs x points x bands planes; a stack exists after compute_psf() for the current heights.
  std::size_t psf_planes() const override { return nb_; }
  bool psf_ready() const override { return psf_valid_; }
  std::string describe() const override;

  // Uploads an N x N height map (metres, row-major). Rejects wrong shapes, NaN/Inf and
  // heights outside [0, 2 h_max] before any device work.
  void set_heights(const Map2D& height_m) override;
  // One N x N map per design (designs() of them), for batched PSF stacks.
  void set_heights_batch(const std::vector<Map2D>& maps);
  // The same from design parameters, on the device: expands `params` (layout of
  // parameter_count(kind, N), metres) onto the N x N grid (clamped to [0, h_max]) and, when q is
  // given, applies the alpha-blended quantizer (kernels/doe.cl). Rejects NaN/Inf and wrong sizes.
  void set_design(Parameterization kind, const std::vector<double>& params, const Quantizer* q = nullptr,
                  double alpha = 1.0);
  // The current N x N heights (a host copy).
  Map2D heights() const;
  // Moves the optical axis to (x, y) metres from the grid's centre sample (config.hpp
  // aperture_offset_m; x along columns) without a new simulator: the aperture's weights, the
  // object points and the sensor window follow; a stack computed before is no longer valid.
  // Needs aperture_edge "area" unless (x, y) = (0, 0); InputError (before any change) for an
  // offset the configuration refuses.
  void set_optical_axis(double x_m, double y_m);

  // Runs the PSF chain on the device (all bands in one batched pass). The results stay on the
  // device; the accessors below copy them to the host. Honours cfg.strict_sampling.
  void compute_psf() override;
  RealStack psf_native() const;        // (designs x points x bands) x N x N, each plane sums to 1
  RealStack psf_sensor() const override;  // (designs x points x bands) x S x S on the sensor pitch, each plane sums to 1
  // Read back from the device on first use after each compute_psf() (a small bands x 4
  // transfer), so the PSF loop itself has no host round trip.
  const SamplingReport& sampling() const;
  // The device buffer behind psf_sensor(): (designs x points x bands) x S x S reals of precision(),
  // row-major, valid after compute_psf() until the heights change. For stages that consume
  // the PSF on the device (src/physics/camera.cpp) without a host round trip.
  const cl::Buffer& psf_sensor_buffer() const override { return psf_s_; }
  // Incremented by every compute_psf(): consumers that cache something derived from the PSF
  // (OTFs, crops) compare it to know when to rebuild.
  std::uint64_t psf_generation() const override { return psf_generation_; }

  // Adjoints at the current heights (compute_psf() must have run; its field, sums and PSFs are
  // reused, all on the device): dL/dH (N x N, per metre) for a gradient of L with respect to
  // psf_sensor() (points x bands x S x S) or psf_native() (points x bands x N x N). See include/qdo/physics/adjoint.hpp.
  Map2D psf_sensor_vjp(const RealStack& g_psf_sensor) override;
  // The same with the gradient on the device: points x bands x S x S reals of precision(), row-major (as
  // psf_sensor_buffer()); it is copied, not modified. Equal to the host form for the same values.
  Map2D psf_sensor_vjp(const cl::Buffer& g_psf_sensor) override;
  Map2D psf_native_vjp(const RealStack& g_psf);

  // Sensor integration alone (no convolution) of a bands x H x W cube, with noise.
  RealStack integrate(const RealStack& cube);

  const Eigen::MatrixXd& srf() const { return sensor_stage_.srf(); }

 private:
  // cfg validated against the other arguments and the device (the constructor's checks).
  static SystemConfig checked(Runtime& rt, const SystemConfig& cfg, Precision p, std::size_t designs, bool phase_fp64);
  void require_heights() const;
  void require_single_design(const char* what) const;
  // Error unless compute_psf() ran and kept its field (set_keep_field).
  void require_adjoint_state() const;
  // compute_psf()'s field + propagation + crop without keeping the field (set_keep_field(false)):
  // a chunk of planes at a time through field_ring_ (chunk x M x M complex, rows [0, N) used).
  void run_streamed_propagation();
  // psf_ normalised in place (it is left unnormalised by compute_psf()).
  void ensure_native_normalized();
  // Writes host reals into a scratch buffer kept across calls (allocated on first use with the
  // size of `host`, which is fixed per call site), in the device precision.
  cl::Buffer& write_scratch(cl::Buffer& buf, const std::vector<double>& host);
  // dL/dH from a gradient on psf_sensor() in g_sensor (bands x S x S; overwritten by the kernel
  // path, only read by the host one), or on the unnormalised native stack (bands x N x N).
  Map2D sensor_vjp_in_scratch(cl::Buffer& g_sensor);
  Map2D backward_from_native(const cl::Buffer& g_native);
  // dL/dH from the back-propagated field gradient in gfield_ ([0, N)^2), read back to the host.
  template <typename Stage>
  Map2D phase_vjp_gradient(Stage& stage);

  Runtime& rt_;
  SystemConfig cfg_;
  Precision prec_;
  std::size_t designs_ = 1;
  bool phase_fp64_ = false;
  std::size_t nb_ = 0;   // planes in the PSF chain: designs x bands
  PropagationGeometry geom_;
  std::size_t s_ = 0;    // sensor PSF size
  std::size_t rsz_ = 4;  // bytes per real on the device

  DoeStage doe_stage_;
  FieldStage field_stage_;
  PropagationStage propagation_;
  PsfStage psf_stage_;
  SensorStage sensor_stage_;

  bool heights_set_ = false, psf_valid_ = false;
  bool field_valid_ = false;  // field_ holds the propagated field of the current heights (adjoints need it)
  bool native_normalized_ = true;  // psf_ holds normalised values (else raw |U|², sums in sums_crop_)
  std::uint64_t psf_generation_ = 0;
  bool keep_field_ = true;
  bool field_streamed_ = false;  // the last compute_psf() streamed its field (field_valid_ false for that reason)

  // Between the stages: heights (designs x N x N), field (planes x M x M complex), psf (planes x N x N),
  // psf_s (planes x S x S), the per-plane sums of the crop and of the sensor stack (planes reals).
  cl::Buffer heights_, field_, psf_, psf_s_, sums_crop_, sums_sensor_;
  cl::Buffer field_ring_;  // the streamed PSF's field: chunk x M x M complex
  // Adjoint state: the field gradient (bands x M x M complex), dL/dH (N x N), the adjoint inputs
  // (bands x N x N, bands x S x S), reused across calls.
  cl::Buffer gfield_, dh_, g_native_, g_sensor_;
};

}  // namespace qdo
