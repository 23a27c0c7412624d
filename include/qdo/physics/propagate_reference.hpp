// CPU reference of the propagation stage (kernels/propagate.cl and the host propagation), in
// double with FFTW. Conventions as in cpu_reference.hpp: forward FFT e^{-i2π(fx x + fy y)},
// inverse normalised by 1/M², Fresnel transfer function exp(-iπ λ z (fx² + fy²)) (the constant
// exp(ikz) dropped; the angular spectrum transfer function drops it too). The adjoint of
// propagation over z is propagation over -z (adjoint.hpp).
#pragma once
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo::ref {

// In-place circular propagation of a bands x M x M field over z_m (negative z goes back).
// wavelengths_nm has one entry per plane. Also fills `sampling` (if given) per band:
// the spectral energy beyond the transfer function's reliable limit.
void propagate(ComplexStack& field, const std::vector<double>& wavelengths_nm, double pitch_m, double z_m,
               Propagator method, std::vector<BandSampling>* sampling = nullptr);

// A direct (O(N^4)) Fresnel diffraction integral of an N x N field at pitch_m over z_m, in the
// same convention as the transfer function (constant exp(ikz) dropped): for tests.
ComplexStack fresnel_integral_direct(const ComplexStack& field, double wavelength_nm, double pitch_m, double z_m);

}  // namespace qdo::ref
