// The "other encoders" of Table 3 (REFERENCE §5) with the same decoder family as the DOE camera
// (linear MMSE under the Gaussian scene prior of wiener.hpp):
//  - a Fresnel lens: a wrapped diffractive lens quantized to L levels; its PSFs come from the
//    Simulator and it is decoded with the WienerDecoder, exactly like a DOE design;
//  - single-disperser CASSI: random binary coded aperture, an integer lateral shift per band and
//    a detector; it is not shift-invariant, so it is decoded by conjugate gradients on the same
//    prior-regularised objective (CgDecoder, alias CassiDecoder);
//  - an Encoder interface (noiseless linear measurement and its exact adjoint) implemented by
//    CASSI and by the DOE camera (DoeEncoder, an OTF + SRF), and evaluate_encoder(), which runs
//    any (Encoder, Decoder) pair over test cubes with the metrics of `qdo eval`.
//
// Shapes (all Stack<T> row-major, types.hpp): cubes B x H x W; sensor images C x H x W' (W' = W
// for the DOE camera, W + (B − 1)·shift for CASSI); masks H x W; OTFs complex B x H x W; the
// sensor / detector response C x B.
//
// The objective (MAP = posterior mean for the Gaussian model; the same for every encoder):
//     x̂ = argmin_x ‖A x − y‖² / σ² + xᵀ C⁻¹ x,   i.e.   (AᵀA/σ² + C⁻¹) x̂ = Aᵀ y / σ²,
// σ the per-pixel spatial noise standard deviation, C the B·H·W x B·H·W covariance of a
// zero-mean stationary Gaussian scene whose DFT has E[X(f) X(f)^H] = H·W·P(f) (P from
// wiener::SpectralPrior, which is divided by H·W). As in the WienerDecoder, the second moment P
// (not centred) is used as the covariance of a zero-mean Gaussian. Derivation of the scaling:
// with the unitary DFT U = F/√(HW) (F the unnormalised DFT of wiener.hpp), U x has covariance
// P(f) at frequency f, so
//     C^p x = U^H P^p U x = F⁻¹ [P(f)^p X(f)]  (F⁻¹ with its 1/(H·W)),   xᵀ C⁻¹ x = Σ_f X^H (H·W·P(f))⁻¹ X,
// i.e. the operator C^p multiplies each DFT coefficient by P(bin f)^p (no extra H·W factor), and
// the quadratic form weights |X(f)|² by (H·W·P)⁻¹. For a shift-invariant camera A(f) = srf ·
// diag(OTF(f)), Parseval gives ‖A x − y‖² = Σ_f ‖A(f) X(f) − Y(f)‖² / (H·W), so per frequency
// the normal equations read (A^H A/σ² + P⁻¹) X = A^H Y/σ², whose solution is
// X = P A^H (A P A^H + σ² I)⁻¹ Y: exactly the WienerDecoder (tested to 1e-6).
//
// Solver: C may be badly conditioned (estimate_prior's ridge is 1e-9·tr/B), so C⁻¹ is never
// applied. CG runs on the whitened variable z, x = C^{1/2} z (C^{1/2} per bin from a symmetric
// eigendecomposition, negative eigenvalues clamped to 0), multiplied through by σ²:
//     G z = b,   G = C^{1/2} AᵀA C^{1/2} + σ² I,   b = C^{1/2} Aᵀ y,
// which is the symmetrically preconditioned form of the system above (G = σ² C^{1/2} K C^{1/2}),
// has eigenvalues in [σ², σ² + ‖A‖² λ_max(C)], needs no P⁻¹ and allows σ = 0 (then CG from
// z = 0 returns the minimum-‖z‖ solution of the consistent semi-definite system, the σ → 0
// limit). Reported residual: ‖b − G z‖ / ‖b‖ (0 when b = 0).
#pragma once
#include <Eigen/Dense>

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/decode/decoder.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/runtime/types.hpp"
#include "qdo/decode/wiener.hpp"

namespace qdo {

// ---------------------------------------------------------------------------------------------
// Fresnel lens.

// lens_design(cfg, design_wavelength_nm) (N x N heights, metres) quantized to `levels` levels;
// levels = 0 returns the full-precision lens. The quantizer's range is the lens's own 2π relief
// at the design wavelength, h_2π = λ_d / (n(λ_d) − 1) (= cfg.h_max_m() when λ_d equals
// cfg.base_wavelength_nm): heights become h_2π · Q(H / h_2π) with Quantizer{levels, placement},
// so Wrapped gives the textbook L-level kinoform (phases 2πk/L, efficiency sinc²(1/L)) at any
// design wavelength; Inclusive puts levels at 2πk/(L−1) (the top level is 2π ≡ 0 at λ_d).
// levels must be 0 or in [2, 65536] (InputError).
Map2D fresnel_lens_heights(const SystemConfig& cfg, double design_wavelength_nm, int levels,
                           Placement placement = Placement::Wrapped);

// ---------------------------------------------------------------------------------------------
// Encoders: noiseless linear measurement y = A x and its exact adjoint (⟨A x, y⟩ = ⟨x, Aᵀ y⟩).
class Encoder {
 public:
  virtual ~Encoder() = default;
  // x: bands() x rows() x cols() -> channels() x rows() x out_cols(), noiseless.
  virtual RealStack measure(const RealStack& x) const = 0;
  // y: channels() x rows() x out_cols() -> bands() x rows() x cols().
  virtual RealStack adjoint(const RealStack& y) const = 0;
  virtual std::size_t bands() const = 0;
  virtual std::size_t channels() const = 0;
  virtual std::size_t rows() const = 0;      // scene (and sensor) height H
  virtual std::size_t cols() const = 0;      // scene width W
  virtual std::size_t out_cols() const = 0;  // sensor width W'
};

// An H x W binary mask (values 0 / 1), pixel i open when a counter-based uniform draw
// (Philox, key = seed, counter = i; identical on every platform) is below fill_factor.
// fill_factor in [0, 1] (InputError).
Map2D random_binary_mask(std::size_t rows, std::size_t cols, double fill_factor, std::uint64_t seed);

// Single-disperser CASSI: y_c(r, x + s·b) += resp(c, b) · M(r, x) · X_b(r, x), i.e. the coded
// cube's band b is shifted right by s·b pixels (s = shift_px_per_band, an integer >= 0) onto a
// detector of W' = W + (B − 1)·s columns and integrated with the response.
// Response: C x B, non-negative. Default (an empty matrix): a monochrome detector (C = 1) with
// weights 1/B — the band sum scaled like sensor_response()'s rows-sum-to-1 normalisation, so a
// flat unit spectrum through an open mask pixel reads 1 and a given noise σ means the same SNR
// as for the DOE camera (the MAP estimate only depends on the ratio of A's scale to σ). Pass
// sensor_response(cfg) for an RGB detector, or a 1 x B row of ones for the plain band sum.
class CassiEncoder final : public Encoder {
 public:
  // mask H x W (any real values; normally random_binary_mask(H, W, 0.5, seed)), bands >= 1.
  CassiEncoder(Map2D mask, std::size_t bands, std::size_t shift_px_per_band, Eigen::MatrixXd response = {});
  RealStack measure(const RealStack& x) const override;  // B x H x W -> C x H x W'
  RealStack adjoint(const RealStack& y) const override;  // C x H x W' -> B x H x W
  std::size_t bands() const override { return bands_; }
  std::size_t channels() const override { return static_cast<std::size_t>(response_.rows()); }
  std::size_t rows() const override { return mask_.rows; }
  std::size_t cols() const override { return mask_.cols; }
  std::size_t out_cols() const override { return mask_.cols + (bands_ - 1) * shift_; }
  const Map2D& mask() const { return mask_; }
  const Eigen::MatrixXd& response() const { return response_; }
  std::size_t shift_px_per_band() const { return shift_; }

 private:
  Map2D mask_;
  std::size_t bands_, shift_;
  Eigen::MatrixXd response_;
};

// The shift-invariant DOE (or Fresnel lens) camera: wiener::simulate_measurement (circular
// per-band convolution through the OTF, then the C x B srf). Adjoint: Re F⁻¹[conj(OTF_b) ·
// Σ_c srf(c, b) Y_c]. otf: complex B x H x W (wiener::psf_to_otf of the sensor PSF stack).
class DoeEncoder final : public Encoder {
 public:
  DoeEncoder(ComplexStack otf, Eigen::MatrixXd srf);
  RealStack measure(const RealStack& x) const override;  // B x H x W -> C x H x W
  RealStack adjoint(const RealStack& y) const override;  // C x H x W -> B x H x W
  std::size_t bands() const override { return otf_.planes; }
  std::size_t channels() const override { return static_cast<std::size_t>(srf_.rows()); }
  std::size_t rows() const override { return otf_.rows; }
  std::size_t cols() const override { return otf_.cols; }
  std::size_t out_cols() const override { return otf_.cols; }
  const ComplexStack& otf() const { return otf_; }
  const Eigen::MatrixXd& srf() const { return srf_; }

 private:
  ComplexStack otf_;
  Eigen::MatrixXd srf_;
};

// An encoder whose sensor records only some of its pixels: y = mask ⊙ (inner x), the same mask on
// every channel (mask inner.rows() x inner.out_cols(), every value 0 or 1: a pixel recorded or
// not). Adjoint: innerᵀ (mask ⊙ y). A tile of a capture as the camera made it (linear convolution:
// light from outside the tile lands inside it) is the recorded window of a circular capture of a
// scene larger than the tile (tiled.hpp, TileBoundary::Linear); masked pixels may also be ones the
// sensor lost (hot or saturated). The MAP decoder (solve_map_cg) then estimates the scene over the
// whole grid from the recorded pixels alone.
class MaskedEncoder final : public Encoder {
 public:
  MaskedEncoder(std::shared_ptr<const Encoder> inner, Map2D mask);
  RealStack measure(const RealStack& x) const override;  // B x H x W -> C x H x W' (0 where masked)
  RealStack adjoint(const RealStack& y) const override;  // C x H x W' -> B x H x W (masked pixels ignored)
  std::size_t bands() const override { return inner_->bands(); }
  std::size_t channels() const override { return inner_->channels(); }
  std::size_t rows() const override { return inner_->rows(); }
  std::size_t cols() const override { return inner_->cols(); }
  std::size_t out_cols() const override { return inner_->out_cols(); }
  const Map2D& mask() const { return mask_; }

 private:
  void apply_mask(RealStack& y) const;
  std::shared_ptr<const Encoder> inner_;
  Map2D mask_;
};

// ---------------------------------------------------------------------------------------------
// Prior operator and the conjugate-gradient MAP decoder.

// C^power x for the stationary prior covariance above: x B x H x W on the prior's grid
// (prior.rows x prior.cols, prior.bands) -> B x H x W, multiplying DFT coefficient f by
// P(bin f)^power (symmetric eigendecomposition; eigenvalues clamped at 0 for power > 0).
// power <= 0 needs every used bin positive definite (InputError otherwise).
RealStack apply_prior_power(const wiener::SpectralPrior& prior, const RealStack& x, double power);

// Defaults: on 31-band 64 x 64 synthetic scenes through CASSI at σ = 1e-3, 1e-6 takes ~500
// iterations (~5 ms each on one core; ~90 at σ = 1e-2) and gives PSNR within 0.01 dB of the
// converged solution (1e-5: 0.03 dB; 1e-4: up to 1 dB off).
struct CgOptions {
  double tolerance = 1e-6;          // stop when ‖b − G z‖ <= tolerance · ‖b‖ (see the top comment)
  std::size_t max_iterations = 5000;
};
struct CgResult {
  RealStack x;                      // B x H x W estimate (not clipped)
  std::size_t iterations = 0;
  double residual = 0;              // final ‖b − G z‖ / ‖b‖ (recomputed, not the recursion's)
  bool converged = false;           // residual <= tolerance
};

// Solves the objective above for any linear encoder: y channels x H x W' (encoder.out_cols()),
// prior on the encoder's H x W grid with encoder.bands() bands, noise_sigma >= 0.
CgResult solve_map_cg(const Encoder& encoder, const RealStack& y, const wiener::SpectralPrior& prior,
                      double noise_sigma, const CgOptions& options = {});

// solve_map_cg behind the Decoder interface (decoder.hpp); holds the encoder (shared) and a copy of the prior.
// decode() returns the estimate only (call solve() for iterations and residual); it does not
// throw when CG stops at max_iterations.
class CgDecoder final : public Decoder {
 public:
  CgDecoder(std::shared_ptr<const Encoder> encoder, wiener::SpectralPrior prior, double noise_sigma,
            CgOptions options = {});
  RealStack decode(const RealStack& y) const override;  // C x H x W' -> B x H x W
  CgResult solve(const RealStack& y) const;
  std::size_t bands() const override { return encoder_->bands(); }
  std::size_t channels() const override { return encoder_->channels(); }
  std::string description() const override { return "conjugate-gradient MAP decoder"; }
  double noise_sigma() const { return noise_sigma_; }
  const CgOptions& options() const { return options_; }

 private:
  std::shared_ptr<const Encoder> encoder_;
  wiener::SpectralPrior prior_;
  double noise_sigma_;
  CgOptions options_;
};
using CassiDecoder = CgDecoder;  // CASSI's decoder: CgDecoder(std::make_shared<CassiEncoder>(...), ...)

// ---------------------------------------------------------------------------------------------
// Evaluation of an (encoder, decoder) pair on test cubes, as `qdo eval` does it.
struct EncoderEval {
  // Means over cubes of the REFERENCE §4 metrics (wiener.hpp metrics::): whole-cube PSNR
  // (peak 1), SSIM (tf.image.ssim convention), whole-cube RMSE, ERGAS (ratio 1), SAM (radians).
  double psnr_db = 0, ssim = 0, rmse = 0, ergas = 0, sam_rad = 0;
  std::size_t cubes = 0;
};

// For cube k (B x H x W, encoder.rows() x encoder.cols(), H, W >= 11 for SSIM, every band mean
// non-zero for ERGAS): y = encoder.measure(x) + Gaussian noise σ (ref::add_noise(y, σ, 0, seed, k):
// the same counter-based draws as `qdo eval` with that seed), x̂ = decoder.decode(y) clipped to
// [0, 1], metrics against x. sigma >= 0; cubes non-empty (InputError).
EncoderEval evaluate_encoder(const Encoder& encoder, const Decoder& decoder, const std::vector<RealStack>& cubes,
                             double sigma, std::uint64_t seed);

}  // namespace qdo
