// CPU references (double) of the depth-layered / spatially varying imaging operator
// (include/qdo/physics/varying.hpp, kernels/varying.cl): the operator itself as a sum of per-component
// convolutions (ref::convolve, linear) with its adjoints, and a brute-force per-pixel model that
// does not share the weighted-sum structure.
//
// Shapes (all row-major): scene bands x H x W; psfs (K * bands) x S x S, component k's band b at
// plane k * bands + b, axis at (S/2, S/2), already shifted (the device's per-component shifts are
// shift_planes() here); weights K x H x W; srf 3 x bands (rows summing to 1); images 3 x H x W.
#pragma once
#include <Eigen/Dense>

#include "qdo/runtime/types.hpp"
#include "qdo/physics/varying.hpp"

namespace qdo::ref {

// source:  rgb = srf . sum_k convolve(w_k ⊙ scene, PSF_k)
// output:  rgb = srf . sum_k w_k ⊙ convolve(scene, PSF_k)
RealStack varying_images(const RealStack& scene, const RealStack& psfs, const RealStack& weights,
                         const Eigen::MatrixXd& srf, PsfPlacement placement);

// Adjoint of varying_images to the scene (bands x H x W), to the PSFs ((K * bands) x S x S) and to
// the weight maps (K x H x W) for an image gradient g_rgb (3 x H x W).
struct VaryingGradient {
  RealStack scene, psfs, weights;
};
VaryingGradient varying_vjp(const RealStack& scene, const RealStack& psfs, const RealStack& weights,
                            const Eigen::MatrixXd& srf, PsfPlacement placement, const RealStack& g_rgb);

// Brute force, pixel by pixel, O(bands H W K S^2): every pixel q forms its own PSF
// P_q = sum_k w_k(q) PSF_k explicitly; source placement splats scene(q) P_q around q
// (out(q + t) += scene(q) P_q(S/2 + t)), output placement gathers out(q) = sum_t P_q(S/2 + t)
// scene(q - t); then the sensor integration. Zero outside the scene.
RealStack varying_images_brute_force(const RealStack& scene, const RealStack& psfs, const RealStack& weights,
                                     const Eigen::MatrixXd& srf, PsfPlacement placement);

}  // namespace qdo::ref
