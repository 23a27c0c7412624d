// Shared by the joint-training tests (test_joint.cpp, test_joint_files.cpp): a stand-in network
// written in plain C++ (a per-pixel affine map RGB -> bands trained by Adam on the MSE), so network
// runs are tested without LibTorch, its factory guard, and a tiny network run's options.
#pragma once
#include <cmath>
#include <cstring>
#include <memory>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "common.hpp"
#include "qdo/design/design_run.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/decode/network_decoder.hpp"

namespace qdo::test {

// x̂_b(p) = sum_c W[b][c] y_c(p) + c_b; loss = mean (x̂ - x)²; Adam on (W, c).
class AffineNet final : public NetworkDecoder {
 public:
  explicit AffineNet(const NetworkSettings& s) : s_(s), w_(s.out_channels * 4, 0.0), m_(w_.size(), 0.0), v_(w_.size(), 0.0) {
    std::mt19937_64 rng(s.seed);
    std::uniform_real_distribution<double> u(-0.5, 0.5);
    for (double& x : w_) x = u(rng);
  }
  std::string spec() const override { return s_.spec.to_string(); }
  std::size_t parameter_count() const override { return w_.size(); }
  NetworkStep train(const std::vector<RealStack>& y, const std::vector<RealStack>& x, double lr) override {
    NetworkStep r;
    std::vector<double> g(w_.size(), 0.0);
    double n = 0;
    for (const auto& xi : x) n += double(xi.size());
    double sse = 0;
    for (std::size_t k = 0; k < y.size(); ++k) {
      RealStack gy(3, y[k].rows, y[k].cols, 0.0);
      const RealStack xh = apply(y[k]);
      for (std::size_t b = 0; b < xh.planes; ++b)
        for (std::size_t p = 0; p < xh.plane_size(); ++p) {
          const double e = xh.plane(b)[p] - x[k].plane(b)[p];
          sse += e * e;
          const double d = 2 * e / n;
          for (std::size_t c = 0; c < 3; ++c) {
            g[b * 4 + c] += d * y[k].plane(c)[p];
            gy.plane(c)[p] += d * w_[b * 4 + c];
          }
          g[b * 4 + 3] += d;
        }
      r.grad_images.push_back(std::move(gy));
    }
    r.mae = r.loss = sse / n;
    r.psnr_db = 10 * std::log10(1 / r.loss);
    ++t_;
    for (std::size_t i = 0; i < w_.size(); ++i) {  // Adam
      m_[i] = 0.9 * m_[i] + 0.1 * g[i];
      v_[i] = 0.999 * v_[i] + 0.001 * g[i] * g[i];
      const double mh = m_[i] / (1 - std::pow(0.9, double(t_))), vh = v_[i] / (1 - std::pow(0.999, double(t_)));
      w_[i] -= lr * mh / (std::sqrt(vh) + 1e-8);
    }
    return r;
  }
  std::vector<RealStack> reconstruct(const std::vector<RealStack>& y) override {
    std::vector<RealStack> out;
    for (const auto& yi : y) out.push_back(apply(yi));
    return out;
  }
  std::string save() const override {
    std::string b = "affine " + spec() + "\n";
    auto put = [&](const std::vector<double>& v) { b.append(reinterpret_cast<const char*>(v.data()), v.size() * sizeof(double)); };
    put(w_);
    put(m_);
    put(v_);
    b.append(reinterpret_cast<const char*>(&t_), sizeof t_);
    return b;
  }
  void load(const std::string& bytes, const std::string& origin) override {
    const std::string head = "affine " + spec() + "\n";
    if (bytes.rfind("affine ", 0) != 0) throw InputError("file '" + origin + "': not an affine network");
    if (bytes.compare(0, head.size(), head) != 0)
      throw InputError("file '" + origin + "': holds " + bytes.substr(7, bytes.find('\n') - 7) + ", the run asks for " + spec());
    if (bytes.size() != head.size() + 3 * w_.size() * sizeof(double) + sizeof t_) throw InputError("file '" + origin + "': truncated");
    const char* p = bytes.data() + head.size();
    for (auto* v : {&w_, &m_, &v_}) {
      std::memcpy(v->data(), p, v->size() * sizeof(double));
      p += v->size() * sizeof(double);
    }
    std::memcpy(&t_, p, sizeof t_);
  }

 private:
  RealStack apply(const RealStack& y) const {
    RealStack xh(s_.out_channels, y.rows, y.cols);
    for (std::size_t b = 0; b < xh.planes; ++b)
      for (std::size_t p = 0; p < xh.plane_size(); ++p)
        xh.plane(b)[p] = w_[b * 4] * y.plane(0)[p] + w_[b * 4 + 1] * y.plane(1)[p] + w_[b * 4 + 2] * y.plane(2)[p] + w_[b * 4 + 3];
    return xh;
  }
  NetworkSettings s_;
  std::vector<double> w_, m_, v_;
  long t_ = 0;
};

// Registers AffineNet as the network for the guard's lifetime, then puts back what was there.
struct AffineFactory {
  NetworkFactory previous = registered_network_factory();
  AffineFactory() {
    register_network_factory([](const NetworkSettings& s) -> std::unique_ptr<NetworkDecoder> { return std::make_unique<AffineNet>(s); });
  }
  ~AffineFactory() { register_network_factory(previous); }
};

inline DesignRunOptions net_run(const std::string& out, DesignMode mode) {
  DesignRunOptions o;
  o.cfg = tiny_config(32, 3);  // S = 16
  o.design.mode = mode;
  o.design.quantizer.levels = 4;
  o.design.steps_per_epoch = 2;
  o.design.t0_epochs = 1;
  o.design.t1_epochs = 2;
  o.design.seed = 3;
  o.epochs = 3;
  o.synthetic_scenes = 3;
  o.checkpoint_every = 2;
  o.batch = 2;
  o.decoder = decoder_spec_from_string("resunet:depth=2,root=4");
  o.objective = Objective::Network;
  o.lr_decoder = 0.05;
  o.precision = runtime().has_fp64() ? Precision::F64 : Precision::F32;
  o.out = out;
  o.quiet = true;
  return o;
}

}  // namespace qdo::test
