// Per-object-point PSF planes: picking one point's planes out of a points x bands stack
// and moving an off-axis point's PSF onto the axis, so that a field-dependent PSF can be compared
// with, or interpolated against, the on-axis one.
//
// Stacks here are RealStack, planes x S x S, row-major, the optical axis at (S/2, S/2) (row S/2,
// column S/2); a point's PSF lies near its chief-ray image, row S/2 + rows_px, column S/2 + cols_px
// with (cols_px, rows_px) = chief_ray_image_m / sensor_pitch_m (config.hpp; inverted: -z tan θ).
#pragma once
#include <cstddef>
#include <utility>

#include "qdo/data/config.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

// Point p's planes (bands x S x S) of a stack of points x bands planes, point-major (plane
// p * bands + b, PsfSource's layout). InputError when bands is 0, does not divide the planes or
// p is not below planes / bands.
RealStack point_planes(const RealStack& stack, std::size_t point, std::size_t bands);

// Where the chief ray of `p` meets the sensor, in sensor pixels from the axis: {rows_px, cols_px}
// = {-z tan θy, -z tan θx} / sensor_pitch_m (not rounded).
std::pair<double, double> chief_ray_offset_px(const SystemConfig& c, const ObjectPoint& p);

// The stack moved by whole pixels, zero filled: out(q, y, x) = in(q, y + dy_px, x + dx_px) where
// that lies inside, 0 elsewhere. Every plane the same shift.
RealStack shift_planes(const RealStack& stack, long dy_px, long dx_px);

// An off-axis point's planes (bands x S x S) moved so its chief-ray image, rounded to the nearest
// pixel, lands on the axis: shift_planes(planes, round(rows_px), round(cols_px)). `lost` (when
// given) receives the largest fraction of a plane's sum moved out of the window (0 when nothing
// was; the planes are not renormalised). An on-axis point's planes come back unchanged.
RealStack recentre_on_chief_ray(const RealStack& planes, const SystemConfig& c, const ObjectPoint& p,
                                double* lost = nullptr);

}  // namespace qdo
