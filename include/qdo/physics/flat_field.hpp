// A flat field from white frames: a uniformly lit, spectrally flat white target seen through the
// camera. Its signal per pixel, over its mean, is each pixel's gain (the colour channel's gain
// times the pixel's response non-uniformity); dividing a capture's signal by it leaves what the
// model's normalised response table predicts.
#pragma once
#include <array>
#include <string>

#include "qdo/data/config.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

struct FlatField {
  RealStack gain;                            // planes x H x W, the white's signal over its mean (mean 1)
  std::array<double, 3> channel_gains{};     // each colour's mean gain (R, G, B; 0 for a colour absent)
};

// white_signal: planes x H x W, the white frames' mean minus the dark (or the black level), in DN;
// planes 3 (RGB, cfa none) or 1 (a mosaic laid out as `cfa`, or a monochrome frame with cfa none:
// one channel). Refused with an InputError naming `where`: no signal, or a pixel under 5 % of its
// colour's mean (a dead pixel, or the target not filling the view).
FlatField flat_field(const RealStack& white_signal, Cfa cfa, const std::string& where);

}  // namespace qdo
