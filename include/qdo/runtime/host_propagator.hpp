// The fused host propagation of CPU devices (HostPropagator below; src/runtime/propagate_fftw.cpp).
#pragma once
#include <CL/opencl.hpp>

#include <cstddef>
#include <memory>

#include "qdo/runtime/runtime.hpp"

namespace qdo {

// Fused, pruned propagation on a CPU device's own buffers (FFTW, src/runtime/propagate_fftw.cpp),
// used by PropagationStage (propagate.hpp) when the FFT backend is FFTW and the field is zero-padded.
// One call propagates `planes` fields of M x M complex values (interleaved, the precision given
// at construction, row-major, plane b at complex offset b * M * M) whose samples sit in
// [0, N)^2 (rows and columns >= N of the input are never read), by one transfer function per plane:
//   1. each of the N data rows: copied with zeros beyond column N, transformed (length M);
//   2. per block of columns: the N data rows gathered (zeros below), column transform, the
//      transfer function, its sampling energies and the 1/M² scale, inverse column transform,
//      rows [0, N) scattered back;
//   3. each of the N data rows: inverse transform, columns [0, N) written back, and the crop's
//      intensity |U|² and its sum when asked for.
// 2-D circular propagation of the padded field restricted to the [0, N)^2 crop, with 5/6 of the
// 1-D transforms of an unpruned 2-D pair at N = 2M/3 and the column passes cache-resident; planes run
// in parallel on the device's compute units. Output: field rows [0, N), columns [0, N) hold the
// propagated samples; the rest of the plane is scratch (undefined).
class HostPropagator {
 public:
  virtual ~HostPropagator() = default;
  HostPropagator(const HostPropagator&) = delete;
  HostPropagator& operator=(const HostPropagator&) = delete;

  // The transfer function as PropagationStage keeps it: `separable` (Fresnel): planes x M table t with
  // TF(ky, kx) = t[ky] t[kx]; otherwise planes x M x M (FFT order on both axes).
  struct Tf {
    const cl::Buffer* table = nullptr;
    bool separable = true;
  };
  // Optional outputs (null: not computed).
  struct Outputs {
    // Sampling energies per plane, as the tf_energy_* kernels and finalize_sums3 give them:
    // energy3 (planes x 3 reals) = (Σ|spec|², the part with |f| index > klim[b] on either axis,
    // Σ|spec · TF|² unscaled); klim: planes integers, host memory.
    cl::Buffer* energy3 = nullptr;
    const int* klim = nullptr;
    // The crop's intensity |U|² (planes x N x N reals) and its per-plane sums (planes reals).
    cl::Buffer* intensity = nullptr;
    cl::Buffer* crop_sums = nullptr;
  };
  // Optional input in place of the field's own [0, N)^2 block (the PSF adjoint of Simulator::psf_sensor_vjp):
  // row y of plane b becomes, for x < N,
  //   2 · (A g A^T)[y][x] · U[b][y][x],   (A g A^T)[y][x] = Σ_ty Σ_tx w[y][ty] w[x][tx] g[b][start[y] + ty][start[x] + tx]
  // i.e. the transposed area resampling of the sensor-grid gradient g (planes x S x S reals; taps
  // outside [0, S) have weight 0 and are read clamped) followed by the vector-Jacobian product of
  // |U|² with U the forward's propagated field (planes x M x M complex, crop [0, N)^2). start: N
  // ints; w: N x taps reals (AreaWeights::transposed()); with col_offset = N the columns read
  // start[N + x] and w[(N + x) x taps ..] (tables of 2 N rows: a different shift per axis).
  // With y_sensor and sensor_sums (planes x S x S and planes reals) g is first taken through the
  // vector-Jacobian product of the per-plane normalisation y = x / Σx:
  //   g <- (g - <g, y>) / Σx   (0 where Σx <= 0).
  struct IntensityAdjointInput {
    const cl::Buffer* g_sensor = nullptr;
    const cl::Buffer* u = nullptr;
    std::size_t s = 0, taps = 0, col_offset = 0;
    const int* start = nullptr;
    const double* w = nullptr;
    const cl::Buffer* y_sensor = nullptr;
    const cl::Buffer* sensor_sums = nullptr;
  };
  // Blocks until done (the queue is finished first: the buffers are mapped); one call at a time
  // per object (its per-thread arrays are members; separate objects may run concurrently). field must hold
  // planes x M x M complex values; the tables as above. With `in`, field's contents are not
  // read (only written).
  virtual void run(cl::Buffer& field, const Tf& tf, const Outputs& out, const IntensityAdjointInput* in) = 0;
  void run(cl::Buffer& field, const Tf& tf, const Outputs& out) { run(field, tf, out, nullptr); }
  // Forward only, planes [first, first + count) of the planes given at construction, with
  // `field` holding just those planes (count x M x M complex, plane first + i at complex offset
  // i * M * M): the streamed PSF of Simulator::set_keep_field(false), which reuses one small field
  // buffer for all planes. The transfer-function table and the outputs are indexed by the global
  // plane as in run(); outputs of other planes are left as they are. The same arithmetic as run(),
  // so each plane's results are bit-identical to it. InputError unless first + count <= planes.
  virtual void run_planes(cl::Buffer& field, std::size_t first, std::size_t count, const Tf& tf, const Outputs& out) = 0;
  // How many planes run at once (one per thread): the natural `count` for run_planes.
  virtual std::size_t threads() const = 0;

  std::size_t m() const { return m_; }
  std::size_t n() const { return n_; }
  std::size_t planes() const { return planes_; }
  Precision precision() const { return precision_; }
  double bake_seconds() const { return bake_seconds_; }  // FFTW planning (wisdom makes it ~0)

 protected:
  HostPropagator(std::size_t m, std::size_t n, std::size_t planes, Precision p)
      : m_(m), n_(n), planes_(planes), precision_(p) {}
  std::size_t m_, n_, planes_;
  Precision precision_;
  double bake_seconds_ = 0;
};

// A HostPropagator for rt's device; DeviceError unless the device is a CPU; InputError unless
// 0 < n < m and planes >= 1.
std::unique_ptr<HostPropagator> make_host_propagator(Runtime& rt, std::size_t m, std::size_t n, std::size_t planes,
                                                     Precision p);

}  // namespace qdo
