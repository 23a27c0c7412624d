// The OpenCL forward model: PSF stack, per-band convolution and RGB sensor, with every
// buffer kept on the device between stages. One Simulator per (configuration, precision).
//
//   heights (N x N) --doe_field--> field (bands x M x M) --FFT, TF, IFFT--> field
//     --intensity_crop_sums, normalise--> psf (bands x N x N) --resample_area, normalise--> psf_sensor
//     (bands x S x S) --FFT--> OTF (bands x PY x PX, cached until the heights change)
//   cube (bands x H x W) --Camera (camera.hpp): per-band convolution, sensor integration, noise-->
//     rgb (3 x H x W); the Simulator's convolution and sensor-image calls delegate to one Camera
//     that follows this simulator's PSF (psf_sensor_buffer(), psf_generation()).
#pragma once
#include <CL/opencl.hpp>

#include <Eigen/Dense>

#include <cstdint>
#include <memory>

#include "qdo/config.hpp"
#include "qdo/doe.hpp"
#include "qdo/fft.hpp"
#include "qdo/optics.hpp"
#include "qdo/psf_source.hpp"
#include "qdo/runtime.hpp"
#include "qdo/types.hpp"

namespace qdo {

class Camera;

// A HeightMapPsfSource (psf_source.hpp): its parameters are the N x N height map (metres, row-major).
class Simulator final : public HeightMapPsfSource {
 public:
  // Validates cfg (InputError) and the precision against the device (DeviceError); builds
  // or loads the kernels, bakes the FFT plan and uploads the per-band tables.
  // designs > 1 batches that many height maps through the PSF chain in one pass (planes =
  // designs x bands, design-major: plane d * bands + b); adjoints, convolution and the sensor
  // need designs = 1.
  // phase_fp64 (float32 only; needs cl_khr_fp64): evaluate the DOE phase and its sine/cosine in
  // double before rounding the field to float ("float32 with float64 phase"; the adjoint's
  // phase recomputation stays float32). Ignored for Precision::F64.
  Simulator(Runtime& rt, const SystemConfig& cfg, Precision p, std::size_t designs = 1, bool phase_fp64 = false);
  ~Simulator();
  Simulator(const Simulator&) = delete;
  Simulator& operator=(const Simulator&) = delete;
  bool phase_fp64() const { return phase_fp64_; }
  // The fused host propagation (HostPropagator, fft.hpp) on CPU devices with the FFTW backend:
  // on by default; off runs the same propagation as FFT plan + transfer-function kernel + crop
  // kernel, as on every other backend (tests compare the two, benchmarks time both).
  void set_host_fusion(bool on) { host_fusion_ = on; }
  bool host_fusion() const { return host_fusion_; }
  // Whether compute_psf() and psf_sensor_vjp() propagate on the host (fusion on, FFTW backend,
  // N < M).
  bool uses_host_propagation() const { return host_propagation(true); }
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
  // PsfSource: designs x bands planes; a stack exists after compute_psf() for the current heights.
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

  // Runs the PSF chain on the device (all bands in one batched pass). The results stay on the
  // device; the accessors below copy them to the host. Honours cfg.strict_sampling.
  void compute_psf() override;
  RealStack psf_native() const;        // (designs x bands) x N x N, each band sums to 1
  RealStack psf_sensor() const override;  // (designs x bands) x S x S on the sensor pitch, each band sums to 1
  // Read back from the device on first use after each compute_psf() (a small bands x 4
  // transfer), so the PSF loop itself has no host round trip.
  const SamplingReport& sampling() const;
  // The device buffer behind psf_sensor(): (designs x bands) x S x S reals of precision(),
  // row-major, valid after compute_psf() until the heights change. For stages that consume
  // the PSF on the device (src/physics/camera.cpp) without a host round trip.
  const cl::Buffer& psf_sensor_buffer() const override { return psf_s_; }
  // Incremented by every compute_psf(): consumers that cache something derived from the PSF
  // (OTFs, crops) compare it to know when to rebuild.
  std::uint64_t psf_generation() const override { return psf_generation_; }

  // Adjoints at the current heights (compute_psf() must have run; its field, sums and PSFs are
  // reused, all on the device): dL/dH (N x N, per metre) for a gradient of L with respect to
  // psf_sensor() (bands x S x S) or psf_native() (bands x N x N). See include/qdo/adjoint.hpp.
  Map2D psf_sensor_vjp(const RealStack& g_psf_sensor) override;
  // The same with the gradient on the device: bands x S x S reals of precision(), row-major (as
  // psf_sensor_buffer()); it is copied, not modified. Equal to the host form for the same values.
  Map2D psf_sensor_vjp(const cl::Buffer& g_psf_sensor) override;
  // Adjoint of sensor_images() for the batch of its last call (same scenes, still on the
  // device): gradients on the RGB images (3 x H x W per scene) -> gradient on psf_sensor()
  // (bands x S x S), through the sensor integration and the per-band convolution. Noise is an
  // additive constant. Chain with psf_sensor_vjp() for dL/dH.
  RealStack sensor_images_vjp(const std::vector<RealStack>& g_rgb);
  Map2D psf_native_vjp(const RealStack& g_psf);

  // Field after the DOE (bands x M x M) and after propagation, for tests: runs the stages
  // up to that point and returns a host copy.
  ComplexStack debug_field_after_doe();
  ComplexStack debug_field_after_propagation();
  // Propagates an arbitrary bands x M x M field over z_m on the device (tests).
  ComplexStack propagate_field(const ComplexStack& field, double z_m);

  // Per-band convolution of cubes (bands x H x W each) with psf_sensor (compute_psf() first;
  // the OTF is reused across calls and scenes until the heights change).
  RealStack convolve(const RealStack& cube);
  // A batch of same-shape scenes in one batched FFT pass (scenes x bands planes).
  std::vector<RealStack> convolve_batch(const std::vector<RealStack>& cubes);
  // Convolution then sensor integration and noise (cfg's noise settings): 3 x H x W. In a
  // batch, scene k draws noise counters ((k*H*W + pixel) * 3 + channel), as ref::add_noise.
  RealStack sensor_image(const RealStack& cube);
  std::vector<RealStack> sensor_images(const std::vector<RealStack>& cubes);
  // Sensor integration alone (no convolution) of a bands x H x W cube, with noise.
  RealStack integrate(const RealStack& cube);

  const Eigen::MatrixXd& srf() const { return srf_; }

 private:
  template <typename T>
  cl::Buffer upload(const std::vector<T>& host, cl_mem_flags flags = CL_MEM_READ_ONLY) const;
  cl::Buffer upload_real(const std::vector<double>& host, cl_mem_flags flags = CL_MEM_READ_ONLY) const;
  cl::Buffer make_tf(double z_m) const;
  cl::Buffer upload_complex(const std::vector<cdouble>& host, cl_mem_flags flags = CL_MEM_READ_ONLY) const;
  std::vector<double> download_real(const cl::Buffer& b, std::size_t count) const;
  cl::Buffer& write_scratch(cl::Buffer& buf, const std::vector<double>& host);
  std::vector<cdouble> download_complex(const cl::Buffer& b, std::size_t count) const;
  // The DOE field into field_; crop_rows: only rows [0, N) are written (enough for the host
  // propagation, which reads nothing else), else the whole M x M window.
  void run_doe_field(bool crop_rows = false);
  // compute_psf()'s field + propagation + crop without keeping the field (set_keep_field(false)):
  // planes [b0, b0 + c) at a time through field_ring_ (c x M x M complex, rows [0, N) used).
  void run_streamed_propagation();
  // In-place propagation of a bands x M x M field over z_m; hinted: the field is zero outside
  // [0, N)^2 and only [0, N)^2 of the result is read (field_plan()). With the host propagation
  // (host_propagation(hinted)) and `intensity`/`crop_sums` given, the crop's |U|² (bands x N x N)
  // and its per-band sums are written too and true is returned; otherwise false (the caller
  // computes them).
  bool run_propagation(cl::Buffer& field, double z_m, bool record_sampling, bool hinted = true,
                       cl::Buffer* intensity = nullptr, cl::Buffer* crop_sums = nullptr);
  FftPlan& field_plan(bool hinted = true);
  // Whether a propagation with this hint runs fused on the host (HostPropagator): the FFT
  // backend is FFTW (CPU devices), the field is zero-padded (N < M) and fusion is on.
  bool host_propagation(bool hinted) const;
  HostPropagator& host_propagator();
  // A device field of the stored layout (samples at [0, N)) as the centred window of
  // PropagationGeometry (samples at [offset, offset + N)): for the debug accessors.
  ComplexStack centred(const cl::Buffer& field) const;
  // Where the DOE samples sit in the stored M x M window (see field_plan()).
  static constexpr std::size_t kFieldOffset = 0;
  void band_reduce(cl::Kernel& k, const cl::Buffer& x, std::size_t len, cl::Buffer& sums);
  // The camera of convolve*/sensor_images*/sensor_images_vjp (made on first use; `what` names
  // the caller in errors: one design, compute_psf() first).
  Camera& camera(const char* what);
  void run_sensor(const cl::Buffer& in, cl::Buffer& out, std::size_t hw, std::size_t scenes);
  // Sets the arguments doe_field, doe_field_p64 and phase_vjp share: (height, k_tab, dn_tab,
  // a3, a4, n, m, offset, bands, pitch, distance (<= 0: plane wave), aperture radius^2), the
  // scalars in precision p; bands = `planes`, or all planes (nb_) when 0 (the streamed PSF passes
  // its chunk's planes).
  template <typename A3, typename A4>
  void set_phase_args(cl::Kernel& k, Precision p, const cl::Buffer& k_tab, const cl::Buffer& dn_tab, const A3& a3,
                      const A4& a4, std::size_t planes = 0);
  void require_single_design(const char* what) const;
  // Error unless compute_psf() ran and kept its field (set_keep_field).
  void require_adjoint_state() const;
  void normalize_bands(cl::Buffer& x, std::size_t len, cl::Buffer& sums);
  void resample(const cl::Buffer& in, cl::Buffer& out, const cl::Buffer& start, const cl::Buffer& w, std::size_t n_in,
                std::size_t n_out, std::size_t taps);
  void ensure_native_normalized();
  void normalize_vjp(cl::Buffer& g, const cl::Buffer& y, std::size_t len, const cl::Buffer& sums);
  Map2D backward_from_native(const cl::Buffer& g_native);
  template <typename Stage>
  Map2D phase_vjp_gradient(Stage& stage);
  cl::Buffer tf_for(double z_m);

  Runtime& rt_;
  SystemConfig cfg_;
  Precision prec_;
  std::size_t designs_ = 1;
  bool phase_fp64_ = false;
  cl::Buffer k64_, dn64_;  // double copies of k_ and dn_ for doe_field_p64
  std::size_t nb_ = 0;                 // planes in the PSF chain: designs x bands
  PropagationGeometry geom_;
  std::size_t s_ = 0;                  // sensor PSF size
  std::size_t rsz_ = 4;                // bytes per real on the device
  std::vector<double> wavelengths_nm_;
  Eigen::MatrixXd srf_;
  AreaWeights weights_;
  bool heights_set_ = false, psf_valid_ = false;
  bool field_valid_ = false;  // field_ holds the propagated field of the current heights (adjoints need it)
  mutable SamplingReport sampling_;
  mutable bool sampling_fresh_ = true;
  double sampling_z_m_ = 0;
  bool native_normalized_ = true;  // psf_ holds normalised values (else raw |U|², sums in sums_crop_)
  std::uint64_t psf_generation_ = 0;
  static constexpr std::size_t kGroupsPerBand = 32;
  bool host_fusion_ = true;
  bool keep_field_ = true;
  bool field_streamed_ = false;  // the last compute_psf() streamed its field (field_valid_ false for that reason)
  cl::Buffer field_ring_;                  // the streamed PSF's field: threads x M x M complex
  std::vector<cl::Buffer> chunk_k_, chunk_dn_;  // per chunk of the streamed PSF: its planes' k and dn
  std::size_t chunk_planes_ = 0;                // the planes per chunk those tables were made for
  std::unique_ptr<HostPropagator> host_prop_;
  std::vector<int> klim_host_;  // klim_ on the host (bands), for the host propagation

  cl::Buffer heights_, k_, dn_, field_, psf_, psf_s_, partial_, tf_, klim_, wstart_, wts_, srf_buf_;
  cl::Buffer energy3_;                              // per band: spectrum total, beyond limit, after TF (bands x 3)
  cl::Buffer sums_crop_, sums_sensor_;              // per-band sums (bands reals each)
  std::unique_ptr<Camera> camera_;

  cl::Kernel k_field_, k_tf_, k_tf_energy_, k_finalize3_, k_crop_sums_, k_sums_, k_finalize_, k_scale_, k_resample_,
      k_sensor_, k_expand_, k_quantize_, k_dot_, k_norm_vjp_, k_int_vjp_, k_phase_vjp_;
  // Adjoint state: transposed resampling weights, the back-propagation TF, gradient buffers.
  AreaWeights weights_t_;
  cl::Buffer wstart_t_, wts_t_, tf_back_, gfield_, dots_, dh_;
  Map2D sensor_vjp_in_scratch(cl::Buffer& g_sensor);
  cl::Buffer g_native_, g_sensor_;  // adjoint inputs (bands x N x N, bands x S x S), reused across calls
};

}  // namespace qdo
