// Joint training of the optics and a network decoder, the core half: the
// training patches, the device camera with its adjoint, the sensor noise, and the glue that turns
// a NetworkDecoder step into a PsfObjective for Designer::step. Per step:
//   batch of S x S scene patches (random crops, one of the 8 flips/rotations each)
//   -> PatchCamera (circular per-band convolution on the S x S patch grid, sensor integration;
//      the imaging `qdo eval` uses) -> + Gaussian read noise σ (drawn per step)
//   -> NetworkDecoder::train (loss, dL/d(images), the network's Adam step)
//   -> PatchCamera::vjp -> dL/dPSF (bands x S x S), which Designer carries to the heights.
#pragma once
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/design/joint_sampling.hpp"
#include "qdo/decode/network_decoder.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/decode/testset.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

// The scenes a network run trains and validates on. train: whole cubes (bands x H x W, H and
// W >= S) from which patches are cropped; val: fixed S x S patches (testset::Patch).
struct JointData {
  std::vector<RealStack> train;
  std::vector<std::string> train_names, val_names;  // file paths (or synthetic_<i>)
  std::vector<testset::Patch> val;
};
// Scenes under `data` (cfg's band grid) split at random by `seed` into 90 % training and 10 %
// validation scenes (at least one of each when there are two or more; with one scene both use
// it, and the caller is told by val_names == train_names). With no data: `synthetic` training
// scenes and max(2, synthetic / 4) validation scenes of S x S drawn with other seeds. Validation
// patches: non-overlapping S x S crops, at most `max_val_patches` (spread evenly).
// An entry "synthetic:N" of `data` adds N synthetic S x S training scenes (drawn with the seed)
// to the real ones, which alone are split (scripts/experiments_network.sh SYNTH=N measures
// whether they help).
// InputError naming `data` for a scene smaller than S x S.
JointData load_joint_data(const SystemConfig& cfg, const std::vector<std::string>& data, const std::string& data_format,
                          std::size_t synthetic, std::uint64_t seed, std::size_t max_val_patches = 16);

// The batch of step `step`: `batch` S x S crops, scene, position and transform (bit 0: flip
// columns, bit 1: flip rows, bit 2: transpose) drawn from a generator seeded with (seed, step),
// so a resumed run draws the same batches.
// N of "synthetic:N" (an integer in [1, 100000]); InputError naming `data` otherwise.
std::size_t synthetic_count(const std::string& entry);

std::vector<RealStack> joint_batch(const JointData& d, std::size_t s, std::size_t batch, std::uint64_t seed, long step);

// One of the release's fixed training patches: the whole of scene `scene` resized to S x S
// (resized), or its S x S crop with top-left corner (y0, x0).
struct FixedPatch {
  std::size_t scene = 0;
  bool resized = false;
  std::size_t y0 = 0, x0 = 0;
};
// The release's patch list (dataset_loader.py, the ICVL 512 loader, for any scene size H x W and
// patch size S): per training scene in order, first the whole scene resized to S x S, then the
// crops at rows y in range(0, H, ceil(H / 3)) and, within each row, columns x in range(0, W,
// ceil(W / 3)), each moved inside the scene (y = min(y, H - S), x = min(x, W - S)). For the
// release's 1392 x 1300 ICVL scenes and S = 512: rows 0, 464, 880 and columns 0, 434, 788, ten
// patches per scene.
std::vector<FixedPatch> fixed_patches(const JointData& d, std::size_t s);
// A fixed patch's cube (bands x S x S). The resize is bilinear with half-pixel centres and no
// anti-aliasing (tf.image.resize's default): output sample i reads the input at
// (i + 0.5) H / S - 0.5, between samples max(floor, 0) and min(ceil, H - 1).
RealStack fixed_patch(const JointData& d, const FixedPatch& p, std::size_t s);
// The batch of step `step` under fixed patches: patches (step * batch + k) mod P, k < batch, of
// the list `list` (P patches), in order: every epoch of P / batch steps sees each once, unshuffled.
std::vector<RealStack> fixed_batch(const JointData& d, const std::vector<FixedPatch>& list, std::size_t s, std::size_t batch,
                                   long step);

// The sensor noise of JointSampling::noise_on_bands, added to rgb (3 x S x S, row-major planes):
// on each pixel the distribution of srf * n, n a vector of bands Gaussians of std sigma_band,
// i.e. Gaussian with covariance sigma_band^2 srf srf^T, drawn as its symmetric square root times
// three standard normals from (seed, counter (scene_index * S*S + pixel) * 3 + channel). srf: 3 x bands.
// The per-band std on the sensor grid of noise sigma drawn on the DOE grid and averaged over the
// r x r samples of a sensor pixel: sigma / r, r = sensor_pitch_m / pitch_m.
double band_noise_sigma(const SystemConfig& cfg, double sigma);
void add_band_noise(RealStack& rgb, const Eigen::MatrixXd& srf, double sigma_band, unsigned long long seed,
                    std::size_t scene_index);

// Data-parallel training (qdo design under mpirun with N > 1 ranks, qdo/runtime/mpi.hpp): every rank
// draws the step's whole batch from the seed (the one a single process draws) and takes items
// [r B/N, (r+1) B/N) of it (rank r; B a multiple of N), with the read noise of their places in
// the batch. It images them, runs the network's forward and backward on them (batch norm
// synchronised over the ranks) and the camera adjoint, then sums over the ranks, in ONE
// allreduce, [dL/dPSF, the network's gradients, loss, MAE, MSE], each rank's share weighted by
// its part of the batch and the γ ||ω||² term on rank 0 alone: the sums are the 1-process
// step's. Every rank then takes the same network Adam step and returns the same dL/dPSF and loss,
// from which Designer takes the same optics step (dL/dheights and dL/doffsets are linear in
// dL/dPSF, and its β L_aq term is added once, after the sum). So the ranks' states stay identical.
class JointTrainer {
 public:
  // `net` and `data` must outlive the trainer. noise_sigma: the read noise added to each image.
  // Under mpirun with N > 1 ranks (above): InputError naming `batch` unless N divides it.
  // sampling: which patches each step trains on and where the noise enters (joint_sampling.hpp).
  JointTrainer(Runtime& rt, const SystemConfig& cfg, Precision p, NetworkDecoder& net, const JointData& data,
               std::size_t batch, double noise_sigma, std::uint64_t seed, const JointSampling& sampling = {});
  // One joint step at the sensor PSF stack psf (bands x S x S): images the step's batch, trains
  // the network one step at learning rate lr_net, and writes dL/dpsf into grad_psf. Returns the
  // loss (NetworkStep::loss). Data-parallel: the global batch's loss and dL/dpsf on every rank.
  double step(long step, double lr_net, const RealStack& psf, RealStack& grad_psf);
  // The last step's loss, MAE and PSNR (the global batch's), and this rank's image gradients.
  const NetworkStep& last() const { return last_; }
  std::size_t ranks() const { return ranks_; }
  const RealStack& last_psf() const { return last_psf_; }
  // Mean PSNR (peak 1) over the validation patches through psf, with noise drawn per patch from
  // (seed + 78, k), network in inference mode. Same value for the same state and PSF.
  double validation_psnr_db(const RealStack& psf);

 private:
  testset::PatchCamera camera_;
  NetworkDecoder& net_;
  const JointData& data_;
  std::size_t s_, batch_;
  double sigma_;
  std::uint64_t seed_;
  JointSampling sampling_;
  std::vector<FixedPatch> fixed_;  // the fixed patch list (sampling_.fixed_patches)
  Eigen::MatrixXd srf_;            // 3 x bands (sampling_.noise_on_bands)
  double sigma_band_ = 0;          // the band noise's std on the DOE grid, over the r x r average
  std::size_t rank_ = 0, ranks_ = 1;  // this process's MPI rank and the world size
  NetworkStep last_;
  RealStack last_psf_;
};

}  // namespace qdo
