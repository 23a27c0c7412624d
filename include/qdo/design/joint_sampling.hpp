// How a network trained with the optics sees its training data (qdo/design/joint.hpp), the recipe's data
// items (recipe.hpp): which patches, in what order, and where the sensor noise enters.
#pragma once

namespace qdo {

struct JointSampling {
  // false (qdo's): every step draws `batch` random S x S crops of random training scenes, each
  // flipped and transposed at random (joint_batch). true (the release's): the fixed patch list
  // (fixed_patches: per scene the whole scene resized to S x S, then a 3 x 3 grid of crops), taken
  // in order, `batch` consecutive patches per step, no augmentation (fixed_batch).
  bool fixed_patches = false;
  // false (qdo's): Gaussian noise sigma on each RGB sensor pixel. true (the release's): sigma on
  // every band of the image on the DOE grid (pitch_m) before the sensor response and the area
  // resampling to the sensor grid, i.e. on RGB srf * n with n ~ N(0, (sigma / r)^2) per band and
  // sensor pixel, r = sensor_pitch_m / pitch_m (r x r DOE samples averaged per pixel).
  bool noise_on_bands = false;
};

}  // namespace qdo
