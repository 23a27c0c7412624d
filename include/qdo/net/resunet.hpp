// The paper's decoder (REFERENCE §3): a residual UNet in LibTorch's C++ API (Debian libtorch-dev,
// or another LibTorch through Torch_DIR). Built only with QDO_TORCH (target qdo_net).
//
// Tensors are NCHW: input batch x in_channels x H x W (the RGB sensor images, 3 channels), output
// batch x out_channels x H x W (the bands), in [0, 1] (final sigmoid). H and W must be divisible by
// 2^(depth - 1) (max-pool down, nearest up-sampling by 2 per level); forward() refuses others.
//
// Level i (0 .. depth-1) has c_i = root * 2^i filters. Down level i: a residual block
//   y = ELU( conv1x1_nobias(x) + BN(conv3x3(ELU(BN(conv_k(x))))) ),  k = 7 at level 0, else 3,
// then, except at the deepest level, a 2x2 max-pool (the block's output is kept for the skip).
// Up level i (depth-2 .. 0): u = ELU(conv1x1(upsample2(x))) with c_i filters, concatenated with the
// skip of level i (2 c_i channels), then y = ELU( conv1x1_nobias(cat) + BN(conv3x3(ELU(BN(conv3x3(cat))))) ).
// Last: conv1x1 to out_channels, sigmoid. Batch norm before ELU; convolutions "same"-padded with
// bias (except the 1x1 identities); He-uniform weights (bound sqrt(6 / fan_in)), zero biases,
// batch-norm scale 1 and shift 0. NetworkStyle (network_decoder.hpp) picks the batch-norm constants
// (torch's momentum 0.1, eps 1e-5, or Keras' 0.01 = "0.99", 1e-3, the release's) and the last
// convolution's initialiser (He-uniform, or Glorot-uniform, bound sqrt(6 / (fan_in + fan_out)), the
// release's).
#pragma once
#include <torch/torch.h>

#include <cstddef>
#include <cstdint>
#include <functional>

#include "qdo/decode/decoder_spec.hpp"
#include "qdo/decode/network_decoder.hpp"

namespace qdo {

struct ResUNetImpl : torch::nn::Module {
  // in_channels >= 1, out_channels >= 1, depth in [1, 10], root >= 1 (InputError otherwise).
  // The initial weights are drawn from a generator seeded with `seed`, so a network is
  // reproducible (torch's global generator is left untouched).
  ResUNetImpl(std::size_t in_channels, std::size_t out_channels, std::size_t depth, std::size_t root, std::uint64_t seed,
              const NetworkStyle& style = {});
  torch::Tensor forward(const torch::Tensor& x);

  std::size_t depth() const { return depth_; }
  std::size_t root() const { return root_; }
  const NetworkStyle& style() const { return style_; }
  std::size_t parameter_count() const;  // trainable values (batch-norm running statistics excluded)
  // Data-parallel training: the element-wise sum over the ranks (in place, n doubles). While one is
  // set, batch norm in training mode normalises with the statistics of the union of the ranks'
  // batches (synchronised batch norm: one sum per layer in forward, one in backward; running
  // statistics updated with the global mean and unbiased variance), so every rank computes what
  // one process with the whole batch does. Empty (the default): each batch norm on its own batch.
  void set_rank_sum(std::function<void(double* data, std::size_t n)> sum) { rank_sum_ = std::move(sum); }

 private:
  struct Down {
    torch::nn::Conv2d identity{nullptr}, conv1{nullptr}, conv2{nullptr};
    torch::nn::BatchNorm2d bn1{nullptr}, bn2{nullptr};
  };
  struct Up {
    torch::nn::Conv2d up_conv{nullptr}, conv1{nullptr}, conv2{nullptr}, identity{nullptr};
    torch::nn::BatchNorm2d bn1{nullptr}, bn2{nullptr};
  };
  torch::Tensor norm(torch::nn::BatchNorm2d& bn, const torch::Tensor& x);  // bn(x), synchronised under rank_sum_
  std::function<void(double*, std::size_t)> rank_sum_;
  std::size_t in_, out_, depth_, root_;
  NetworkStyle style_;
  std::vector<Down> down_;
  std::vector<Up> up_;  // up_[i] is level i (i < depth - 1)
  torch::nn::Conv2d final_{nullptr};
};
TORCH_MODULE(ResUNet);

// The network a DecoderSpec of kind ResUNet describes.
ResUNet make_resunet(const DecoderSpec& spec, std::size_t in_channels, std::size_t out_channels, std::uint64_t seed,
                     const NetworkStyle& style = {});

// Batch norm's running-average momentum (torch's convention: new = (1 - m) old + m batch) and eps.
struct BatchNormConstants {
  double momentum, eps;
};
// keras: the release's (momentum 0.99 in Keras' convention = 0.01 here, eps 1e-3); else torch's
// defaults (0.1, 1e-5).
BatchNormConstants batch_norm_constants(bool keras);

}  // namespace qdo
