// The test-set evaluation shared by `qdo eval` (src/evaluate/eval.cpp) and `qdo tolerance`
// (src/fab/fab_tolerance.cpp): the test patches, one patch through the camera and a decoder,
// the six metrics, and their averages (per scene over its patches, then over scenes, in that
// order, so both commands give bit-identical numbers for the same design).
#pragma once
#include <Eigen/Dense>

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "qdo/physics/camera.hpp"
#include "qdo/data/config.hpp"
#include "qdo/decode/decoder.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/runtime/types.hpp"
#include "qdo/decode/wiener.hpp"

namespace qdo::testset {

// One S x S test patch (bands x S x S) and the scene it was cut from (file stem, or synthetic_<i>).
struct Patch {
  std::string scene;
  RealStack cube;
};

// The run's test patches: the scenes under `data` (format `data_format`, on cfg's band grid)
// cut into non-overlapping s x s patches; with no data, `synthetic_scenes` held-out synthetic
// scenes of s x s drawn with seed run_seed + 1000003. InputError naming `data` for a scene
// smaller than s x s.
std::vector<Patch> patches(const SystemConfig& cfg, std::size_t s, const std::vector<std::string>& data,
                           const std::string& data_format, std::size_t synthetic_scenes, std::uint64_t run_seed);

// The patches' noiseless RGB images (3 x S x S each, in patch order) through a sensor PSF stack
// (bands x S x S, axis at S/2) with circular convolution on the S x S patch grid, on the device
// camera (Camera, camera.hpp) in float64 where the device has it, else float32. A 7-smooth S
// runs the camera in circular mode; any other S runs the linear camera on each patch's periodic
// extension (2S - 1 pixels a side) and keeps the centre, which is the same circular convolution.
// The host double-precision reference is wiener::simulate_measurement(x, psf_to_otf(psf, S, S), srf).
class PatchCamera {
 public:
  PatchCamera(Runtime& rt, const SystemConfig& cfg);
  // The same camera in precision p (the joint training runs it in the run's precision).
  PatchCamera(Runtime& rt, const SystemConfig& cfg, Precision p);
  std::vector<RealStack> measure(const RealStack& psf_sensor, const std::vector<Patch>& patches);
  // The same for bare cubes (bands x S x S each); with at most kMaxBatch of them on a 7-smooth S
  // they go to the device without a host copy (the joint training step's path).
  std::vector<RealStack> measure(const RealStack& psf_sensor, const std::vector<RealStack>& cubes);
  // Adjoint of the last measure() call (at most kMaxBatch patches, so one device call): gradients
  // on its images (3 x S x S each, in patch order) -> the gradient on its sensor PSF stack
  // (bands x S x S, summed over the patches). With the periodic extension the image gradient
  // sits on the kept centre of each extended image (zero elsewhere). InputError after a larger
  // call or with a wrong count or shape.
  RealStack vjp(const std::vector<RealStack>& g_images);
  static constexpr std::size_t kMaxBatch = 64;  // patches per device call (bounds the device memory)
  Precision precision() const { return prec_; }
  bool periodic_extension() const { return extend_; }

 private:
  std::size_t s_ = 0;
  Precision prec_ = Precision::F32;
  bool extend_ = false;
  std::size_t last_count_ = 0;  // patches of the last measure() call
  std::unique_ptr<Camera> camera_;
};

// Patch k's reconstruction from its noiseless image y (3 x S x S): Gaussian noise sigma drawn
// from (run_seed + 77, k), decoded by `dec` and clamped to [0, 1] (the decoder's output range,
// as the release's sigmoid).
RealStack reconstruct(const RealStack& y_noiseless, const Decoder& dec, double sigma, std::uint64_t run_seed, std::size_t k);

struct Scores {
  double psnr = 0, psnr_hyper = 0, ssim = 0, rmse = 0, ergas = 0, sam_rad = 0;
};
// The six metrics of a reconstruction xh against the truth x (metrics:: conventions).
Scores score(const RealStack& xh, const RealStack& x);

// Per-scene means (scenes in order of first appearance; each the mean over its patches, summed
// in patch order) of per-patch scores tagged with their scene.
std::vector<std::pair<std::string, Scores>> per_scene_means(const std::vector<std::pair<std::string, Scores>>& per_patch);
// The mean over rows, summed in row order.
Scores mean_of(const std::vector<Scores>& rows);

// The one test-set evaluation of eval, tolerance (and so sweep): every patch measured through
// psf_actual on `camera`, its noise drawn as reconstruct() draws it (patch k's), decoded by `dec`
// (decoder.hpp; dec.batch() images per decode_batch() call, each returning one bands x S x S cube
// per image), clamped to [0, 1] and scored; per-scene means in order of first appearance, and
// their mean. `each` (optional) sees every patch's reconstruction in patch order (eval writes
// some of them).
struct Evaluation {
  std::vector<std::pair<std::string, Scores>> per_patch;  // (scene, scores), patch order
  std::vector<std::pair<std::string, Scores>> per_scene;  // per_scene_means(per_patch)
  Scores mean;                                            // mean_of(per_scene)
};
Evaluation evaluate(PatchCamera& camera, const RealStack& psf_actual, const std::vector<Patch>& patches, const Decoder& dec,
                    double sigma, std::uint64_t run_seed, const std::function<void(std::size_t k, const RealStack& xh)>& each = {});

}  // namespace qdo::testset
