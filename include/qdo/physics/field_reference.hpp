// CPU reference of the field stage (kernels/field.cl), in double: the field just after the DOE
// and its derivatives with respect to the heights. Conventions as in cpu_reference.hpp (Goodman:
// diverging spherical wave exp(+ik r), DOE factor exp(+i k (n-1) H)); gradients of complex
// quantities as in adjoint.hpp (g = dL/dRe(z) + i dL/dIm(z)).
#pragma once
#include "qdo/data/config.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/runtime/types.hpp"

#include <vector>

namespace qdo::ref {

// Field just after the DOE for every object point and band, in the zero-padded window: shape
// points x bands x M x M (points = cfg.point_count(), point-major: plane p * bands + b), row-major;
// zero outside the circular aperture and outside the N x N DOE; each sample times its aperture
// weight (aperture_transmission, optics.hpp: 1 inside, or its cell's area fraction with
// aperture_edge "area"). The object points move with the optical axis (cfg.aperture_offset_*_m).
// Phase k (sqrt((x-x0)² + (y-y0)² + d²) - R0) + k (n_b - 1) H (R0 = sqrt(x0² + y0² + d²)), the first
// term written without cancellation (point_source_m) so no large constant k·R0 enters
// (REFERENCE §1 precision pitfall); on axis r²/(sqrt(r²+d²)+d), for a plane wave -(x α + y β).
// The object points as FieldStage::point_table(cfg) (field.hpp) describes them.
ComplexStack doe_field(const SystemConfig& cfg, const Map2D& height_m, const PropagationGeometry& g);

// The source term (metres) at DOE position (x, y) of point p of a point table (FieldStage::point_table:
// points x 4 doubles): the exact path length to the point minus R0, cancellation-free.
double point_source_m(const std::vector<double>& point_table, std::size_t p, double x, double y);

// VJP of doe_field with respect to the heights: u1 = doe_field(cfg, H, geo) and g_field, the
// gradient on that field (both points x bands x M x M; the points' gradients add up) -> dL/dH (N x N) = sum_b k_b dn_b Re(conj(g) i U1)
// over the N x N DOE window at [geo.offset, geo.offset + N).
Map2D doe_phase_vjp(const SystemConfig& cfg, const PropagationGeometry& geo, const ComplexStack& u1,
                    const ComplexStack& g_field);
// JVP of the same map: d_height_m (N x N) -> dU1 = i k_b dn_b dH U1 (points x bands x M x M, zero outside
// the DOE window).
ComplexStack doe_phase_jvp(const SystemConfig& cfg, const PropagationGeometry& geo, const ComplexStack& u1,
                           const Map2D& d_height_m);

}  // namespace qdo::ref
