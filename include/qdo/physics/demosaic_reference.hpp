// CPU reference of the demosaic stage (kernels/demosaic.cl, include/qdo/physics/demosaic.hpp), in double:
// one Bayer raw plane -> three colour planes, by bilinear interpolation or by Malvar, He and
// Cutler's gradient-corrected 5 x 5 linear filters (ICASSP 2004), and the transpose of that map.
//
// Units: the stage is linear and takes the raw plane in linear signal units, black level removed
// and scaled (raw_to_linear below: 1.0 = full well, the RawStage input's units); its output is in
// the same units. DN straight from a file can be demosaiced too (the map is linear and every
// filter sums to 1, so a constant offset passes through), but the decoders expect linear units.
//
// The map: output (c, y, x) = sum over the taps (dy, dx, w) of the filter chosen by the pixel's
// site (the channel its filter passes, and for a green site whether red lies left/right or
// above/below) and the output channel c, of w * raw(m(y + dy), m(x + dx)). Filters (all sum to 1,
// all symmetric about the centre):
//   own channel                      identity
//   G at R or B       bilinear  (N + S + E + W) / 4
//                     MHC       (4 C + 2 (N + S + E + W) - (N2 + S2 + E2 + W2)) / 8, C the site's value
//   R (B) at a green site with R (B) left and right
//                     bilinear  (E + W) / 2
//                     MHC       (5 C + 4 (E + W) - (E2 + W2) - (NE + NW + SE + SW) + (N2 + S2) / 2) / 8
//   R (B) at a green site with R (B) above and below: the transpose of the above
//   R at B and B at R bilinear  (NE + NW + SE + SW) / 4
//                     MHC       (6 C + 2 (NE + NW + SE + SW) - 3/2 (N2 + S2 + E2 + W2)) / 8
// (N = (y - 1, x), N2 = (y - 2, x), NE = (y - 1, x + 1), ...).
// Border rule: mirror about the edge pixel without repeating it (m(-1) = 1, m(-2) = 2,
// m(H) = H - 2, m(H + 1) = H - 3), which keeps each pixel's parity and so the mosaic: a mirrored
// tap reads a pixel of the same colour the unmirrored one would have. Rows and columns >= 3.
// Closed forms: a constant image is reproduced exactly everywhere by both; bilinear reproduces
// per-channel affine ramps at pixels >= 1 from the border, MHC at pixels >= 2 from it (each
// filter's part on another channel sums to 0 and is symmetric).
#pragma once
#include <string>

#include "qdo/data/config.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

enum class DemosaicMethod { Bilinear, MHC };
// "bilinear" or "mhc" (case-insensitive); anything else is rejected naming `argument`.
DemosaicMethod demosaic_method_from_string(const std::string& s, const std::string& argument = "demosaic");
std::string to_string(DemosaicMethod m);  // "bilinear", "mhc"

// Raw code values (DN) -> linear signal, the inverse of the raw stage's affine part (raw.hpp):
// (dn - black_level_dn) / (gain * (white - black_level_dn)), white = cfg.white_level_dn(), element by
// element (any shape; clipping and rounding are not undone).
RealStack raw_to_linear(const RealStack& raw_dn, const SystemConfig& cfg);

namespace ref {

// raw: 1 x H x W (H, W >= 3, linear units), cfa a mosaic (not Cfa::None) -> 3 x H x W (R, G, B).
RealStack demosaic(const RealStack& raw, Cfa cfa, DemosaicMethod method);
// The transpose: g_rgb 3 x H x W -> g_raw 1 x H x W (each tap scatters back to the pixel it read,
// through the mirror).
RealStack demosaic_vjp(const RealStack& g_rgb, Cfa cfa, DemosaicMethod method);
// The mosaic as three sparse planes: raw 1 x H x W -> 3 x H x W with raw(y, x) in the plane of the
// channel the filter at (y, x) passes and 0 in the other two (a decoder reading the mosaic directly).
RealStack mosaic_planes(const RealStack& raw, Cfa cfa);

}  // namespace ref
}  // namespace qdo
