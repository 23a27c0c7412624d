// What a reader looks at in a spectral cube (bands x H x W, row-major planes, at wavelengths_nm):
// an sRGB render, and the mean spectra at points and over boxes. `qdo reconstruct` and `qdo eval`
// write them.
#pragma once
#include <cstddef>
#include <string>
#include <vector>

#include "qdo/runtime/types.hpp"

namespace qdo {

// A point (rows = cols = 1) or a box of the reconstructed image, 0-based.
struct SpectrumRegion {
  std::size_t row = 0, col = 0, rows = 1, cols = 1;
  bool box = false;
  std::string label() const;  // "point R,C" or "box R,C,H,W"
};
// "R,C;R,C;..." (points) or "R,C,H,W;..." (boxes); an InputError naming `argument` otherwise.
std::vector<SpectrumRegion> parse_regions(const std::string& s, bool boxes, const std::string& argument);
// The mean spectrum (bands values) over each region of cube (bands x H x W); a region reaching
// outside is an InputError naming `argument`, the region and the image size.
std::vector<std::vector<double>> region_spectra(const RealStack& cube, const std::vector<SpectrumRegion>& regions,
                                                const std::string& argument = "--points/--boxes");

// Linear sRGB (3 x H x W, >= 0) of a cube (bands x H x W at wavelengths_nm) through the CIE 1931
// 2° observer (a flat unit spectrum has Y = 1) and the XYZ -> linear sRGB (D65) matrix.
RealStack render_srgb(const RealStack& cube, const std::vector<double>& wavelengths_nm);

}  // namespace qdo
