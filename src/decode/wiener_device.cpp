// The Wiener expected-error objective on the device: see include/qdo/decode/wiener_device.hpp and
// kernels/wiener.cl.
#include "qdo/decode/wiener_device.hpp"

#include <cmath>
#include <string>
#include <vector>

#include "qdo/runtime/error.hpp"
#include "qdo/runtime/fft.hpp"

namespace qdo {
namespace wiener {

namespace {
constexpr std::size_t kMaxChannels = 4;  // private C x C and C x B arrays per work item

// Per bin a lower-triangular F with F Fᵀ = P (bins x B x B, row-major), in double, for every
// symmetric positive semidefinite P (a bin holding no frequency is all zero): F0 = V sqrt(Λ⁺)
// from the eigen-decomposition (eigenvalues below zero, round-off, clamped), then the QR
// F0ᵀ = Q R gives F = Rᵀ (F Fᵀ = F0 F0ᵀ). A plain Cholesky would fail on semidefinite bins.
std::vector<double> prior_factors(const SpectralPrior& prior) {
  const std::size_t nb = prior.bands;
  std::vector<double> out(prior.cov.size(), 0.0);
  for (std::size_t k = 0; k < prior.bins; ++k) {
    const Eigen::MatrixXd p = prior.bin(k);
    const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(0.5 * (p + p.transpose()));
    const Eigen::MatrixXd f0 = eig.eigenvectors() * eig.eigenvalues().cwiseMax(0.0).cwiseSqrt().asDiagonal();
    const Eigen::MatrixXd r = Eigen::HouseholderQR<Eigen::MatrixXd>(f0.transpose()).matrixQR().triangularView<Eigen::Upper>();
    for (std::size_t i = 0; i < nb; ++i)
      for (std::size_t j = 0; j <= i; ++j) out[(k * nb + i) * nb + j] = r(static_cast<Eigen::Index>(j), static_cast<Eigen::Index>(i));
  }
  return out;
}
}  // namespace

DeviceObjective::DeviceObjective(Runtime& rt, Precision p, const Eigen::MatrixXd& srf, const SpectralPrior& prior,
                                 double noise_sigma, std::size_t psf_size, bool acc64)
    : rt_(rt), prec_(p), acc64_(p == Precision::F64 || (acc64 && rt.has_fp64())) {
  prior.validate();
  if (!(noise_sigma >= 0) || !std::isfinite(noise_sigma)) reject("noise_sigma", noise_sigma, ">= 0 and finite");
  if (srf.rows() < 1 || static_cast<std::size_t>(srf.rows()) > kMaxChannels)
    reject("srf rows (channels)", srf.rows(), "1 ... " + to_str(kMaxChannels));
  if (static_cast<std::size_t>(srf.cols()) != prior.bands)
    reject("srf", to_str(srf.rows()) + " x " + to_str(srf.cols()), "C x B with B = " + to_str(prior.bands) + " (the prior's bands)");
  if (!srf.allFinite()) reject("srf", "non-finite entries", "finite values");
  if (psf_size < 1) reject("psf_size", psf_size, ">= 1");
  rt_.require(p);
  bands_ = prior.bands;
  channels_ = static_cast<std::size_t>(srf.rows());
  rows_ = prior.rows;
  cols_ = prior.cols;
  s_ = psf_size;
  pairs_ = (bands_ + 1) / 2;
  half_ = rows_ * (cols_ / 2 + 1);
  sigma2_ = noise_sigma * noise_sigma;

  const std::string opts = "-DNB=" + to_str(bands_) + " -DNC=" + to_str(channels_) + " -DQDO_ACC64=" + (acc64_ ? "1" : "0");
  k_place_ = rt_.kernel("wiener.cl", "wiener_place_pairs", p, opts);
  k_expected_ = rt_.kernel("wiener.cl", "wiener_expected", p, opts);
  k_gather_ = rt_.kernel("wiener.cl", "wiener_gather_grad", p, opts);

  const cl::Context& ctx = rt_.context();
  const std::size_t rsz = real_size(p);
  std::vector<double> srf_rm(channels_ * bands_);
  for (std::size_t c = 0; c < channels_; ++c)
    for (std::size_t b = 0; b < bands_; ++b)
      srf_rm[c * bands_ + b] = srf(static_cast<Eigen::Index>(c), static_cast<Eigen::Index>(b));
  prior_ = cl::Buffer(ctx, CL_MEM_READ_ONLY, prior.cov.size() * rsz);
  factor_ = cl::Buffer(ctx, CL_MEM_READ_ONLY, prior.cov.size() * rsz);
  const std::vector<double> factors = prior_factors(prior);
  rt_.write_reals(factor_, factors.data(), factors.size(), p);
  srf_ = cl::Buffer(ctx, CL_MEM_READ_ONLY, srf_rm.size() * rsz);
  rt_.write_reals(prior_, prior.cov.data(), prior.cov.size(), p);
  rt_.write_reals(srf_, srf_rm.data(), srf_rm.size(), p);
  std::vector<int> bins(half_);
  for (std::size_t ky = 0; ky < rows_; ++ky)
    for (std::size_t kx = 0; kx <= cols_ / 2; ++kx)
      bins[ky * (cols_ / 2 + 1) + kx] = static_cast<int>(radial_bin(ky, kx, rows_, cols_, prior.bins));
  bin_of_ = cl::Buffer(ctx, CL_MEM_READ_ONLY | CL_MEM_COPY_HOST_PTR, bins.size() * sizeof(int), bins.data());
  const std::size_t spec_bytes = pairs_ * rows_ * cols_ * 2 * rsz;
  z_ = cl::Buffer(ctx, CL_MEM_READ_WRITE, spec_bytes);
  g_ = cl::Buffer(ctx, CL_MEM_READ_WRITE, spec_bytes);
  value_ = cl::Buffer(ctx, CL_MEM_WRITE_ONLY, half_ * (acc64_ ? sizeof(double) : sizeof(float)));
  values_.resize(half_);
  rt_.fft(rows_, cols_, pairs_, p);  // bake the plan now, not inside the first evaluation
}

double DeviceObjective::expected(const cl::Buffer& psf, cl::Buffer& grad_psf) {
  const std::size_t rsz = real_size(prec_), stack = bands_ * s_ * s_;
  if (psf.getInfo<CL_MEM_SIZE>() < stack * rsz)
    reject("psf buffer", to_str(psf.getInfo<CL_MEM_SIZE>()) + " bytes", ">= " + to_str(stack * rsz) + " (B x S x S reals)");
  if (grad_psf.getInfo<CL_MEM_SIZE>() < stack * rsz)
    reject("grad_psf buffer", to_str(grad_psf.getInfo<CL_MEM_SIZE>()) + " bytes",
           ">= " + to_str(stack * rsz) + " (B x S x S reals)");
  const int s = static_cast<int>(s_), h = static_cast<int>(rows_), w = static_cast<int>(cols_);
  Runtime::launch_1d(rt_.queue(), k_place_, pairs_ * rows_ * cols_, prec_, psf, z_, s, h, w);
  FftPlan& plan = rt_.fft(rows_, cols_, pairs_, prec_);
  plan.forward(z_);
  // c = 1 / (H·W·B); the inverse transform divides by H·W, so the kernel scales by −2c·H·W.
  const double n = double(rows_) * double(cols_);
  Runtime::launch_1d(rt_.queue(), k_expected_, half_, prec_, z_, prior_, factor_, srf_, bin_of_, g_, value_, h, w,
                     Real{sigma2_}, Real{-2.0 / double(bands_)});
  plan.inverse(g_);
  Runtime::launch_1d(rt_.queue(), k_gather_, stack, prec_, g_, grad_psf, s, h, w, Real{1.0});
  rt_.read_reals(value_, values_.data(), half_, acc64_ ? Precision::F64 : Precision::F32);
  double acc = 0;
  for (std::size_t i = 0; i < half_; ++i) {
    if (!std::isfinite(values_[i])) {
      const std::size_t wh = cols_ / 2 + 1;
      throw Error("Wiener filter (device): A P A^H + sigma^2 I is singular or not positive definite at DFT index (" +
                  to_str(i / wh) + ", " + to_str(i % wh) + "); use noise_sigma > 0 or an OTF without zeros there" +
                  (acc64_ ? std::string()
                          : std::string(" (float32 accumulation: sigma^2 may be below float32's resolution of M there; "
                                        "use a device with float64 or the CPU objective, --wiener-on cpu)")));
    }
    acc += values_[i];
  }
  return acc / (n * double(bands_));
}

PsfObjective DeviceObjective::expected(const RealStack& psf) {
  if (psf.planes != bands_ || psf.rows != s_ || psf.cols != s_)
    reject("psf", shape(psf), "B x S x S = " + shape(bands_, s_, s_) + " (the objective's bands and psf_size)");
  for (double v : psf.data)
    if (!std::isfinite(v)) reject("psf", "non-finite entries", "finite values");
  const std::size_t rsz = real_size(prec_), stack = bands_ * s_ * s_;
  if (!psf_()) {
    psf_ = cl::Buffer(rt_.context(), CL_MEM_READ_ONLY, stack * rsz);
    grad_ = cl::Buffer(rt_.context(), CL_MEM_READ_WRITE, stack * rsz);
  }
  rt_.write_reals(psf_, psf.data.data(), stack, prec_);
  PsfObjective out;
  out.value = expected(psf_, grad_);
  out.grad_psf = RealStack(bands_, s_, s_);
  rt_.read_reals(grad_, out.grad_psf.data.data(), stack, prec_);
  return out;
}

}  // namespace wiener
}  // namespace qdo
