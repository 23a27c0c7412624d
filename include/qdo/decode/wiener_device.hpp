// The Wiener expected-error objective (wiener::Loss::Expected) and its exact gradient with respect
// to the PSF stack, on the OpenCL device (kernels/wiener.cl). The CPU reference, in double, is
// wiener::objective_psf(Loss::Expected, ...) (include/qdo/decode/wiener.hpp), whose conventions this
// follows exactly; tests/test_wiener_device.cpp compares the two and runs the adjoint ladder.
//
// Work: the PSF stack is wrapped onto the prior's H x W grid two bands per complex plane, one
// batched forward FFT gives every OTF, one kernel evaluates per frequency the C x C solve, tr E
// and the OTF gradient, one inverse FFT and a gather give dL/dPSF. Only the half spectrum
// kx <= W/2 is evaluated (the OTF of a real PSF is Hermitian, the prior is symmetric in f).
//
// Precision: F64 is double throughout. F32 keeps the OTFs, A P and the B x B products in float;
// on devices with cl_khr_fp64 (unless acc64 = false) the C x C matrices, the Cholesky solve,
// the value and the gradient's sums are double ("float32 with float64 accumulation").
#pragma once
#include <CL/opencl.hpp>

#include <Eigen/Dense>

#include <cstddef>
#include <vector>

#include "qdo/runtime/runtime.hpp"
#include "qdo/runtime/types.hpp"
#include "qdo/decode/wiener.hpp"

namespace qdo {
namespace wiener {

class DeviceObjective {
 public:
  // srf: C x B (1 <= C <= 4), prior: B bands on its H x W grid (validated), noise_sigma >= 0,
  // psf_size S >= 1: the PSF stacks passed later are B x S x S. Throws InputError naming the
  // argument; DeviceError when p is F64 on a device without double.
  DeviceObjective(Runtime& rt, Precision p, const Eigen::MatrixXd& srf, const SpectralPrior& prior,
                  double noise_sigma, std::size_t psf_size, bool acc64 = true);
  DeviceObjective(const DeviceObjective&) = delete;
  DeviceObjective& operator=(const DeviceObjective&) = delete;

  // psf: B x S x S (host, double) -> value and grad_psf (B x S x S), the same quantities as
  // objective_psf(Loss::Expected, psf, srf, prior, noise_sigma). Non-finite PSF entries are an
  // InputError; a singular filter (noise_sigma = 0) is a qdo::Error naming the DFT index, as on
  // the CPU.
  PsfObjective expected(const RealStack& psf);
  // Device-resident form: psf and grad_psf hold B x S x S reals of precision() (row-major); the
  // gradient is written to grad_psf, the value returned (blocking on its read-back).
  double expected(const cl::Buffer& psf, cl::Buffer& grad_psf);

  Precision precision() const { return prec_; }
  bool acc64() const { return acc64_; }
  std::size_t bands() const { return bands_; }
  std::size_t psf_size() const { return s_; }

 private:
  Runtime& rt_;
  Precision prec_;
  bool acc64_;
  std::size_t bands_, channels_, rows_, cols_, s_, pairs_, half_;
  double sigma2_;
  cl::Kernel k_place_, k_expected_, k_gather_;
  cl::Buffer prior_, factor_, srf_, bin_of_, z_, g_, value_, psf_, grad_;
  std::vector<double> values_;
};

}  // namespace wiener
}  // namespace qdo
