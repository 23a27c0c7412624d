// Linear MMSE (Wiener) decoder for the shift-invariant diffractive camera (REFERENCE §3b), its
// differentiable objectives with exact gradients with respect to the OTF and the PSF stack,
// and the reconstruction metrics of REFERENCE §4. CPU, double precision, FFTW + Eigen.
//
// Shapes: cubes X are bands x H x W (B x H x W), sensor images Y are channels x H x W
// (C x H x W, C = 3 for an RGB sensor), PSF stacks B x S x S with the optical axis at
// (S/2, S/2), OTF stacks complex B x H x W; all Stack<T> row-major (types.hpp).
// The sensor response `srf` is C x B (optics.hpp sensor_response(): rows sum to 1).
//
// Conventions (the same as ref::convolve(..., Circular) + ref::sensor_integrate):
//  - DFT: forward F[f] = Σ_r x[r] e^{-i2π(fy·y/H + fx·x/W)}, unnormalised; inverse 1/(H·W).
//  - wrap: PSF pixel (y, x) goes to grid index ((y - S/2) mod H, (x - S/2) mod W), summing
//    (folding) pixels that land on the same index when S > H or S > W.
//  - OTF_b = F[wrap(PSF_b)]; camera: Y_c(f) = Σ_b srf(c, b) OTF_b(f) X_b(f), i.e.
//    Y(f) = A(f) X(f) with A(f) = srf · diag(OTF(f)) ∈ C^{C×B}, plus white noise.
//  - Prior: P(f) = E[X(f) X(f)^H] / (H·W), real symmetric B x B, one per radial bin
//    (radial_bin()). It is the second moment (not centred): the scene mean lives in the DC
//    bin, P(DC) = C_pix + (H·W)·μμᵀ for a stationary scene with per-pixel covariance C_pix.
//    For spatially white scenes every other bin equals the per-pixel spectral covariance.
//  - Noise: noise_sigma is the standard deviation of i.i.d. per-pixel, per-channel noise in
//    the spatial domain (full-scale units). A DFT coefficient then has variance H·W·σ²;
//    since P is also divided by H·W, the filter uses σ² directly:
//        K(f) = P A^H (A P A^H + σ² I_C)⁻¹,   X̂(f) = K(f) Y(f),   x̂ = Re IDFT(X̂).
//  - All errors are "per pixel per band": sums over B·H·W elements (and scenes) divided by
//    B·H·W (and the scene count), i.e. directly comparable to the MSE / MAE of a cube.
//  - Gradients with respect to a complex array z are G = ∂L/∂Re z + i ∂L/∂Im z, so that
//    dL = Re Σ conj(G) dz. Every OTF entry is an independent variable (no Hermitian
//    symmetry is imposed); psf_gradient() chains G to a real PSF exactly.
#pragma once
#include <Eigen/Dense>

#include <cstddef>
#include <mutex>
#include <string>
#include <vector>

#include "qdo/decode/decoder.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

namespace wiener {

// Spectral second-moment prior, one real symmetric B x B matrix per radial frequency bin.
struct SpectralPrior {
  std::size_t bands = 0, bins = 0;  // B, number of radial bins (bin 0 = DC only)
  std::size_t rows = 0, cols = 0;   // H x W grid the prior was estimated on (DC scales with H·W)
  std::vector<double> cov;          // bins x B x B row-major: cov[(k * B + i) * B + j]

  // Bin k as a B x B matrix. Throws InputError if k >= bins.
  Eigen::MatrixXd bin(std::size_t k) const;
  // Throws InputError unless the sizes are consistent, bins >= 2 and every entry is finite.
  void validate() const;
};

// Radial bin of DFT index (ky, kx) on a rows x cols grid: 0 for DC; otherwise, with the signed
// frequencies in cycles/pixel νy = k̃y/rows, νx = k̃x/cols (k̃ = k or k − size, as numpy
// fftfreq) and ρ = sqrt(νy² + νx²) ∈ (0, 1/√2]: 1 + floor(ρ·√2 · (bins − 1)), capped at
// bins − 1. The edges do not depend on the grid size; f and −f always share a bin.
// Requires bins >= 2 and ky < rows, kx < cols (InputError).
std::size_t radial_bin(std::size_t ky, std::size_t kx, std::size_t rows, std::size_t cols, std::size_t bins);

// Estimates P per bin from training cubes (all B x H x W, same shape): the average over scenes
// and over the frequencies of a bin of X(f) X(f)^H / (H·W), real part (f and -f share a bin,
// so the imaginary parts cancel), symmetrised, plus a ridge 1e-9 · tr/B on the diagonal.
// A bin holding no frequency of the grid (possible on tiny or odd grids) stays zero; it is
// never used on that grid.
SpectralPrior estimate_prior(const std::vector<RealStack>& scenes, std::size_t bins);

// ---------------------------------------------------------------------------------------------
// Optics <-> OTF, exactly the wrap/fold of ref::convolve(..., Circular).

// psf: B x S x S (axis at S/2) -> OTF: complex B x rows x cols, OTF_b = F[wrap(psf_b)].
ComplexStack psf_to_otf(const RealStack& psf, std::size_t rows, std::size_t cols);
// Adjoint of psf_to_otf for real inner products (⟨a, b⟩ = Re Σ conj(a) b on complex arrays):
// grad_otf B x rows x cols -> B x psf_size x psf_size, wrapᵀ(Re(Σ_f G(f) e^{+i2π f·r})).
// Given G = ∂L/∂Re OTF + i ∂L/∂Im OTF it returns ∂L/∂PSF.
RealStack psf_gradient(const ComplexStack& grad_otf, std::size_t psf_size);

// Noiseless camera through an OTF: cube B x H x W, otf B x H x W, srf C x B -> C x H x W.
// Equals ref::sensor_integrate(ref::convolve(cube, psf, Circular), srf) for otf = psf_to_otf(psf).
RealStack simulate_measurement(const RealStack& cube, const ComplexStack& otf, const Eigen::MatrixXd& srf);

// ---------------------------------------------------------------------------------------------
// Decoding.

// y: C x H x W (noisy sensor image) -> B x H x W, X̂(f) = K(f) Y(f), real part of the IDFT.
// otf B x H x W, srf C x B, prior on the same H x W grid, noise_sigma >= 0 (σ = 0 requires
// A P A^H invertible at every frequency; otherwise qdo::Error).
RealStack decode(const RealStack& y, const ComplexStack& otf, const Eigen::MatrixXd& srf, const SpectralPrior& prior,
                 double noise_sigma);

// The result of a search for sigma over a log-spaced grid (gcv_noise_sigma, ml_noise_sigma).
struct SigmaSearch {
  double sigma = 0;                    // the best sigma
  std::vector<double> sigmas, scores;  // the grid and the criterion on it (GCV over its minimum; -log L less its minimum)
  bool at_edge = false;                // the grid's best is its first or last point
};
// The noise sigma the data ask for, by generalised cross-validation (Golub, Heath and Wahba 1979):
// for the Wiener filter at sigma, the influence matrix at frequency f is T(f) = M (M + sigma^2 I)^-1
// with M = A P A^H (C x C), and GCV(sigma) = N |(I - T) Y|^2 / tr(I - T)^2 over every frequency of
// every image (N = C H W x images), the score of predicting each measurement from the others.
// With C < B the filter fits every measurement exactly as sigma -> 0, so on real captures (3
// channels, 31 bands) it runs to the bottom of its range (EXPERIMENTS.md); it works where the model
// holds and the noise is white (tests/test_wiener_sigma.cpp). ys: C x H x W images on the OTF's
// grid; the minimum over `points` log-spaced values in [sigma_min, sigma_max] (> 0), refined by a
// parabola through the lowest and its neighbours in log sigma. Eigen-decomposes M once per
// frequency, so the grid costs little. InputError on shapes or a bad range.
SigmaSearch gcv_noise_sigma(const std::vector<RealStack>& ys, const ComplexStack& otf, const Eigen::MatrixXd& srf,
                            const SpectralPrior& prior, double sigma_min = 1e-4, double sigma_max = 1.0, std::size_t points = 49);
// The same search for the sigma of largest marginal likelihood under the decoder's own model
// (empirical Bayes): Y(f) ~ CN(0, H W (A P A^H + sigma^2 I)), -log L = sum_f sum_k log(l_k +
// sigma^2) + |z_k|^2 / (H W (l_k + sigma^2)) with l_k, z_k the eigenvalues of A P A^H and Y(f) in
// its eigenvectors. Power the prior does not predict (model error, non-white noise) raises sigma.
// scores: -log L less its minimum.
SigmaSearch ml_noise_sigma(const std::vector<RealStack>& ys, const ComplexStack& otf, const Eigen::MatrixXd& srf,
                           const SpectralPrior& prior, double sigma_min = 1e-4, double sigma_max = 1.0, std::size_t points = 49);

// The paper's "DO" mismatch: the scene (B x H x W) is imaged noiselessly through otf_actual and
// decoded by the Wiener filter built for otf_design (noise_sigma only enters the filter).
// Returns the B x H x W estimate. With otf_actual == otf_design it is the matched decode.
RealStack decode_mismatched(const RealStack& scene, const ComplexStack& otf_actual, const ComplexStack& otf_design,
                            const Eigen::MatrixXd& srf, const SpectralPrior& prior, double noise_sigma);

// Expected per-pixel-per-band MSE, under the prior and noise σ, of the filter designed for
// otf_design applied to measurements through otf_actual:
// 1/(B·H·W) Σ_f tr((K A_act − I) P (K A_act − I)^H + σ² K K^H). Equals expected error when equal.
double expected_error_mismatched(const ComplexStack& otf_actual, const ComplexStack& otf_design,
                                 const Eigen::MatrixXd& srf, const SpectralPrior& prior, double noise_sigma);

// ---------------------------------------------------------------------------------------------
// Objectives and gradients.
enum class Loss {
  Expected,  // 1/(B·H·W) Σ_f tr(P − P A^H (A P A^H + σ² I)⁻¹ A P): expected MSE per pixel per band
             // under the prior, noise included; needs no scenes.
  Mse,       // empirical MSE over scenes, Y = camera(X) noiseless through the same OTF, decoded
             // with the σ-regularised filter. Evaluated by Parseval in the DFT domain:
             // 1/(N·B·(H·W)²) Σ_s Σ_f ‖(K A − I) X_s(f)‖², equal to the spatial MSE of x̂ when the
             // OTF is the DFT of a real PSF (for other OTFs it counts the imaginary part too).
  Mae,       // empirical MAE 1/(N·B·H·W) Σ |Re IDFT((K A − I) X_s)|, same setting; sign(0) = 0.
};

struct OtfObjective {
  double value = 0;
  ComplexStack grad_otf;  // B x H x W, ∂L/∂Re OTF + i ∂L/∂Im OTF
};
struct PsfObjective {
  double value = 0;
  RealStack grad_psf;  // B x S x S, ∂L/∂PSF
};

// otf: B x H x W; srf: C x B; prior on H x W; noise_sigma >= 0; scenes (B x H x W each, at
// least one) are needed by Mse and Mae and ignored by Expected.
OtfObjective objective(Loss loss, const ComplexStack& otf, const Eigen::MatrixXd& srf, const SpectralPrior& prior,
                       double noise_sigma, const std::vector<RealStack>& scenes = {});
// The same as a function of a PSF stack psf (B x S x S) on the prior's H x W grid:
// otf = psf_to_otf(psf, H, W), grad_psf = psf_gradient(grad_otf, S).
PsfObjective objective_psf(Loss loss, const RealStack& psf, const Eigen::MatrixXd& srf, const SpectralPrior& prior,
                           double noise_sigma, const std::vector<RealStack>& scenes = {});

}  // namespace wiener

// The Wiener decoder behind the Decoder interface (decoder.hpp; holds copies of its inputs).
class WienerDecoder final : public Decoder {
 public:
  // otf B x H x W, srf C x B, prior on H x W, noise_sigma >= 0: validated here (InputError).
  WienerDecoder(ComplexStack otf, Eigen::MatrixXd srf, wiener::SpectralPrior prior, double noise_sigma);
  RealStack decode(const RealStack& y) const override;  // C x H x W -> B x H x W
  std::size_t bands() const override { return otf_.planes; }
  std::size_t channels() const override { return static_cast<std::size_t>(srf_.rows()); }
  std::string description() const override { return "Wiener decoder"; }
  double noise_sigma() const { return noise_sigma_; }
  // The largest filter decode() keeps between calls (bytes; see decode()).
  static constexpr std::size_t kFilterCacheBytes = std::size_t(256) << 20;
  const ComplexStack& otf() const { return otf_; }

 private:
  ComplexStack otf_;
  Eigen::MatrixXd srf_;
  wiener::SpectralPrior prior_;
  double noise_sigma_;
  // The filter Kh (H·W x C x B), made on the first decode (decode() is const and may run on
  // several threads: once_flag).
  mutable std::vector<cdouble> filter_;
  mutable std::once_flag filter_once_;
};

// ---------------------------------------------------------------------------------------------
// Metrics (REFERENCE §4). estimate and truth are cubes of the same shape B x H x W; values
// are in full-scale units (data range 1).
namespace metrics {

// Mean of (estimate − truth)² over all B·H·W elements.
double mse(const RealStack& estimate, const RealStack& truth);
// Whole-cube PSNR with peak 1 (release psnr_metric): 10·log10(1 / mse). +inf when mse = 0.
double psnr(const RealStack& estimate, const RealStack& truth);
// "PSNR-H" (release psnr_hyper_metric): per band 10·log10(max_b(truth)² / mse_b), averaged
// over bands. A band with mse_b = 0 contributes +inf.
double psnr_hyper(const RealStack& estimate, const RealStack& truth);
// MST-style: per band with peak 1, averaged over bands.
double psnr_per_band(const RealStack& estimate, const RealStack& truth);
// Whole-cube RMSE: sqrt(mse).
double rmse(const RealStack& estimate, const RealStack& truth);
// ERGAS with ratio 1: 100·sqrt(mean_b mse_b / μ_b²), μ_b = mean of truth band b (must be ≠ 0).
double ergas(const RealStack& estimate, const RealStack& truth);
// SAM in radians: mean over every pixel of acos(⟨x̂, x⟩ / (‖x̂‖‖x‖)) (cosine clamped to [−1, 1]).
// Zero spectra, where the angle is undefined: between a zero and a non-zero spectrum it is
// π/2 (a zero vector is orthogonal to every vector, and the reconstruction carries no spectral
// information), between two zero spectra 0 (they agree). Every pixel counts: an all-zero
// reconstruction of a non-zero scene scores π/2, not a perfect 0 (pixels used to be skipped).
double sam(const RealStack& estimate, const RealStack& truth);
// SSIM as tf.image.ssim (the release): per band, Gaussian window 11 x 11 with σ = 1.5
// (normalised to sum 1), "valid" positions only (H, W >= 11), K1 = 0.01, K2 = 0.03, data
// range 1, biased local variances; mean over positions, then over bands.
double ssim(const RealStack& estimate, const RealStack& truth);

}  // namespace metrics
}  // namespace qdo
