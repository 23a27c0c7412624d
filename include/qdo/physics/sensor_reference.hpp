// CPU reference of the sensor stage (kernels/sensor.cl), in double: Eq. 7's integration over the
// bands, its adjoint, and the counter-based shot and read noise.
#pragma once
#include <Eigen/Dense>

#include <cstddef>

#include "qdo/runtime/types.hpp"

namespace qdo::ref {

// Eq. 7 without noise: rgb(c, y, x) = sum_b srf(c, b) * cube(b, y, x); srf is 3 x B with
// rows already normalised to unit sum (sensor_response()).
RealStack sensor_integrate(const RealStack& blurred, const Eigen::MatrixXd& srf);
// Shot noise (Poisson with full_well_photons at value 1; skipped when 0) then Gaussian read
// noise (sigma in full-scale units), element (c, y, x) of scene k in a batch drawing counter
// ((k*H*W) + y*W + x)*3 + c.
void add_noise(RealStack& rgb, double read_noise_sigma, double full_well_photons, unsigned long long seed,
               std::size_t scene_index = 0);

// VJP of ref::sensor_integrate: g_rgb 3 x H x W -> bands x H x W (srf^T g).
RealStack sensor_integrate_vjp(const RealStack& g_rgb, const Eigen::MatrixXd& srf);

}  // namespace qdo::ref
