// Camera raw files: DNG and the vendors' raw formats, read with LibRaw as the Bayer mosaic the
// camera stored (no demosaic, no black subtraction, no scaling, no white balance); and a minimal
// DNG writer (libtiff) for fixtures and for users who make their own test frames.
#pragma once
#include <array>
#include <cstddef>
#include <string>

#include "qdo/runtime/types.hpp"

namespace qdo {

// What a camera raw file says about its mosaic. CFA positions are row-major over the 2 x 2 cell
// at the top-left pixel of the returned mosaic: 0 = (0, 0), 1 = (0, 1), 2 = (1, 0), 3 = (1, 1).
struct CameraRawInfo {
  std::string make, model;                  // as LibRaw names them (it normalizes makers' names)
  std::string cfa;                          // the 2 x 2 pattern: "rggb", "bggr", "grbg" or "gbrg"
  double black_level_dn = 0;                // mean of channel_black_dn
  std::array<double, 4> channel_black_dn{}; // black level per CFA position, DN
  double white_level_dn = 0;                // saturation level, DN (LibRaw's `maximum`)
  double linear_max_dn = 0;                 // where the maker notes say the response stops being linear (0: not given)
  std::size_t rows = 0, cols = 0;           // of the returned mosaic: the visible area
  std::size_t top = 0, left = 0;            // where it starts in the stored raw image (LibRaw's margins)
  int bits = 0;                             // bits per stored sample when the file says (0: unknown)
};

// Extension .dng, .nef, .cr2, .cr3, .arw, .raf, .orf, .rw2, .pef, .srw or .raw (any case).
bool is_camera_raw_path(const std::string& path);

// The raw Bayer mosaic: 1 x rows x cols code values in DN, row-major, the visible area of the
// sensor (LibRaw's raw_image cropped to top_margin, left_margin, height, width; masked border
// pixels dropped; LibRaw 0.20 moves a DNG ActiveArea corner at an odd row or column to the next
// even one, so such a mosaic starts a row or column inside the file's active area). Values are what LibRaw decodes: a file's linearization curve (DNG
// LinearizationTable, lossy NEF) is applied, nothing else; the camera's orientation flag is not.
// Refused with an InputError naming the file: a file LibRaw cannot read or unpack, a decode that
// reports corrupt or missing data, and anything but a 2 x 2 RGB Bayer mosaic (X-Trans, Foveon,
// monochrome sensors, 4-colour mosaics, Fuji SuperCCD, linear or reduced-size DNG and sRAW);
// a sensor of more than 2^28 pixels.
RealStack read_camera_raw(const std::string& path, CameraRawInfo* info = nullptr);

// A DNG 1.4 file (one IFD, uncompressed 16-bit CFA data) holding dn (rows x cols code values,
// row-major) as a Bayer mosaic whose top-left 2 x 2 cell is `cfa` ("rggb", "bggr", "grbg" or
// "gbrg"), with one BlackLevel and WhiteLevel, an identity ColorMatrix1 (D65), AsShotNeutral
// 1 1 1. Codes, black and white must be integers in [0, 65535] with black < white, make and
// model non-empty (an InputError naming the file otherwise). Written to a temporary name, then
// renamed. LibRaw reads no DNG below 22 x 22 pixels.
void write_dng_mosaic(const std::string& path, const Map2D& dn, const std::string& cfa, double black_level_dn,
                      double white_level_dn, const std::string& make = "qdo", const std::string& model = "synthetic");

}  // namespace qdo
