// The Res-UNet decoder (include/qdo/net/resunet.hpp, LibTorch) and the whole chain's gradient: heights
// -> PSF (OpenCL) -> camera (OpenCL) -> network (LibTorch) -> loss, its analytic gradient dL/dH
// (LibTorch's backward, then qdo's camera and PSF adjoints) against central differences, in double.
#include <cmath>
#include <random>
#include <tuple>

#include "torch_common.hpp"  // LibTorch, then doctest's CHECK macros and the common helpers
#include "qdo/physics/doe.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/physics/simulator.hpp"

using namespace qdo;
using namespace qdo::test;

namespace {

// Trainable values of the architecture in resunet.hpp, counted from its description.
std::size_t expected_parameters(std::size_t in, std::size_t out, std::size_t depth, std::size_t root) {
  std::size_t n = 0, c_in = in;
  for (std::size_t i = 0; i < depth; ++i) {
    const std::size_t c = root << i, k = i == 0 ? 7 : 3;
    n += c_in * c;                    // 1x1 identity, no bias
    n += k * k * c_in * c + c + 2 * c;  // conv1 + bias, batch norm
    n += 9 * c * c + c + 2 * c;         // conv2 + bias, batch norm
    c_in = c;
  }
  for (std::size_t i = depth - 1; i-- > 0;) {
    const std::size_t c = root << i;
    n += c_in * c + c;                     // 1x1 after up-sampling
    n += 9 * 2 * c * c + c + 2 * c;        // conv on the concatenation, batch norm
    n += 9 * c * c + c + 2 * c;            // second conv, batch norm
    n += 2 * c * c;                        // 1x1 identity of the concatenation
    c_in = c;
  }
  return n + root * out + out;  // final 1x1
}

torch::Tensor to_tensor(const RealStack& s) {  // planes x H x W -> 1 x planes x H x W (double)
  return torch::from_blob(const_cast<double*>(s.data.data()),
                          {1, std::int64_t(s.planes), std::int64_t(s.rows), std::int64_t(s.cols)}, torch::kDouble)
      .clone();
}

}  // namespace

TEST_SUITE("net") {
  TEST_CASE("Res-UNet: parameter count, output shape and range, seeded initialisation, refusals") {
    for (auto [depth, root] : {std::pair<std::size_t, std::size_t>{1, 4}, {3, 4}, {4, 16}}) {
      CAPTURE(depth);
      CAPTURE(root);
      ResUNet net(3, 31, depth, root, 7);
      CHECK(net->parameter_count() == expected_parameters(3, 31, depth, root));
      const torch::Tensor x = torch::rand({2, 3, 16, 24});
      const torch::Tensor y = net->forward(x);
      CHECK(y.sizes() == torch::IntArrayRef({2, 31, 16, 24}));
      CHECK(y.min().item<double>() >= 0.0);  // a float32 sigmoid may round to exactly 0 or 1
      CHECK(y.max().item<double>() <= 1.0);
      CHECK(y.max().item<double>() > y.min().item<double>());
      // The same seed gives the same network; another seed another one.
      ResUNet same(3, 31, depth, root, 7), other(3, 31, depth, root, 8);
      const auto pa = net->parameters(), pb = same->parameters(), pc = other->parameters();
      bool equal = true, differ = false;
      for (std::size_t i = 0; i < pa.size(); ++i) {
        equal = equal && torch::equal(pa[i], pb[i]);
        differ = differ || !torch::equal(pa[i], pc[i]);
      }
      CHECK(equal);
      CHECK(differ);
      // He-uniform: every conv weight within sqrt(6 / fan_in), and spread over most of it.
      for (const auto& kv : net->named_parameters()) {
        if (kv.value().dim() != 4) continue;
        const double fan_in = double(kv.value().size(1) * kv.value().size(2) * kv.value().size(3));
        const double bound = std::sqrt(6.0 / fan_in), m = kv.value().abs().max().item<double>();
        CAPTURE(kv.key());
        CHECK(m <= bound);
        if (kv.value().numel() >= 64) CHECK(m >= 0.8 * bound);
      }
    }
    // The paper's size: REFERENCE §3 says about 1.2e8 parameters at depth 7 (the count formula is
    // checked against the module above; building the paper's network here would take 0.5 GB).
    CHECK(expected_parameters(3, 31, 7, 32) == 121658655);
    ResUNet net(3, 31, 3, 4, 1);
    CHECK_THROWS_WITH_AS(net->forward(torch::rand({1, 3, 10, 16})), doctest::Contains("divisible"), InputError);
    CHECK_THROWS_WITH_AS(net->forward(torch::rand({1, 2, 16, 16})), doctest::Contains("network input"), InputError);
    CHECK_THROWS_WITH_AS(ResUNet(3, 31, 0, 4, 1), doctest::Contains("depth"), InputError);
    CHECK_THROWS_WITH_AS(ResUNet(3, 31, 3, 0, 1), doctest::Contains("root"), InputError);
  }

  TEST_CASE("the release's network style: Keras batch-norm constants and a Glorot-uniform last convolution") {
    NetworkStyle keras;
    keras.keras_batch_norm = true;
    keras.glorot_final = true;
    ResUNet k(3, 31, 2, 4, 5, keras), t(3, 31, 2, 4, 5);
    // Every batch norm: momentum 0.01 (Keras' 0.99) and eps 1e-3, or torch's 0.1 and 1e-5.
    std::size_t norms = 0;
    for (const auto& [net, m, eps] : {std::tuple<ResUNet*, double, double>{&k, 0.01, 1e-3}, {&t, 0.1, 1e-5}})
      for (const auto& mod : (*net)->modules(false))
        if (const auto* bn = mod->as<torch::nn::BatchNorm2dImpl>()) {
          CHECK(bn->options.momentum().value() == m);
          CHECK(bn->options.eps() == eps);
          ++norms;
        }
    CHECK(norms == 2 * 6);  // per network: 2 per block, 2 down blocks and 1 up block at depth 2
    // The running mean moves by momentum x the batch mean in one training forward.
    k->train();
    const torch::Tensor x = torch::rand({2, 3, 8, 8}) + 1.0;
    k->forward(x);
    for (const auto& mod : k->modules(false))
      if (const auto* bn = mod->as<torch::nn::BatchNorm2dImpl>()) {
        CHECK(bn->running_mean.abs().max().item<double>() > 0);
        break;
      }
    // The last 1x1 convolution (root 4 -> 31): Glorot's bound sqrt(6 / (4 + 31)) against He's sqrt(6 / 4).
    const torch::Tensor wk = k->named_parameters()["final.weight"], wt = t->named_parameters()["final.weight"];
    const double glorot = std::sqrt(6.0 / 35.0), he = std::sqrt(6.0 / 4.0);
    CHECK(wk.abs().max().item<double>() <= glorot);
    CHECK(wk.abs().max().item<double>() >= 0.8 * glorot);
    CHECK(wt.abs().max().item<double>() > glorot);
    CHECK(wt.abs().max().item<double>() <= he);
    // The rest of the network is drawn as before: the same seed, the same first convolution.
    CHECK(torch::equal(k->named_parameters()["down0_conv1.weight"], t->named_parameters()["down0_conv1.weight"]));
    const BatchNormConstants kc = batch_norm_constants(true), tc = batch_norm_constants(false);
    CHECK(kc.momentum == 0.01);
    CHECK(tc.eps == 1e-5);
  }

  TEST_CASE("the whole chain's gradient: heights -> optics -> camera -> network -> loss, against central differences") {
    if (!skip_unless(runtime().has_fp64(), "float64 device: the chain's gradient check runs in double")) return;
    const SystemConfig c = tiny_config(32, 3);
    const std::size_t s = c.sensor_size_px();
    std::mt19937_64 rng(3);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    RealStack scene(c.bands, 16, 16), target(c.bands, 16, 16);
    for (double& v : scene.data) v = 0.1 + 0.8 * u(rng);
    for (double& v : target.data) v = u(rng);
    torch::manual_seed(0);
    ResUNet net(3, c.bands, 3, 4, 5);
    net->to(torch::kDouble);
    net->eval();  // batch norm with its (initial) running statistics: a fixed function of the image
    Simulator sim(runtime(), c, Precision::F64);
    Camera cam(sim);
    const torch::Tensor t_target = to_tensor(target);
    // Loss (Eq. 14's data term): mean absolute error of the network's reconstruction.
    auto loss_at = [&](const Map2D& h) {
      sim.set_heights(h);
      sim.compute_psf();
      const RealStack rgb = cam.images({scene}, no_skipping()).front();
      torch::NoGradGuard ng;
      return (net->forward(to_tensor(rgb)) - t_target).abs().mean().item<double>();
    };
    Map2D h = lens_design(c, 550);
    // Heights kept 1 % of h_max inside [0, 2 h_max], so the difference steps below stay valid.
    for (double& v : h.data)
      v = std::min(1.99 * c.h_max_m(), std::max(0.01 * c.h_max_m(), v + 0.05 * c.h_max_m() * (u(rng) - 0.5)));
    // Analytic: LibTorch's backward to the RGB image, then the camera and PSF adjoints.
    sim.set_heights(h);
    sim.compute_psf();
    const RealStack rgb = cam.images({scene}, no_skipping()).front();
    torch::Tensor t_rgb = to_tensor(rgb).requires_grad_(true);
    const torch::Tensor loss = (net->forward(t_rgb) - t_target).abs().mean();
    loss.backward();
    const torch::Tensor g = t_rgb.grad().contiguous();
    RealStack g_rgb(3, rgb.rows, rgb.cols);
    std::copy(g.data_ptr<double>(), g.data_ptr<double>() + g.numel(), g_rgb.data.begin());
    const RealStack g_psf = cam.vjp({g_rgb}, false).psf;
    const Map2D g_h = sim.psf_sensor_vjp(g_psf);
    CHECK(loss.item<double>() == doctest::Approx(loss_at(h)).epsilon(1e-12));
    // Directional derivative along a random direction, then central differences on the 6 heights
    // with the largest gradient inside the aperture.
    const double step = 1e-3 * c.h_max_m();
    Map2D dir(c.n, c.n);
    for (double& v : dir.data) v = u(rng) - 0.5;
    Map2D hp = h, hm = h;
    double analytic = 0;
    for (std::size_t i = 0; i < h.data.size(); ++i) {
      hp.data[i] += step * dir.data[i];
      hm.data[i] -= step * dir.data[i];
      analytic += g_h.data[i] * dir.data[i];
    }
    const double numeric = (loss_at(hp) - loss_at(hm)) / (2 * step);
    CAPTURE(analytic);
    CAPTURE(numeric);
    CHECK(std::fabs(analytic - numeric) <= 1e-5 * std::fabs(analytic));
    std::vector<std::size_t> order(h.data.size());
    for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
    std::partial_sort(order.begin(), order.begin() + 6, order.end(),
                      [&](std::size_t a, std::size_t b) { return std::fabs(g_h.data[a]) > std::fabs(g_h.data[b]); });
    double gmax = std::fabs(g_h.data[order[0]]);
    for (int k = 0; k < 6; ++k) {
      const std::size_t i = order[std::size_t(k)];
      Map2D a = h, b = h;
      a.data[i] += step;
      b.data[i] -= step;
      const double fd = (loss_at(a) - loss_at(b)) / (2 * step);
      CAPTURE(i);
      CHECK(std::fabs(fd - g_h.data[i]) <= 1e-4 * gmax);
    }
    (void)s;
  }
}
