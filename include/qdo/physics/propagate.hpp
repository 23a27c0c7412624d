// Free-space propagation of the DOE field to the sensor on the device (kernels/propagate.cl): the
// transfer functions (Fresnel, band-limited angular spectrum), the FFT plan, the transfer-function
// kernels with the sampling energies, and on CPU devices with the FFTW backend the fused host
// propagation (HostPropagator, host_propagator.hpp). The CPU reference is ref::propagate
// (cpu_reference.hpp).
//
// Field: planes x M x M complex (interleaved, the precision, row-major; planes = designs x points x
// bands, design-major then point-major, points = cfg.point_count(); M = PropagationGeometry::m), in place. Hinted propagations take the FieldStage
// layout (field.hpp: samples at [0, N)^2, zero elsewhere) and define only [0, N)^2 of the result;
// unhinted ones take any field in any layout and define the whole window.
#pragma once
#include <CL/opencl.hpp>

#include <cstddef>
#include <memory>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/runtime/fft.hpp"
#include "qdo/runtime/host_propagator.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/runtime/runtime.hpp"

namespace qdo {

class PropagationStage {
 public:
  // One per (configuration, precision, designs); the configuration is taken as valid. Uploads the
  // transfer function over cfg.sensor_distance_m and bakes what a hinted propagation over it uses
  // (the host propagator or the pruned FFT plan), so the first one is not charged for it.
  PropagationStage(Runtime& rt, const SystemConfig& cfg, Precision p, std::size_t designs = 1);
  ~PropagationStage();
  PropagationStage(const PropagationStage&) = delete;
  PropagationStage& operator=(const PropagationStage&) = delete;

  // The fused host propagation on CPU devices with the FFTW backend: on by default; off runs FFT
  // plan + transfer-function kernel, as on every other backend.
  void set_host_fusion(bool on) { host_fusion_ = on; }
  bool host_fusion() const { return host_fusion_; }
  // Whether a propagation with this hint runs fused on the host (HostPropagator): the FFT
  // backend is FFTW (CPU devices), the field is zero-padded (N < M) and fusion is on.
  bool host(bool hinted = true) const;
  // The host propagator of all planes (made on first use).
  HostPropagator& host_propagator();
  // The FFT plan of planes x M x M. The field's N x N samples are stored at window rows/cols
  // [0, N), i.e. the centred window of PropagationGeometry circularly shifted by -offset.
  // Propagation is a circular convolution, so it commutes with that shift: the propagated field's
  // crop is again [0, N). The zero rows and columns [N, M) then form one block per axis, which the
  // FFT's zero-padding hint prunes (hinted: FFTW skips the zero rows forward and the unread columns
  // inverse, VkFFT skips both).
  FftPlan& plan(bool hinted = true);
  // The transfer function over z_m (planes x M complex for Fresnel, planes x M x M for the angular
  // spectrum, as HostPropagator::Tf): the tables over +z and -z are kept, others made per call.
  cl::Buffer tf(double z_m);

  // In-place propagation of `field` over z_m. record_sampling: the per-plane energies for
  // sampling() are kept. With the host propagation (host(hinted)) and `intensity`/`crop_sums`
  // given, the crop's |U|² (planes x N x N reals) and its per-plane sums (planes reals) are written
  // too and true is returned; otherwise false (the caller computes them).
  bool run(cl::Buffer& field, double z_m, bool record_sampling, bool hinted = true, cl::Buffer* intensity = nullptr,
           cl::Buffer* crop_sums = nullptr);
  // Planes per chunk of the streamed PSF (run_planes on the host propagation): a multiple of the
  // host propagator's threads, at least 8, at most planes; QDO_STREAM_BANDS (an integer >= 1)
  // overrides it.
  std::size_t chunk_planes();
  // The hinted host propagation over cfg.sensor_distance_m of planes [first, first + count) held
  // in `field` (count x M x M complex, FieldStage::run_chunk's layout), recording their sampling
  // energies and writing their crop intensity and sums into `intensity` and `crop_sums` (laid out
  // for all planes): HostPropagator::run_planes, bit-identical per plane to run().
  void run_planes(cl::Buffer& field, std::size_t first, std::size_t count, cl::Buffer& intensity, cl::Buffer& crop_sums);
  // The host propagation over -cfg.sensor_distance_m of the PSF adjoint's input into gfield
  // (bands x M x M complex; [0, N)^2 defined): HostPropagator::run with `in` (host() only).
  void run_adjoint(cl::Buffer& gfield, const HostPropagator::IntensityAdjointInput& in);

  // The sampling report of the last propagation that recorded its energies (read back on first use
  // after it, a planes x 3 transfer). crop_sums: that propagation's per-plane crop sums of |U|²
  // (planes reals) for energy_outside_window, or null (0 then). Empty before any recording.
  const SamplingReport& sampling(const cl::Buffer* crop_sums) const;

 private:
  cl::Buffer make_tf(double z_m) const;

  Runtime& rt_;
  SystemConfig cfg_;
  Precision prec_;
  std::size_t nb_ = 0, rsz_ = 4;
  PropagationGeometry geom_;
  std::vector<double> wavelengths_nm_;  // per plane
  bool host_fusion_ = true;
  static constexpr std::size_t kGroupsPerBand = 32;
  cl::Kernel k_tf_, k_tf_energy_, k_finalize3_;
  cl::Buffer tf_, tf_back_;     // over +z and -z
  cl::Buffer klim_;             // per plane: the highest |frequency index| within the transfer function's limit (ints)
  std::vector<int> klim_host_;  // the same on the host, for the host propagation
  cl::Buffer partial_, energy3_;  // tf_energy partial sums (planes x groups x 3); per plane (spectrum total, beyond limit, after TF)
  std::unique_ptr<HostPropagator> host_prop_;
  mutable SamplingReport sampling_;
  mutable bool sampling_fresh_ = true;
  double sampling_z_m_ = 0;
};

}  // namespace qdo
