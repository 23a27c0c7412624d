#include "qdo/net/resunet.hpp"

#include <cmath>
#include <string>
#include <utility>

#include "qdo/runtime/error.hpp"

namespace qdo {

namespace {
torch::nn::Conv2d conv(std::size_t in, std::size_t out, std::size_t k, bool bias) {
  return torch::nn::Conv2d(torch::nn::Conv2dOptions(std::int64_t(in), std::int64_t(out), std::int64_t(k))
                               .padding(std::int64_t(k / 2))
                               .bias(bias));
}

// He-uniform: U(-b, b), b = sqrt(6 / fan_in), fan_in = in_channels * k * k; drawn from `gen`.
void he_uniform(torch::nn::Conv2d& c, torch::Generator& gen) {
  torch::NoGradGuard guard;
  const auto& w = c->weight;
  const double fan_in = double(w.size(1) * w.size(2) * w.size(3));
  const double b = std::sqrt(6.0 / fan_in);
  w.copy_(torch::rand(w.sizes(), gen, w.options()) * (2 * b) - b);
  if (c->options.bias()) c->bias.zero_();
}
// Glorot-uniform (Keras' default, the release's last convolution): U(-b, b),
// b = sqrt(6 / (fan_in + fan_out)), fan_in = in_channels * k * k, fan_out = out_channels * k * k.
void glorot_uniform(torch::nn::Conv2d& c, torch::Generator& gen) {
  torch::NoGradGuard guard;
  const auto& w = c->weight;
  const double k2 = double(w.size(2) * w.size(3));
  const double b = std::sqrt(6.0 / (double(w.size(1)) * k2 + double(w.size(0)) * k2));
  w.copy_(torch::rand(w.sizes(), gen, w.options()) * (2 * b) - b);
  if (c->options.bias()) c->bias.zero_();
}
using RankSum = std::function<void(double*, std::size_t)>;

// A double tensor's values summed over the ranks (on the CPU, where MPI reads them).
torch::Tensor rank_summed(const torch::Tensor& t, const RankSum& sum) {
  torch::Tensor c = t.to(torch::kCPU, torch::kDouble).contiguous().clone();
  sum(c.data_ptr<double>(), std::size_t(c.numel()));
  return c;
}

// Synchronised batch norm (training mode) of x (B x C x H x W) with scale `weight` and shift
// `bias` (C each): statistics over every rank's batch. Forward: one sum of [Σx, Σx², count] per
// channel (in double); backward: one sum of [Σdy, Σdy·x̂]; dx = w/σ (dy - mean(dy) - x̂ mean(dy·x̂))
// with the global means. The parameter gradients are this rank's parts (the caller sums them with
// the others).
struct SyncBatchNorm : torch::autograd::Function<SyncBatchNorm> {
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& x, const torch::Tensor& weight,
                               const torch::Tensor& bias, torch::nn::BatchNorm2dImpl* bn, const RankSum* sum) {
    const std::int64_t c = x.size(1);
    const torch::Tensor xd = x.to(torch::kDouble);
    torch::Tensor stats = torch::cat({xd.sum({0, 2, 3}), (xd * xd).sum({0, 2, 3}),
                                      torch::full({1}, double(x.numel() / c), torch::kDouble).to(x.device())});
    stats = rank_summed(stats, *sum);
    const double n = stats[2 * c].item<double>();
    const torch::Tensor mean = stats.slice(0, 0, c) / n;
    const torch::Tensor var = (stats.slice(0, c, 2 * c) / n - mean * mean).clamp_min(0);
    const torch::Tensor invstd = (var + bn->options.eps()).rsqrt();
    const auto shape = std::vector<std::int64_t>{1, c, 1, 1};
    const torch::Tensor xhat = (x - mean.to(x.options()).view(shape)) * invstd.to(x.options()).view(shape);
    {
      torch::NoGradGuard guard;
      const double m = bn->options.momentum().value_or(0.1);
      bn->running_mean.mul_(1 - m).add_(mean.to(bn->running_mean.options()), m);
      bn->running_var.mul_(1 - m).add_((var * (n / std::max(n - 1, 1.0))).to(bn->running_var.options()), m);
      bn->num_batches_tracked.add_(1);
    }
    ctx->save_for_backward({xhat, invstd.to(x.options()), weight});
    ctx->saved_data["n"] = n;
    ctx->saved_data["sum"] = reinterpret_cast<std::int64_t>(sum);
    return xhat * weight.view(shape) + bias.view(shape);
  }
  static torch::autograd::variable_list backward(torch::autograd::AutogradContext* ctx, torch::autograd::variable_list grads) {
    const auto saved = ctx->get_saved_variables();
    const torch::Tensor &xhat = saved[0], &invstd = saved[1], &weight = saved[2], &dy = grads[0];
    const double n = ctx->saved_data["n"].toDouble();
    const auto* sum = reinterpret_cast<const RankSum*>(ctx->saved_data["sum"].toInt());
    const std::int64_t c = xhat.size(1);
    const torch::Tensor db = dy.sum({0, 2, 3}), dw = (dy * xhat).sum({0, 2, 3});
    const torch::Tensor g = rank_summed(torch::cat({db, dw}), *sum).to(dy.options());
    const auto shape = std::vector<std::int64_t>{1, c, 1, 1};
    const torch::Tensor dx = (weight * invstd).view(shape) *
                             (dy - (g.slice(0, 0, c) / n).view(shape) - xhat * (g.slice(0, c, 2 * c) / n).view(shape));
    return {dx, dw, db, torch::Tensor(), torch::Tensor()};
  }
};
}  // namespace

torch::Tensor ResUNetImpl::norm(torch::nn::BatchNorm2d& bn, const torch::Tensor& x) {
  if (!rank_sum_ || !is_training()) return bn(x);
  return SyncBatchNorm::apply(x, bn->weight, bn->bias, bn.get(), &rank_sum_);
}

ResUNetImpl::ResUNetImpl(std::size_t in_channels, std::size_t out_channels, std::size_t depth, std::size_t root,
                         std::uint64_t seed, const NetworkStyle& style)
    : in_(in_channels), out_(out_channels), depth_(depth), root_(root), style_(style) {
  if (in_channels < 1) reject("in_channels", in_channels, "at least 1");
  if (out_channels < 1) reject("out_channels", out_channels, "at least 1");
  if (depth < 1 || depth > 10) reject("depth", depth, "an integer from 1 to 10");
  if (root < 1 || root > 1024) reject("root", root, "an integer from 1 to 1024");
  const auto bn = [&](std::size_t c) {
    const BatchNormConstants k = batch_norm_constants(style.keras_batch_norm);
    return torch::nn::BatchNorm2d(torch::nn::BatchNorm2dOptions(std::int64_t(c)).momentum(k.momentum).eps(k.eps));
  };
  torch::Generator gen = at::detail::createCPUGenerator(seed);
  std::size_t c_in = in_channels;
  for (std::size_t i = 0; i < depth; ++i) {
    const std::size_t c = root << i;
    Down d;
    d.identity = register_module("down" + std::to_string(i) + "_identity", conv(c_in, c, 1, false));
    d.conv1 = register_module("down" + std::to_string(i) + "_conv1", conv(c_in, c, i == 0 ? 7 : 3, true));
    d.bn1 = register_module("down" + std::to_string(i) + "_bn1", bn(c));
    d.conv2 = register_module("down" + std::to_string(i) + "_conv2", conv(c, c, 3, true));
    d.bn2 = register_module("down" + std::to_string(i) + "_bn2", bn(c));
    for (auto* cv : {&d.identity, &d.conv1, &d.conv2}) he_uniform(*cv, gen);
    down_.push_back(d);
    c_in = c;
  }
  up_.resize(depth > 1 ? depth - 1 : 0);
  for (std::size_t k = depth - 1; k-- > 0;) {  // built deepest first, the order forward() uses them
    const std::size_t c = root << k;
    Up u;
    const std::string p = "up" + std::to_string(k);
    u.up_conv = register_module(p + "_upconv", conv(c_in, c, 1, true));
    u.conv1 = register_module(p + "_conv1", conv(2 * c, c, 3, true));
    u.bn1 = register_module(p + "_bn1", bn(c));
    u.conv2 = register_module(p + "_conv2", conv(c, c, 3, true));
    u.bn2 = register_module(p + "_bn2", bn(c));
    u.identity = register_module(p + "_identity", conv(2 * c, c, 1, false));
    for (auto* cv : {&u.up_conv, &u.conv1, &u.conv2, &u.identity}) he_uniform(*cv, gen);
    up_[k] = u;
    c_in = c;
  }
  final_ = register_module("final", conv(root, out_channels, 1, true));
  if (style.glorot_final) glorot_uniform(final_, gen);
  else he_uniform(final_, gen);
}

torch::Tensor ResUNetImpl::forward(const torch::Tensor& x) {
  if (x.dim() != 4 || x.size(1) != std::int64_t(in_))
    reject("network input", std::to_string(x.dim()) + "-d tensor", "batch x " + std::to_string(in_) + " x H x W (NCHW)");
  const std::int64_t m = std::int64_t(1) << (depth_ - 1);
  if (x.size(2) % m || x.size(3) % m)
    reject("network input size", std::to_string(x.size(2)) + " x " + std::to_string(x.size(3)),
           "H and W divisible by 2^(depth - 1) = " + std::to_string(m));
  std::vector<torch::Tensor> skips;
  torch::Tensor h = x;
  for (std::size_t i = 0; i < depth_; ++i) {
    Down& d = down_[i];
    const torch::Tensor a = torch::elu(norm(d.bn1, d.conv1(h)));
    h = torch::elu(d.identity(h) + norm(d.bn2, d.conv2(a)));
    if (i + 1 < depth_) {
      skips.push_back(h);
      h = torch::max_pool2d(h, 2);
    }
  }
  for (std::size_t k = depth_ - 1; k-- > 0;) {
    Up& u = up_[k];
    const torch::Tensor up = torch::elu(u.up_conv(torch::upsample_nearest2d(h, {h.size(2) * 2, h.size(3) * 2})));
    const torch::Tensor cat = torch::cat({up, skips[k]}, 1);
    const torch::Tensor a = torch::elu(norm(u.bn1, u.conv1(cat)));
    h = torch::elu(u.identity(cat) + norm(u.bn2, u.conv2(a)));
  }
  return torch::sigmoid(final_(h));
}

std::size_t ResUNetImpl::parameter_count() const {
  std::size_t n = 0;
  for (const auto& p : parameters()) n += std::size_t(p.numel());
  return n;
}

BatchNormConstants batch_norm_constants(bool keras) {
  return keras ? BatchNormConstants{0.01, 1e-3} : BatchNormConstants{0.1, 1e-5};
}

ResUNet make_resunet(const DecoderSpec& spec, std::size_t in_channels, std::size_t out_channels, std::uint64_t seed,
                     const NetworkStyle& style) {
  if (spec.kind != DecoderSpec::Kind::ResUNet) reject("decoder", spec.to_string(), "a resunet spec");
  return ResUNet(in_channels, out_channels, spec.depth, spec.root, seed, style);
}

}  // namespace qdo
