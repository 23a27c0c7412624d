// bench_train: the cost of one joint-training step with the pieces that exist:
// the optics forward (OpenCL PSF), the camera (OpenCL, a batch of scenes), the Res-UNet forward +
// backward (LibTorch, MAE loss against the scenes), the adjoints back to the heights (OpenCL camera
// and PSF adjoints) and the network's Adam step, each timed alone (median of --repeats after one
// warm-up), then the whole step. The question it answers: is the physics the bottleneck of joint
// training (the goal: at the small preset the optics' share at most the network's)?
// Speed is never asserted. Peak resident memory (VmHWM) is printed at the end.
//
// Usage: bench_train [--presets small,paper] [--decoder resunet] [--batch 4] [--repeats 3]
//                    [--precision f32] [--out FILE.md]
#include <algorithm>
#include <cstdio>
#include <fstream>
#include <random>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "qdo/physics/camera.hpp"
#include "qdo/net/resunet.hpp"
#include "qdo/design/design.hpp"
#include "qdo/decode/testset.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/design/joint.hpp"
#include "qdo/net/net.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/sensor_reference.hpp"

#include "../bench_util.hpp"

using namespace qdo;

namespace {

// Median in seconds of `repeats` runs of f() after one unmeasured warm-up run.
template <typename F>
double median_time(int repeats, F&& f) {
  return qdo::bench::median_seconds(1, repeats, std::forward<F>(f));
}

using qdo::bench::peak_rss_kib;
using qdo::split_items;

torch::Tensor batch_tensor(const std::vector<RealStack>& xs) {  // each planes x H x W -> B x planes x H x W (float)
  std::vector<torch::Tensor> ts;
  for (const auto& x : xs)
    ts.push_back(torch::from_blob(const_cast<double*>(x.data.data()),
                                  {std::int64_t(x.planes), std::int64_t(x.rows), std::int64_t(x.cols)}, torch::kDouble)
                     .to(torch::kFloat));
  return torch::stack(ts);
}

}  // namespace

int main(int argc, char** argv) {
  std::vector<std::string> presets{"small", "paper"};
  std::string decoder = "resunet", out;
  int repeats = 3;
  std::size_t batch = 4;
  Precision prec = Precision::F32;
  for (int i = 1; i < argc; i += 2) {  // --help, or a flag without its value, prints the usage (exit 2)
    const std::string k = i + 1 < argc ? argv[i] : "--help", v = i + 1 < argc ? argv[i + 1] : "";
    if (k == "--presets") presets = split_items(v);
    else if (k == "--decoder") decoder = v;
    else if (k == "--batch") batch = std::size_t(std::stoul(v));
    else if (k == "--repeats") repeats = std::stoi(v);
    else if (k == "--precision") prec = precision_from_string(v);
    else if (k == "--out") out = v;
    else {
      std::fprintf(stderr, "usage: bench_train [--presets small,paper] [--decoder resunet] [--batch 4] [--repeats 3] "
                           "[--precision f32] [--out FILE.md]\n");
      return 2;
    }
  }
  const DecoderSpec spec = decoder_spec_from_string(decoder);
  torch::set_num_threads(int(std::max(1u, std::thread::hardware_concurrency())));
  Runtime rt;
  std::ostringstream md;
  md << "Device: " << rt.info().name << " (" << rt.info().platform << "); LibTorch CPU, " << torch::get_num_threads()
     << " threads; decoder " << spec.to_string() << "; batch " << batch << "; " << to_string(prec) << "\n\n"
     << "| preset | N | scene H x W | stage | median s | share of the step |\n|---|---:|---|---|---:|---:|\n";
  for (const std::string& pname : presets) {
    const SystemConfig cfg = preset_config(pname);
    const std::size_t s = cfg.sensor_size_px();
    std::mt19937_64 rng(1);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    std::vector<RealStack> scenes;
    for (std::size_t k = 0; k < batch; ++k) {
      RealStack sc(cfg.bands, s, s);
      for (double& v : sc.data) v = u(rng);
      scenes.push_back(std::move(sc));
    }
    Simulator sim(rt, cfg, prec);
    const Map2D h = lens_design(cfg, 550);
    ResUNet net = make_resunet(spec, 3, cfg.bands, 1);
    torch::optim::Adam adam(net->parameters(), torch::optim::AdamOptions(1e-3));
    const torch::Tensor target = batch_tensor(scenes);
    std::vector<RealStack> rgb, g_rgb;
    RealStack g_psf;
    torch::Tensor rgb_t, loss;
    auto optics = [&] {
      sim.set_heights(h);
      sim.compute_psf();
      rt.queue().finish();
    };
    Camera cam(sim);
    SkipOptions exact;
    exact.exact = true;
    auto camera = [&] { rgb = cam.images(scenes, exact); };
    auto network = [&] {
      adam.zero_grad();
      rgb_t = batch_tensor(rgb).requires_grad_(true);
      loss = (net->forward(rgb_t) - target).abs().mean();
      loss.backward();
      const torch::Tensor g = rgb_t.grad().to(torch::kDouble).contiguous();
      g_rgb.assign(batch, RealStack(3, s, s));
      for (std::size_t k = 0; k < batch; ++k)
        std::copy(g[std::int64_t(k)].data_ptr<double>(), g[std::int64_t(k)].data_ptr<double>() + 3 * s * s,
                  g_rgb[k].data.begin());
    };
    auto camera_adjoint = [&] { g_psf = cam.vjp(g_rgb, false).psf; };
    auto psf_adjoint = [&] { (void)sim.psf_sensor_vjp(g_psf); };
    auto adjoints = [&] {
      camera_adjoint();
      psf_adjoint();
    };
    auto optimizer = [&] { adam.step(); };
    optics();
    camera();
    const double t_opt = median_time(repeats, optics);
    const double t_cam = median_time(repeats, camera);
    const double t_net = median_time(repeats, network);
    network();  // g_rgb for the adjoints
    const double t_cam_adj = median_time(repeats, camera_adjoint);
    const double t_psf_adj = median_time(repeats, psf_adjoint);
    const double t_adam = median_time(repeats, optimizer);
    const double t_step = median_time(repeats, [&] {
      optics();
      camera();
      network();
      adjoints();
      optimizer();
    });
    // The step `qdo design --decoder` runs: Designer::step (radial PSF path, quantizer, Adam on the
    // optics) around JointTrainer::step (random crops, the patch camera in circular mode, noise,
    // the network's step, the camera adjoint), on synthetic scenes of S x S.
    register_torch_network();
    auto net2 = make_network_decoder(NetworkSettings{spec, 3, cfg.bands, 1, 1e-4, NetworkStyle{}});
    // The network decoder's own step as the design step calls it (images -> loss with its
    // weight-decay term and metrics, backward, Adam; double <-> float copies included).
    const double t_net_train = median_time(repeats, [&] { (void)net2->train(rgb, scenes, 1e-4); });
    const JointData jd = load_joint_data(cfg, {}, "auto", std::max<std::size_t>(batch, 4), 1);
    JointTrainer jt(rt, cfg, prec, *net2, jd, batch, 1e-3, 1);
    DesignOptions dopt;
    dopt.quantizer.levels = 4;
    Designer designer(sim, dopt);
    std::vector<double> p0(parameter_count(Parameterization::Radial, cfg.n), 0.3 * cfg.h_max_m());
    DesignState st = designer.initial_state(p0);
    const double t_loop = median_time(repeats, [&] {
      const long cur = st.step;
      designer.step(st, [&](const RealStack& psf, RealStack& g) { return jt.step(cur, 1e-3, psf, g); });
    });
    // The physics of that step alone, stage by stage: the design's optics (Designer::step with the
    // objective handing back a fixed PSF gradient: radial PSF forward, its read-back, the PSF
    // adjoint, Adam on the heights) and the patch camera on the S x S crops (circular, the design
    // step's camera) with its adjoint.
    RealStack g_fixed;
    (void)jt.step(st.step, 1e-3, sim.psf_sensor(), g_fixed);  // a real dL/dPSF of the shape the loop sees
    DesignState st_o = designer.initial_state(p0);
    const double t_design_optics = median_time(repeats, [&] {
      designer.step(st_o, [&](const RealStack&, RealStack& g) {
        g = g_fixed;
        return 0.0;
      });
    });
    testset::PatchCamera patch_cam(rt, cfg, prec);
    std::vector<testset::Patch> patches;
    for (const RealStack& sc : scenes) patches.push_back({"", sc});
    const RealStack psf_now = sim.psf_sensor();
    std::vector<RealStack> patch_rgb;
    const double t_patch = median_time(repeats, [&] { patch_rgb = patch_cam.measure(psf_now, patches); });
    RealStack g_patch_psf;
    const double t_patch_adj = median_time(repeats, [&] { g_patch_psf = patch_cam.vjp(g_rgb); });
    // The same step with the release's network items (joint_sampling.hpp, network_decoder.hpp):
    // Keras' batch norm, Glorot-uniform last convolution, noise on the bands, fixed patches.
    NetworkStyle keras;
    keras.keras_batch_norm = keras.glorot_final = true;
    auto net3 = make_network_decoder(NetworkSettings{spec, 3, cfg.bands, 1, 0.0, keras});
    JointSampling release_sampling;
    release_sampling.fixed_patches = release_sampling.noise_on_bands = true;
    JointTrainer jt_release(rt, cfg, prec, *net3, jd, batch, 1e-3, 1, release_sampling);
    DesignState st_r = designer.initial_state(p0);
    const double t_loop_release = median_time(repeats, [&] {
      const long cur = st_r.step;
      designer.step(st_r, [&](const RealStack& psf, RealStack& g) { return jt_release.step(cur, 1e-3, psf, g); });
    });
    // The sensor noise alone on one batch of images: on RGB (3 draws a pixel) and on the bands
    // (bands draws a pixel, then srf n).
    std::vector<RealStack> noisy(batch, RealStack(3, s, s));
    const Eigen::MatrixXd srf = sensor_response(cfg);
    const double t_noise_rgb = median_time(repeats, [&] {
      for (std::size_t k = 0; k < batch; ++k) ref::add_noise(noisy[k], 1e-3, 0, 7, k);
    });
    const double t_noise_bands = median_time(repeats, [&] {
      for (std::size_t k = 0; k < batch; ++k) add_band_noise(noisy[k], srf, band_noise_sigma(cfg, 1e-3), 7, k);
    });
    std::printf("%s (N=%zu, scenes %zu x %zu x %zu x %zu, %zu network parameters):\n", pname.c_str(), cfg.n, batch,
                cfg.bands, s, s, net->parameter_count());
    const std::pair<const char*, double> rows[] = {{"optics forward (PSF)", t_opt},
                                                   {"camera (batch of scenes -> RGB)", t_cam},
                                                   {"network forward + backward (MAE)", t_net},
                                                   {"camera adjoint (dL/dRGB -> dL/dPSF)", t_cam_adj},
                                                   {"PSF-chain adjoint (dL/dPSF -> dL/dH)", t_psf_adj},
                                                   {"network Adam step", t_adam},
                                                   {"whole step", t_step},
                                                   {"qdo design's step (Designer + JointTrainer, radial path)", t_loop},
                                                   {"the same with the release's network items", t_loop_release},
                                                   {"network decoder's train() (the design step's network step)", t_net_train},
                                                   {"design step's optics (radial PSF, read-back, adjoint, Adam)", t_design_optics},
                                                   {"design step's patch camera (S x S crops, circular)", t_patch},
                                                   {"design step's patch camera adjoint", t_patch_adj},
                                                   {"sensor noise on RGB, one batch (qdo)", t_noise_rgb},
                                                   {"sensor noise on the bands, one batch (release)", t_noise_bands}};
    for (const auto& [what, t] : rows) {
      std::printf("  %-44s %8.3f s  %5.1f %%\n", what, t, 100 * t / t_step);
      md << "| " << pname << " | " << cfg.n << " | " << s << " x " << s << " | " << what << " | " << t << " | "
         << 100 * t / t_step << " % |\n";
    }
    const double optics_only = t_opt + t_psf_adj, physics = optics_only + t_cam + t_cam_adj, net_s = t_net + t_adam;
    std::printf("  optics (PSF forward + PSF adjoint) / network (forward + backward + Adam) = %.2f\n", optics_only / net_s);
    std::printf("  physics (optics + camera + camera adjoint) / network = %.2f\n", physics / net_s);
    const double design_physics = t_design_optics + t_patch + t_patch_adj;
    std::printf("  design step's physics (its optics + patch camera + adjoint) / network = %.2f\n", design_physics / net_s);
    // The whole design step against what it cannot do without: the network's step and the design's
    // optics (forward and adjoint; the PSF forward alone is a part of it, so this floor is generous).
    const double floor_s = net_s + t_design_optics;
    std::printf("  design step / (network + its optics) = %.2f\n", t_loop / floor_s);
    std::printf("  design step / (network decoder's train() + its optics) = %.2f\n", t_loop / (t_net_train + t_design_optics));
    md << "| " << pname << " | " << cfg.n << " | | optics (PSF forward + adjoint) / network | " << optics_only / net_s << " | |\n";
    md << "| " << pname << " | " << cfg.n << " | | physics (optics + camera + its adjoint) / network | " << physics / net_s
       << " | |\n";
    md << "| " << pname << " | " << cfg.n << " | | design step's physics (its optics + patch camera + adjoint) / network | "
       << design_physics / net_s << " | |\n";
    md << "| " << pname << " | " << cfg.n << " | | design step / (network + its optics, forward and adjoint) | " << t_loop / floor_s
       << " | |\n";
    md << "| " << pname << " | " << cfg.n << " | | design step / (network decoder's train() + its optics) | "
       << t_loop / (t_net_train + t_design_optics) << " | |\n";
  }
  std::printf("peak resident memory: %.0f MiB\n", double(peak_rss_kib()) / 1024.0);
  md << "\nPeak resident memory of the whole run: " << peak_rss_kib() / 1024 << " MiB\n";
  if (!out.empty()) std::ofstream(out) << md.str();
  return 0;
}
