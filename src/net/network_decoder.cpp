// The Res-UNet (resunet.hpp) behind the core's NetworkDecoder interface (network_decoder.hpp):
// float32 tensors on LibTorch's device (network_device(): CUDA when the LibTorch found through
// Torch_DIR has it and a GPU is there, else the CPU; QDO_TORCH_DEVICE=cpu|cuda chooses), Adam (lr
// set per step by the design loop), the loss of
// Eq. 14 without the optics' term: MAE(x̂, x) + γ Σ ω² over the convolution weights (4-d
// parameters; batch-norm scales and biases are not decayed).
#include <torch/torch.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <sstream>
#include <thread>
#include <type_traits>
#include <utility>

#include "qdo/runtime/error.hpp"
#include "qdo/net/net.hpp"
#include "qdo/decode/network_decoder.hpp"
#include "qdo/net/resunet.hpp"

namespace qdo {
namespace {

// The key of Adam's per-parameter state: the parameter's TensorImpl address, as a string in
// LibTorch 1.x (c10::guts::to_string of the pointer) and as the pointer itself in 2.x.
using AdamStateKey = std::decay_t<decltype(std::declval<torch::optim::Adam&>().state())>::key_type;
template <class Key>
Key adam_key_of(c10::TensorImpl* p) {
  if constexpr (std::is_same_v<Key, std::string>) {
    std::ostringstream os;
    os << p;
    return os.str();
  } else {
    return static_cast<Key>(p);
  }
}
AdamStateKey adam_key(const torch::Tensor& t) { return adam_key_of<AdamStateKey>(t.unsafeGetTensorImpl()); }

// QDO_TORCH_DEVICE: cpu, cuda, or unset (cuda when available, else cpu).
torch::Device network_device() {
  const char* e = std::getenv("QDO_TORCH_DEVICE");
  const std::string want = e ? e : "";
  if (want == "cpu") return torch::kCPU;
  if (want == "cuda") {
    if (!torch::cuda::is_available())
      reject("QDO_TORCH_DEVICE", want, "cpu: this LibTorch has no CUDA, or no GPU is visible (Debian's libtorch-dev is CPU-only; "
                                       "configure with Torch_DIR pointing at a CUDA LibTorch)");
    return torch::kCUDA;
  }
  if (!want.empty()) reject("QDO_TORCH_DEVICE", want, "cpu, cuda, or unset (cuda when available)");
  return torch::cuda::is_available() ? torch::Device(torch::kCUDA) : torch::Device(torch::kCPU);
}

// A batch of same-shape stacks (planes x H x W each) as a B x planes x H x W float tensor.
torch::Tensor to_tensor(const std::vector<RealStack>& xs, const char* what) {
  if (xs.empty()) reject(what, "an empty batch", "at least one image");
  const RealStack& a = xs.front();
  torch::Tensor t = torch::empty({std::int64_t(xs.size()), std::int64_t(a.planes), std::int64_t(a.rows), std::int64_t(a.cols)},
                                 torch::kFloat);
  float* p = t.data_ptr<float>();
  for (std::size_t k = 0; k < xs.size(); ++k) {
    const RealStack& x = xs[k];
    if (x.planes != a.planes || x.rows != a.rows || x.cols != a.cols)
      reject(std::string(what) + "[" + std::to_string(k) + "]", shape(x), "the shape of the first, " + shape(a));
    for (double v : x.data) *p++ = float(v);
  }
  return t;
}

std::vector<RealStack> from_tensor(const torch::Tensor& t) {
  const torch::Tensor c = t.detach().to(torch::kCPU).to(torch::kDouble).contiguous();
  std::vector<RealStack> out;
  const double* p = c.data_ptr<double>();
  for (std::int64_t k = 0; k < c.size(0); ++k) {
    RealStack x(std::size_t(c.size(1)), std::size_t(c.size(2)), std::size_t(c.size(3)));
    std::copy(p, p + x.data.size(), x.data.begin());
    p += x.data.size();
    out.push_back(std::move(x));
  }
  return out;
}

class TorchNetworkDecoder final : public NetworkDecoder {
 public:
  explicit TorchNetworkDecoder(const NetworkSettings& s)
      : settings_(s),
        device_(network_device()),
        net_(make_resunet(s.spec, s.in_channels, s.out_channels, s.seed, s.style)),
        adam_((net_->to(device_), net_->parameters()), torch::optim::AdamOptions(1e-3)) {
    if (!(s.weight_decay_gamma >= 0) || !std::isfinite(s.weight_decay_gamma))
      reject("gamma_decoder", s.weight_decay_gamma, ">= 0 (γ of Eq. 14)");
    if (device_.is_cuda()) {
      // A resumed run repeats the uninterrupted one bit for bit only with reproducible kernels:
      // cuDNN's default convolution backward sums with atomics in varying order, and its
      // autotuner may pick another algorithm per process. Ops without a deterministic CUDA
      // kernel warn (none in the Res-UNet: convolutions, batch norm, max-pool, nearest upsampling).
      at::globalContext().setDeterministicCuDNN(true);
      at::globalContext().setBenchmarkCuDNN(false);
      at::globalContext().setDeterministicAlgorithms(true, /*warn_only=*/true);
    }
  }
  std::string spec() const override { return settings_.spec.to_string(); }
  std::size_t parameter_count() const override { return net_->parameter_count(); }

  NetworkStep train(const std::vector<RealStack>& images, const std::vector<RealStack>& targets, double lr) override {
    check_lr(lr);
    NetworkStep r = backward(images, targets, 1.0, true);
    step(lr);
    return r;
  }

  NetworkStep backward(const std::vector<RealStack>& images, const std::vector<RealStack>& targets, double data_weight,
                       bool regularise) override {
    if (images.size() != targets.size())
      reject("targets", std::to_string(targets.size()) + " cubes", "one per image (" + std::to_string(images.size()) + ")");
    if (!(data_weight > 0) || data_weight > 1) reject("data_weight", data_weight, "a share of the batch in (0, 1]");
    net_->train();
    torch::Tensor x = to_tensor(images, "images").to(device_).requires_grad_(true);
    const torch::Tensor target = to_tensor(targets, "targets").to(device_);
    adam_.zero_grad();
    const torch::Tensor out = net_->forward(x);
    if (out.sizes() != target.sizes())
      reject("targets", shape(targets.front()), "the network's output shape per image");
    const torch::Tensor mae = (out - target).abs().mean();
    torch::Tensor reg = torch::zeros({}, torch::TensorOptions().dtype(torch::kFloat).device(device_));
    if (regularise)
      for (const auto& p : net_->parameters())
        if (p.dim() == 4) reg = reg + p.pow(2).sum();
    // data_weight 1 (one process): the loss exactly as before data-parallel training existed.
    const torch::Tensor loss = (data_weight == 1 ? mae : mae * data_weight) + settings_.weight_decay_gamma * reg;
    loss.backward();
    NetworkStep r;
    r.loss = loss.item<double>();
    r.mae = mae.item<double>() * data_weight;
    const double mse = (out.detach() - target).pow(2).mean().item<double>();
    r.psnr_db = data_weight == 1 ? (mse > 0 ? 10 * std::log10(1 / mse) : INFINITY) : mse * data_weight;
    r.grad_images = from_tensor(x.grad());
    return r;
  }

  void set_rank_sum(RankSum sum) override { net_->set_rank_sum(std::move(sum)); }

  void read_gradients(double* out) const override {
    for (const auto& p : net_->parameters()) {
      const std::int64_t n = p.numel();
      if (p.grad().defined()) {
        const torch::Tensor g = p.grad().detach().to(torch::kCPU, torch::kDouble).contiguous();
        std::copy(g.data_ptr<double>(), g.data_ptr<double>() + n, out);
      } else {
        std::fill(out, out + n, 0.0);
      }
      out += n;
    }
  }

  void apply_gradients(const double* grad, double lr) override {
    check_lr(lr);
    {
      torch::NoGradGuard guard;
      for (auto& p : net_->parameters()) {
        const std::int64_t n = p.numel();
        const torch::Tensor g = torch::from_blob(const_cast<double*>(grad), p.sizes(), torch::kDouble).to(p.options());
        if (p.grad().defined()) p.mutable_grad().copy_(g);
        else p.mutable_grad() = g.clone();
        grad += n;
      }
    }
    step(lr);
  }

  std::vector<RealStack> reconstruct(const std::vector<RealStack>& images) override {
    torch::NoGradGuard guard;
    net_->eval();
    return from_tensor(net_->forward(to_tensor(images, "images").to(device_)));
  }

  std::string save() const override {
    // Adam's state is written per parameter in the network's parameter order (LibTorch's own
    // serialisation keys it by tensor addresses, in hash-map order: the bytes would differ from
    // run to run for the same state). Its options are not stored: lr is set every step.
    torch::serialize::OutputArchive ar, net_ar, adam_ar;
    net_->save(net_ar);
    const auto params = net_->parameters();
    const auto& state = adam_.state();
    adam_ar.write("count", c10::IValue(std::int64_t(params.size())));
    for (std::size_t i = 0; i < params.size(); ++i) {
      const auto it = state.find(adam_key(params[i]));
      if (it == state.end()) continue;
      const auto& st = static_cast<const torch::optim::AdamParamState&>(*it->second);
      const std::string k = std::to_string(i);
      adam_ar.write("step_" + k, c10::IValue(st.step()));
      adam_ar.write("m_" + k, st.exp_avg());
      adam_ar.write("v_" + k, st.exp_avg_sq());
    }
    ar.write("qdo_network_format", c10::IValue(std::int64_t(1)));
    ar.write("spec", c10::IValue(spec()));
    ar.write("out_channels", c10::IValue(std::int64_t(settings_.out_channels)));
    ar.write("net", net_ar);
    ar.write("adam", adam_ar);
    std::ostringstream os;
    ar.save_to(os);
    return os.str();
  }

  void load(const std::string& bytes, const std::string& origin) override {
    torch::serialize::InputArchive ar;
    try {
      std::istringstream is(bytes);
      ar.load_from(is, device_);
    } catch (const c10::Error& e) {
      throw InputError("file '" + origin + "': not a network state written by qdo (LibTorch: " + first_line(e.what()) + ")");
    }
    c10::IValue fmt, spec_v, out_v;
    if (!ar.try_read("qdo_network_format", fmt) || !ar.try_read("spec", spec_v) || !ar.try_read("out_channels", out_v) ||
        !spec_v.isString() || !out_v.isInt())
      throw InputError("file '" + origin + "': not a network state written by qdo (format, spec or band count missing)");
    const std::string stored = spec_v.toStringRef();
    if (stored != spec() || out_v.toInt() != std::int64_t(settings_.out_channels))
      throw InputError("file '" + origin + "': holds a " + stored + " network with " + std::to_string(out_v.toInt()) +
                       " output bands; the run asks for " + spec() + " with " + std::to_string(settings_.out_channels) +
                       " (a checkpoint of another architecture)");
    try {
      torch::serialize::InputArchive net_ar, adam_ar;
      ar.read("net", net_ar);
      ar.read("adam", adam_ar);
      net_->load(net_ar);
      const auto params = net_->parameters();
      c10::IValue count;
      adam_ar.read("count", count);
      if (!count.isInt() || count.toInt() != std::int64_t(params.size()))
        throw InputError("file '" + origin + "': the optimiser state holds another parameter count");
      auto& state = adam_.state();
      state.clear();
      for (std::size_t i = 0; i < params.size(); ++i) {
        const std::string k = std::to_string(i);
        c10::IValue step;
        if (!adam_ar.try_read("step_" + k, step)) continue;  // no Adam step taken on it yet
        torch::Tensor m, v;
        adam_ar.read("m_" + k, m);
        adam_ar.read("v_" + k, v);
        if (!step.isInt() || !m.sizes().equals(params[i].sizes()) || !v.sizes().equals(params[i].sizes()))
          throw InputError("file '" + origin + "': the optimiser state of parameter " + k + " does not fit the network");
        auto st = std::make_unique<torch::optim::AdamParamState>();
        st->step(step.toInt());
        st->exp_avg(m);
        st->exp_avg_sq(v);
        state[adam_key(params[i])] = std::move(st);
      }
    } catch (const c10::Error& e) {
      throw InputError("file '" + origin + "': the network state does not load into " + spec() + " (LibTorch: " +
                       first_line(e.what()) + ")");
    }
  }

 private:
  static std::string first_line(const std::string& s) { return s.substr(0, s.find('\n')); }
  static void check_lr(double lr) {
    if (!(lr >= 0) || !std::isfinite(lr)) reject("lr_decoder", lr, "a finite learning rate >= 0");
  }
  void step(double lr) {  // one Adam step on the gradients held
    for (auto& g : adam_.param_groups()) static_cast<torch::optim::AdamOptions&>(g.options()).lr(lr);
    adam_.step();
  }
  NetworkSettings settings_;
  torch::Device device_;
  ResUNet net_;
  torch::optim::Adam adam_;
};

}  // namespace

void register_torch_network() {
  torch::set_num_threads(network_threads());  // QDO_TORCH_THREADS, checked, else the hardware threads
  register_network_factory([](const NetworkSettings& s) -> std::unique_ptr<NetworkDecoder> {
    return std::make_unique<TorchNetworkDecoder>(s);
  });
}

}  // namespace qdo

// The entry point of the plugin module libqdo-net.so (CMake target qdo_net_plugin), which the qdo
// tool dlopen()s when a network decoder is first asked for (src/cli/net_plugin.cpp).
extern "C" __attribute__((visibility("default"))) void qdo_net_plugin_register() { qdo::register_torch_network(); }
