// mosaic_compare: which reconstructs better from a Bayer raw capture: demosaic then
// decode, or a decoder that reads the mosaic directly? One trained design (a `qdo design` run
// folder: its psf.h5, prior.h5 and configuration), the CAVE test patches (testset::patches, as
// `qdo eval`), each patch's noiseless RGB image through the design (testset::PatchCamera), then
// the sensor as built (ref::raw_forward: the mosaic, read (and shot) noise of the run's
// configuration, black level, 12-bit codes by default) with noise seeds --seeds, and:
//   none        no mosaic: the same raw stage with cfa none (three planes, same noise and bits)
//   bilinear    the mosaic, demosaiced bilinearly (DemosaicStage, float32 on the device)
//   mhc         the mosaic, demosaiced by Malvar-He-Cutler
//   zeros       the mosaic as three planes with zeros where a filter drops the colour (mosaic_planes)
// each decoded by the run's Wiener decoder (built for the PSF, the prior and the run's decoder
// noise sigma: the same filter for every input), clamped to [0, 1] and scored (testset::score).
// With --net-steps > 0, also Res-UNets trained for --net-steps steps on the training scenes
// (--train-data, joint_batch crops through the same camera and raw stage, fresh noise per step), one
// per input in --net-inputs (none, mhc, zeros: the network that reads the mosaic directly), from
// the same initial weights, batches and noise, then scored on the same test patches and seeds.
// Output: a markdown table and a CSV (per variant: mean over scenes and seeds of the per-scene
// means; the 95 % t interval of the mean over the (scene, seed) cells; the paired difference
// against mhc with its interval), and per-cell rows.
//
// Usage: mosaic_compare --run RUN [--data ../shared/data/hsi/cave] [--seeds 0,1,2] [--cfa rggb]
//          [--bit-depth 12] [--black-level 64] [--net-steps 0] [--net-batch 4]
//          [--net-spec resunet:depth=3,root=8] [--net-lr 1e-3] [--net-inputs none,mhc,zeros]
//          [--train-data ../shared/data/hsi/cave_train] [--out DIR]
// Device: QDO_DEVICE (see runtime.hpp). LibTorch threads: QDO_TORCH_THREADS.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <functional>
#include <fstream>
#include <iostream>
#include <map>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/decode/decoder_spec.hpp"
#include "qdo/physics/demosaic.hpp"
#include "qdo/physics/demosaic_reference.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"
#include "qdo/design/joint.hpp"
#include "qdo/net/net.hpp"
#include "qdo/decode/network_decoder.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/raw_reference.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/decode/testset.hpp"
#include "qdo/decode/wiener.hpp"

#include "../bench_util.hpp"

using namespace qdo;

namespace {

[[noreturn]] void usage(const std::string& err) {
  if (!err.empty()) std::cerr << "mosaic_compare: " << err << "\n";
  std::cerr << "usage: mosaic_compare --run RUN [--data DIR] [--seeds 0,1,2] [--cfa rggb] [--bit-depth 12] [--black-level 64]\n"
               "                      [--net-steps 0] [--net-batch 4] [--net-spec resunet:depth=3,root=8] [--net-lr 1e-3]\n"
               "                      [--net-inputs none,mhc,zeros] [--train-data DIR] [--out DIR]\n";
  std::exit(err.empty() ? 0 : 2);
}

struct Options {
  std::string run, data = "../shared/data/hsi/cave", train_data = "../shared/data/hsi/cave_train", out;
  std::vector<std::uint64_t> seeds{0, 1, 2};
  Cfa cfa = Cfa::RGGB;
  std::size_t bit_depth = 12;
  double black = 64;
  int net_steps = 0;
  std::size_t net_batch = 4;
  std::string net_spec = "resunet:depth=3,root=8";
  double net_lr = 1e-3;
  std::vector<std::string> net_inputs{"none", "mhc", "zeros"};
};

// The sensor-as-built configuration of an input kind: "none" reads three planes, the others the mosaic.
SystemConfig raw_config(const SystemConfig& run_cfg, const Options& o, const std::string& kind, std::uint64_t seed) {
  SystemConfig c = run_cfg;
  c.cfa = kind == "none" ? Cfa::None : o.cfa;
  c.bit_depth = o.bit_depth;
  c.black_level_dn = o.black;
  c.gain = 1;
  c.noise_seed = seed;
  return c;
}

// The decoder's input from a noiseless image (3 x S x S): raw capture (scene index `index` of the
// noise stream), linear units, then the kind's reconstruction of three planes.
RealStack decoder_input(const RealStack& clean, const SystemConfig& c, const std::string& kind, std::size_t index,
                        DemosaicStage* bil, DemosaicStage* mhc) {
  const RealStack lin = raw_to_linear(ref::raw_forward(clean, c, index).raw, c);
  if (kind == "none") return lin;
  if (kind == "bilinear") return bil->run(std::vector<RealStack>{lin})[0];
  if (kind == "mhc") return mhc->run(std::vector<RealStack>{lin})[0];
  if (kind == "zeros") return ref::mosaic_planes(lin, c.cfa);
  reject("input kind", kind, "none, bilinear, mhc or zeros");
}

RealStack clamp01(RealStack x) {
  for (double& v : x.data) v = std::min(1.0, std::max(0.0, v));
  return x;
}

struct Cell {  // one (variant, scene, seed)
  std::string variant, scene;
  std::uint64_t seed = 0;
  testset::Scores s;
};

// Mean and half-width of the 95 % t interval of the mean.
std::pair<double, double> mean_ci(const std::vector<double>& v) {
  const double n = double(v.size());
  double m = 0;
  for (double x : v) m += x / n;
  if (v.size() < 2) return {m, 0};
  double var = 0;
  for (double x : v) var += (x - m) * (x - m) / (n - 1);
  // t quantiles (0.975) for 1 .. 30 degrees of freedom, then the normal's.
  static const double t[] = {12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160, 2.145, 2.131,
                             2.120,  2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048, 2.045, 2.042};
  const std::size_t df = v.size() - 1;
  return {m, (df <= 30 ? t[df - 1] : 1.96) * std::sqrt(var / n)};
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) usage("missing value after " + a);
      return argv[++i];
    };
    try {
      if (a == "--run") o.run = value();
      else if (a == "--data") o.data = value();
      else if (a == "--train-data") o.train_data = value();
      else if (a == "--out") o.out = value();
      else if (a == "--seeds") {
        o.seeds.clear();
        for (const auto& s : qdo::split_items(value())) o.seeds.push_back(std::stoull(s));
        if (o.seeds.empty()) usage("--seeds needs at least one seed");
      } else if (a == "--cfa") {
        const std::string v = value();
        bool found = false;
        for (Cfa c : {Cfa::RGGB, Cfa::GRBG, Cfa::GBRG, Cfa::BGGR})
          if (to_string(c) == v) {
            o.cfa = c;
            found = true;
          }
        if (!found) usage("--cfa must be rggb, grbg, gbrg or bggr");
      } else if (a == "--bit-depth") {
        o.bit_depth = std::stoul(value());
        if (o.bit_depth < 8 || o.bit_depth > 16) usage("--bit-depth must lie in [8, 16]");
      } else if (a == "--black-level") {
        o.black = std::stod(value());
        if (!(o.black >= 0)) usage("--black-level must be >= 0");
      } else if (a == "--net-steps") {
        o.net_steps = std::stoi(value());
        if (o.net_steps < 0) usage("--net-steps must be >= 0");
      } else if (a == "--net-batch") {
        o.net_batch = std::stoul(value());
        if (o.net_batch < 1 || o.net_batch > 64) usage("--net-batch must lie in [1, 64]");
      } else if (a == "--net-spec") o.net_spec = value();
      else if (a == "--net-lr") {
        o.net_lr = std::stod(value());
        if (!(o.net_lr > 0)) usage("--net-lr must be > 0");
      } else if (a == "--net-inputs") {
        o.net_inputs = qdo::split_items(value());
        for (const auto& k : o.net_inputs)
          if (k != "none" && k != "mhc" && k != "bilinear" && k != "zeros") usage("--net-inputs: none, bilinear, mhc, zeros");
      } else if (a == "--help" || a == "-h") usage("");
      else usage("unknown argument " + a);
    } catch (const std::logic_error&) {
      usage("bad value for " + a);
    }
  }
  if (o.run.empty()) usage("--run RUN is required");
  try {
    const RunFolder run(o.run);
    const DesignRunOptions ro = run.config();
    const SystemConfig cfg = ro.cfg;
    const std::size_t S = cfg.sensor_size_px();
    const RealStack psf = read_psf_stack_file(run.psf_path()).psf_sensor;
    if (psf.planes != cfg.bands || psf.rows != S) throw InputError("run '" + o.run + "': psf.h5 is not the configuration's sensor stack");
    const wiener::SpectralPrior prior = run.prior(S);
    const Eigen::MatrixXd srf = sensor_response(cfg);
    const WienerDecoder wiener_dec(wiener::psf_to_otf(psf, S, S), srf, prior, ro.decoder_noise_sigma);
    Runtime rt;
    testset::PatchCamera camera(rt, cfg);
    DemosaicStage bil(rt, o.cfa, DemosaicMethod::Bilinear, Precision::F32), mhc(rt, o.cfa, DemosaicMethod::MHC, Precision::F32);
    const std::vector<testset::Patch> patches = testset::patches(cfg, S, {o.data}, "auto", 0, 0);
    const std::vector<RealStack> clean = camera.measure(psf, patches);
    std::fprintf(stderr, "[mosaic] %zu test patches of %zu x %zu, read noise %g, shot noise %s, %zu-bit, black %g DN, decoder sigma %g\n",
                 patches.size(), S, S, cfg.read_noise_sigma, cfg.full_well_photons > 0 ? "on" : "off", o.bit_depth, o.black,
                 ro.decoder_noise_sigma);
    std::vector<Cell> cells;
    // Per (variant, seed): the per-scene means of the patch scores.
    auto score_variant = [&](const std::string& variant, std::uint64_t seed,
                             const std::function<RealStack(std::size_t k)>& reconstruct) {
      std::vector<std::pair<std::string, testset::Scores>> per_patch;
      for (std::size_t k = 0; k < patches.size(); ++k) per_patch.push_back({patches[k].scene, testset::score(clamp01(reconstruct(k)), patches[k].cube)});
      for (const auto& [scene, s] : testset::per_scene_means(per_patch)) cells.push_back({variant, scene, seed, s});
    };
    const auto t0 = bench::Clock::now();
    const std::vector<std::string> kinds = {"none", "bilinear", "mhc", "zeros"};
    for (std::uint64_t seed : o.seeds)
      for (const std::string& kind : kinds) {
        const SystemConfig c = raw_config(cfg, o, kind, seed);
        score_variant("wiener/" + kind, seed, [&](std::size_t k) {
          return wiener_dec.decode(decoder_input(clean[k], c, kind, k, &bil, &mhc));
        });
        std::fprintf(stderr, "[mosaic] wiener/%s seed %llu done (%.1f s)\n", kind.c_str(), (unsigned long long)seed,
                     bench::seconds_since(t0));
      }
    std::string net_note;
    if (o.net_steps > 0) {
      register_torch_network();
      const JointData jd = load_joint_data(cfg, {o.train_data}, "auto", 0, 0);
      NetworkSettings ns;
      ns.spec = decoder_spec_from_string(o.net_spec);
      ns.in_channels = 3;
      ns.out_channels = cfg.bands;
      ns.seed = 0;
      ns.weight_decay_gamma = ro.gamma_decoder;
      net_note = o.net_spec + ", " + std::to_string(o.net_steps) + " steps of " + std::to_string(o.net_batch) + " crops of " +
                 std::to_string(S) + " px from " + std::to_string(jd.train.size()) + " training scenes, Adam lr " +
                 bench::fmt("%g", o.net_lr);
      for (const std::string& kind : o.net_inputs) {
        std::unique_ptr<NetworkDecoder> net = make_network_decoder(ns);
        const auto t1 = bench::Clock::now();
        double last_psnr = 0;
        for (int step = 0; step < o.net_steps; ++step) {
          const std::vector<RealStack> cubes = joint_batch(jd, S, o.net_batch, 0, step);
          std::vector<testset::Patch> ps;
          for (const RealStack& x : cubes) ps.push_back({"train", x});
          const std::vector<RealStack> ys = camera.measure(psf, ps);
          // Training noise: its own stream (seed 1000 + the step's crops as scene indices).
          const SystemConfig c = raw_config(cfg, o, kind, 1000);
          std::vector<RealStack> in;
          for (std::size_t i = 0; i < ys.size(); ++i) in.push_back(decoder_input(ys[i], c, kind, std::size_t(step) * o.net_batch + i, &bil, &mhc));
          last_psnr = net->train(in, cubes, o.net_lr).psnr_db;
          if ((step + 1) % 50 == 0 || step + 1 == o.net_steps)
            std::fprintf(stderr, "[mosaic] net/%s step %d of %d, batch PSNR %.2f dB (%.1f s)\n", kind.c_str(), step + 1, o.net_steps,
                         last_psnr, bench::seconds_since(t1));
        }
        for (std::uint64_t seed : o.seeds) {
          const SystemConfig c = raw_config(cfg, o, kind, seed);
          std::vector<RealStack> in;
          for (std::size_t k = 0; k < patches.size(); ++k) in.push_back(decoder_input(clean[k], c, kind, k, &bil, &mhc));
          std::vector<RealStack> out;
          for (std::size_t k = 0; k < in.size(); k += 4) {  // inference in batches of 4
            const std::vector<RealStack> part(in.begin() + long(k), in.begin() + long(std::min(in.size(), k + 4)));
            for (RealStack& x : net->reconstruct(part)) out.push_back(std::move(x));
          }
          score_variant("net/" + kind, seed, [&](std::size_t k) { return out[k]; });
        }
      }
    }
    // The table: per variant, the (scene, seed) cells' PSNR, SSIM, SAM; the paired difference against mhc.
    std::vector<std::string> variants;
    for (const Cell& c : cells)
      if (std::find(variants.begin(), variants.end(), c.variant) == variants.end()) variants.push_back(c.variant);
    auto key = [](const Cell& c) { return c.scene + "#" + std::to_string(c.seed); };
    std::map<std::string, std::map<std::string, testset::Scores>> by;  // variant -> cell key -> scores
    for (const Cell& c : cells) by[c.variant][key(c)] = c.s;
    std::ostringstream md, csv;
    md << "| decoder / input | PSNR dB (95 % CI) | SSIM | SAM rad | PSNR - same decoder on mhc, dB (95 % CI, paired) |\n|---|---|---|---|---|\n";
    csv << "variant,psnr,psnr_ci,ssim,sam_rad,dpsnr_vs_mhc,dpsnr_ci,cells\n";
    for (const std::string& v : variants) {
      std::vector<double> p, ss, sam, d;
      const std::string base = v.substr(0, v.find('/')) + "/mhc";
      for (const auto& [k, s] : by[v]) {
        p.push_back(s.psnr);
        ss.push_back(s.ssim);
        sam.push_back(s.sam_rad);
        if (by.count(base) && by[base].count(k)) d.push_back(s.psnr - by[base][k].psnr);
      }
      const auto [pm, pc] = mean_ci(p);
      const auto [sm, sc] = mean_ci(ss);
      const auto [am, ac] = mean_ci(sam);
      const auto [dm, dc] = mean_ci(d);
      (void)sc;
      (void)ac;
      md << "| " << v << " | " << bench::fmt("%.2f", pm) << " (+-" << bench::fmt("%.2f", pc) << ") | " << bench::fmt("%.4f", sm) << " | "
         << bench::fmt("%.4f", am) << " | " << (d.empty() ? std::string("") : bench::fmt("%+.2f", dm) + " (+-" + bench::fmt("%.2f", dc) + ")")
         << " |\n";
      csv << v << "," << pm << "," << pc << "," << sm << "," << am << "," << (d.empty() ? 0.0 : dm) << "," << (d.empty() ? 0.0 : dc) << ","
          << p.size() << "\n";
    }
    std::ostringstream head;
    head << "run " << o.run << " (" << ro.cfg.preset << " preset, " << to_string(ro.design.mode) << ", " << patches.size() << " test patches of "
         << S << " px from " << o.data << "), raw: cfa " << to_string(o.cfa) << ", " << o.bit_depth << "-bit, black " << o.black
         << " DN, read noise " << cfg.read_noise_sigma << " of full scale, noise seeds";
    for (auto s : o.seeds) head << " " << s;
    head << "; Wiener decoder sigma " << ro.decoder_noise_sigma << " for every input";
    if (!net_note.empty()) head << "; networks: " << net_note;
    head << "; intervals over " << by.begin()->second.size() << " (scene, seed) cells; " << bench::fmt("%.0f", bench::seconds_since(t0))
         << " s\n\n";
    const std::string text = head.str() + md.str();
    std::cout << text;
    if (!o.out.empty()) {
      std::filesystem::create_directories(o.out);
      write_text_atomic(o.out + "/table.md", text);
      write_text_atomic(o.out + "/table.csv", csv.str());
      std::ostringstream rows;
      rows << "variant,scene,seed,psnr,ssim,sam_rad,rmse,ergas\n";
      for (const Cell& c : cells)
        rows << c.variant << "," << c.scene << "," << c.seed << "," << c.s.psnr << "," << c.s.ssim << "," << c.s.sam_rad << "," << c.s.rmse
             << "," << c.s.ergas << "\n";
      write_text_atomic(o.out + "/cells.csv", rows.str());
    }
  } catch (const Error& e) {
    std::cerr << "mosaic_compare: " << e.what() << "\n";
    return 2;
  }
  return 0;
}
