// CPU reference of the field stage (kernels/field.cl), in double: the field just after the DOE
// and its derivatives with respect to the heights. Conventions as in cpu_reference.hpp (Goodman:
// diverging spherical wave exp(+ik r), DOE factor exp(+i k (n-1) H)); gradients of complex
// quantities as in adjoint.hpp (g = dL/dRe(z) + i dL/dIm(z)).
#pragma once
#include "qdo/config.hpp"
#include "qdo/optics.hpp"
#include "qdo/types.hpp"

namespace qdo::ref {

// Field just after the DOE for every band, in the zero-padded window: shape bands x M x M,
// (b, y, x) row-major; zero outside the circular aperture and outside the N x N DOE.
// Phase k (sqrt(r² + d²) - d) + k (n_b - 1) H, the first term written r²/(sqrt(r²+d²)+d)
// so no large constant k·d enters (REFERENCE §1 precision pitfall).
ComplexStack doe_field(const SystemConfig& cfg, const Map2D& height_m, const PropagationGeometry& g);

// VJP of doe_field with respect to the heights: u1 = doe_field(cfg, H, geo) and g_field, the
// gradient on that field (both bands x M x M) -> dL/dH (N x N) = sum_b k_b dn_b Re(conj(g) i U1)
// over the N x N DOE window at [geo.offset, geo.offset + N).
Map2D doe_phase_vjp(const SystemConfig& cfg, const PropagationGeometry& geo, const ComplexStack& u1,
                    const ComplexStack& g_field);
// JVP of the same map: d_height_m (N x N) -> dU1 = i k_b dn_b dH U1 (bands x M x M, zero outside
// the DOE window).
ComplexStack doe_phase_jvp(const SystemConfig& cfg, const PropagationGeometry& geo, const ComplexStack& u1,
                           const Map2D& d_height_m);

}  // namespace qdo::ref
