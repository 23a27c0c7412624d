// Adjoints (vector-Jacobian products) of the PSF chain, CPU reference in double.
//
// Gradient convention for complex quantities: g = dL/dRe(z) + i dL/dIm(z). For a complex-linear
// map y = A x this gives g_x = A^H g_y. For the PSF chain (per band b):
//   U1 = A exp(i theta_b),  theta_b = k_b (src(r) + dn_b H)       (doe_field)
//   U2 = F^-1 (T_b . F U1)                                       (propagate; adjoint = propagate over -z)
//   P  = |U2|^2 on the central N x N                              (g_U2 = 2 g_P U2 there, 0 elsewhere)
//   p  = P / sum(P)                                               (g_P = (g_p - <g_p, p>) / sum(P))
//   S  = W p W^T (area resampling)                                (g_p = W^T g_S W)
//   s  = S / sum(S)
//   dL/dH = sum_b k_b dn_b Re(conj(g_U1) i U1)
//
// Each adjoint is declared beside its forward map in its stage's header: the DOE phase in
// field_reference.hpp, the PSF chain (intensity, normalisation, resampling, heights -> PSF) in
// psf_reference.hpp, the convolution in camera_reference.hpp, the sensor integration in
// sensor_reference.hpp, the parameterizations and the quantizer in doe_adjoint_reference.hpp.
// This header includes them all.
#pragma once
#include "qdo/physics/camera_reference.hpp"
#include "qdo/physics/doe_adjoint_reference.hpp"
#include "qdo/physics/field_reference.hpp"
#include "qdo/physics/psf_reference.hpp"
#include "qdo/physics/sensor_reference.hpp"
