// The flat field of white frames (flat_field.hpp).
#include "qdo/physics/flat_field.hpp"

#include <cstddef>

#include "qdo/runtime/error.hpp"
#include "qdo/physics/raw_reference.hpp"

namespace qdo {

FlatField flat_field(const RealStack& white_signal, Cfa cfa, const std::string& where) {
  const RealStack& w = white_signal;
  const std::size_t plane = w.plane_size();
  if (w.data.empty() || plane == 0) reject(where, "(empty)", "white frames of the captures' size");
  // The colour of element i: the mosaic site's, the RGB plane, or 1 (green) for one monochrome plane.
  auto channel = [&](std::size_t i) -> std::size_t {
    if (cfa != Cfa::None) return std::size_t(cfa_channel(cfa, (i % plane) / w.cols, (i % plane) % w.cols));
    return w.planes == 3 ? i / plane : 1;
  };
  std::array<double, 3> sum{}, count{};
  double total = 0;
  for (std::size_t i = 0; i < w.data.size(); ++i) {
    sum[channel(i)] += w.data[i];
    count[channel(i)] += 1;
    total += w.data[i];
  }
  const double mean = total / double(w.data.size());
  if (!(mean > 0)) throw InputError(where + ": the white frames hold no signal above the darks (or the black level)");
  FlatField f;
  for (std::size_t c = 0; c < 3; ++c) f.channel_gains[c] = count[c] > 0 ? sum[c] / count[c] / mean : 0.0;
  f.gain = w;
  for (std::size_t i = 0; i < w.data.size(); ++i) {
    const double channel_mean = f.channel_gains[channel(i)] * mean;
    if (!(w.data[i] > 0.05 * channel_mean))
      throw InputError(where + ": the white signal at row " + to_str((i % plane) / w.cols) + ", column " + to_str((i % plane) % w.cols) +
                       " is " + to_str(w.data[i]) + " DN, under 5 % of its colour's mean " + to_str(channel_mean) +
                       " DN (a dead pixel, or the white target does not fill the view)");
    f.gain.data[i] /= mean;
  }
  return f;
}

}  // namespace qdo
