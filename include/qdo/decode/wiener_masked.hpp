// The Wiener decoder's objective for a PSF camera that records only part of its grid: the MAP
// estimate of encoders.hpp for A = M A_c, A_c the circular camera of an OTF and a response (C x B)
// on an H x W grid and M a 0/1 mask of the recorded pixels (the same on every channel):
//     x̂ = argmin_x ‖M (A_c x − y)‖² / σ² + xᵀ C⁻¹ x.
// A tile of a real (linear) capture is such a window: the scene around it sends light into it
// (tiled.hpp, TileBoundary::Linear). With M = I it is the WienerDecoder.
//
// Solved in the measurement space (Woodbury: x̂ = C A_cᵀ M u with (M A_c C A_cᵀ M + σ² I) u = M y),
// where A_c C A_cᵀ is, per DFT frequency f, the C x C Hermitian matrix Q(f) = A(f) P(f) A(f)^H
// (A(f) = srf · diag(OTF_b(f)), P the prior's bin of f, its eigenvalues clamped at 0 as in
// apply_prior_power). Conjugate gradients on u (C x H x W), preconditioned by the circular camera's
// exact inverse restricted to the recorded pixels, M F⁻¹ (Q(f) + σ² I)⁻¹ F M; each iteration costs
// 2 C forward and 2 C inverse real FFTs (half spectra), against the primal CG's (solve_map_cg on a MaskedEncoder) 2 B
// + 2 C and B x B products per frequency. The estimate then needs B inverse FFTs once.
// Stopping: ‖M y − G u‖ <= tolerance · ‖M y‖ (G the operator above). σ > 0 (with σ = 0 the
// system is singular wherever the prior is).
//
// Shapes: otf complex B x H x W (wiener::psf_to_otf); srf C x B; prior on H x W (prior.bands = B);
// mask H x W, values 0 or 1; y C x H x W (values at masked pixels are ignored); the estimate
// B x H x W over the whole grid.
#pragma once
#include <Eigen/Dense>

#include <cstddef>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "qdo/decode/decoder.hpp"
#include "qdo/decode/encoders.hpp"
#include "qdo/decode/wiener.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

class MaskedWienerDecoder final : public Decoder {
 public:
  // InputError naming the argument on inconsistent shapes, a mask value other than 0 or 1, a
  // non-finite value, σ <= 0 or a tolerance outside (0, 1).
  MaskedWienerDecoder(ComplexStack otf, Eigen::MatrixXd srf, const wiener::SpectralPrior& prior, Map2D mask, double noise_sigma,
                      CgOptions options = {1e-5, 2000});
  RealStack decode(const RealStack& y) const override;  // C x H x W -> B x H x W
  CgResult solve(const RealStack& y) const;             // the estimate, iterations and residual
  // The images of a batch solved concurrently, one thread each (solves share nothing but the
  // statistics); batch() = the machine's hardware threads, at most 8.
  std::vector<RealStack> decode_batch(const std::vector<RealStack>& ys) const override;
  std::size_t batch() const override;
  std::size_t bands() const override { return camera_->bands(); }
  std::size_t channels() const override { return static_cast<std::size_t>(srf_.rows()); }
  std::string description() const override { return "Wiener decoder for the recorded window (conjugate gradients)"; }
  double noise_sigma() const { return sigma_; }
  const CgOptions& options() const { return options_; }
  // Over every solve so far (decode and solve, any thread): how many, the most iterations, the
  // worst final residual and whether every one reached the tolerance.
  struct Stats {
    std::size_t solves = 0, max_iterations = 0;
    double worst_residual = 0;
    bool all_converged = true;
  };
  Stats stats() const;

 private:
  std::shared_ptr<const DoeEncoder> camera_;  // A_c (the OTF and srf)
  Eigen::MatrixXd srf_;
  wiener::SpectralPrior prior_;
  Map2D mask_;
  double sigma_;
  CgOptions options_;
  // Per frequency f of the half spectrum (H x (W/2 + 1), rfftw2): Q(f) and (Q(f) + σ² I)⁻¹, each
  // C x C row-major.
  std::vector<cdouble> q_, q_inv_;
  mutable std::mutex stats_mutex_;
  mutable Stats stats_;
};

}  // namespace qdo
