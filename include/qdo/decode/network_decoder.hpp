// A learned decoder trained with the optics (the paper's Res-UNet), as the LibTorch-free
// core sees it. The core (qdo_core) draws the training patches, images them through the device
// camera, adds the sensor noise, hands the noisy images to a NetworkDecoder, and carries the image
// gradient it returns back through the camera adjoint to the PSF (src/design/joint.cpp). The
// network itself lives in qdo_net (src/net/, LibTorch), which registers its factory with
// register_network_factory() (the slot and the loader: src/decode/network_decoder.cpp); a qdo built
// without LibTorch has none, and asking for a network is then an InputError that says so.
//
// Shapes: images are RGB sensor images, 3 x S x S each (row-major planes, RealStack); targets and
// reconstructions are scene cubes, bands x S x S each, values in [0, 1].
#pragma once
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "qdo/decode/decoder.hpp"
#include "qdo/decode/decoder_spec.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

struct NetworkStep {
  double loss = 0;      // MAE(x̂, x) + γ ||ω||² (Eq. 14 without the optics' β L_aq)
  double mae = 0;       // the data term alone
  double psnr_db = 0;   // PSNR of the batch's reconstruction (whole batch, peak 1)
  std::vector<RealStack> grad_images;  // dL/d(images), 3 x S x S each
};

class NetworkDecoder {
 public:
  virtual ~NetworkDecoder() = default;
  virtual std::string spec() const = 0;  // DecoderSpec::to_string() of the network
  virtual std::size_t parameter_count() const = 0;
  // One training step in training mode (batch statistics): loss and dL/d(images) at the current
  // weights, then one Adam step of the network at learning rate lr. images and targets pair up.
  virtual NetworkStep train(const std::vector<RealStack>& images, const std::vector<RealStack>& targets, double lr) = 0;
  // Inference (batch norm's running statistics, no gradient): one cube per image.
  virtual std::vector<RealStack> reconstruct(const std::vector<RealStack>& images) = 0;
  // The network's weights, running statistics and optimiser state, as bytes; load() restores
  // exactly that state (bit-identical continuation). load() refuses (InputError naming `origin`)
  // bytes that are not such a state or that hold another architecture (both specs named).
  virtual std::string save() const = 0;
  virtual void load(const std::string& bytes, const std::string& origin) = 0;

  // Data-parallel training (qdo design under mpirun, joint.cpp): every rank takes its share of
  // the global batch; train() is then split in two so that the gradients can be summed over the
  // ranks in between. A network that has no such split throws InputError from each (the defaults).
  //
  // The element-wise sum over the ranks (in place, n values) that training-mode batch norm uses
  // for its statistics, so that the ranks normalise with the global batch's mean and variance and
  // keep the same running statistics (synchronised batch norm); an empty function: local batch.
  using RankSum = std::function<void(double* data, std::size_t n)>;
  virtual void set_rank_sum(RankSum sum);
  // Loss and dL/d(images) of this rank's share at the current weights, the network's gradients
  // kept (not applied): loss = data_weight * MAE(share) + (regularise ? γ ||ω||² : 0), so with
  // data_weight = share / global batch and the regulariser on one rank the sum over the ranks of
  // the losses and of the gradients is the global batch's. NetworkStep::mae is the share's MAE
  // times data_weight; with data_weight < 1, psnr_db holds the share's MSE times data_weight (both
  // summed over the ranks: the global batch's; data_weight 1 gives train()'s PSNR).
  virtual NetworkStep backward(const std::vector<RealStack>& images, const std::vector<RealStack>& targets, double data_weight,
                               bool regularise);
  // The gradients backward() left, parameter_count() values in the network's parameter order.
  virtual void read_gradients(double* out) const;
  // Sets the gradients to `grad` (parameter_count() values, same order) and takes one Adam step
  // at learning rate lr.
  virtual void apply_gradients(const double* grad, double lr);
};

// Training constants of the network that are not its architecture (the recipe's network items,
// recipe.hpp): the release's Keras batch norm and Glorot-uniform last convolution, or torch's
// batch norm and He-uniform everywhere (qdo's own).
struct NetworkStyle {
  bool keras_batch_norm = false;  // batch-norm momentum 0.01 and eps 1e-3 (else 0.1 and 1e-5)
  bool glorot_final = false;      // Glorot-uniform last 1x1 convolution (else He-uniform)
};

struct NetworkSettings {
  DecoderSpec spec;                 // the decoder trained (a resunet spec, or a trained registry entry)
  std::size_t in_channels = 3, out_channels = 31;
  std::uint64_t seed = 0;           // initial weights
  double weight_decay_gamma = 1e-4; // γ of Eq. 14 on the convolution weights
  NetworkStyle style;               // batch-norm constants and the last convolution's initialiser
};
using NetworkFactory = std::function<std::unique_ptr<NetworkDecoder>(const NetworkSettings&)>;

// Registers the factory make_network_decoder uses (qdo_net's register_torch_network()).
void register_network_factory(NetworkFactory factory);
NetworkFactory registered_network_factory();  // the one registered (empty if none)
// A loader that registers the factory on first need: the qdo tool loads its LibTorch plugin
// (libqdo-net.so) only when a network is asked for, so commands without one do not pay LibTorch's
// ~0.5 s start-up. It returns "" on success, else why it failed (reported by the two calls below);
// it runs at most once per process.
using NetworkLoader = std::function<std::string()>;
void register_network_loader(NetworkLoader loader);
// Whether a factory is registered, after running the loader if there is one and no factory yet.
bool network_decoder_available();
// The CPU threads a network decoder computes with: QDO_TORCH_THREADS (an integer from 1 to 1024;
// InputError naming it otherwise), else the machine's hardware threads. LibTorch's reductions sum
// in an order that depends on it, so a network run records it (split.json) and a resume with
// another count is noted: the run then continues differently (about 1e-7 in the loss).
int network_threads();
// Why network_decoder_available() is false: the loader's message, or that none is built in.
std::string network_decoder_unavailable_reason();
// A fresh network; InputError naming `decoder` when no factory is registered (built without
// LibTorch, or the plugin failed to load: the reason is in the message).
std::unique_ptr<NetworkDecoder> make_network_decoder(const NetworkSettings& s);

// A network behind the Decoder interface (decoder.hpp), in inference mode: decode_batch() is one
// reconstruct() call (images 3 x S x S -> cubes `bands` x S x S), batch() = `batch` images per call.
// It either owns the network or refers to one the caller keeps alive (the joint trainer's).
class NetworkImageDecoder final : public Decoder {
 public:
  NetworkImageDecoder(std::unique_ptr<NetworkDecoder> net, std::size_t bands, std::size_t batch, std::string description = "");
  NetworkImageDecoder(NetworkDecoder& net, std::size_t bands, std::size_t batch, std::string description = "");
  RealStack decode(const RealStack& y) const override;
  std::vector<RealStack> decode_batch(const std::vector<RealStack>& ys) const override;
  std::size_t batch() const override { return batch_; }
  std::size_t bands() const override { return bands_; }
  std::size_t channels() const override { return 3; }
  std::string description() const override { return description_; }

 private:
  std::unique_ptr<NetworkDecoder> owned_;
  NetworkDecoder* net_;
  std::size_t bands_, batch_;
  std::string description_;
};

}  // namespace qdo
