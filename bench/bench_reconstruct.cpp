// `qdo reconstruct` of one 1024 x 1024 capture, the time per stage: read (the
// 16-bit PNG and every input check), dark (subtraction and scaling), demosaic, psf+decoder (the
// run's PSF simulated and the Wiener decoder built), tiles (decoding and blending every S x S
// tile), write cube, sRGB, spectra. A Wiener run of the preset is made first with `qdo design`
// (unless --run names one, from 8 synthetic scenes); the capture is a synthetic scene (the kind
// the run's prior was estimated on, synthetic_scene; --scene smooth: a few cosines per band, a
// scene that prior does not describe) through the run's PSF, 16-bit RGB. Each reconstruction runs once unmeasured, then --repeats times: the median per
// stage and the min-max beside it. Baseline, in the same run: the Wiener decoder on one S x S tile
// alone, times the tile count (what the tiles stage costs without cutting and blending).
// The capture is made as a camera makes it (linearly: the centre of a circular capture of a scene
// larger by S on each axis), so light from outside it lands inside. With --boundaries a second
// table times the whole command (medians after 1 warm-up) for each tile boundary named
// (circular, mirror, linear; tiled.hpp) with its error beside it: the relative RMS of the cube
// against the scene over the interior (16 px from each edge).
//
//   bench_reconstruct [--qdo build/qdo] [--run RUN] [--preset small] [--size 1024] [--repeats 3] [--out FILE.md]
//                     [--boundary mirror] [--boundaries circular,mirror,linear] [--scene synthetic|smooth]
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <string>
#include <vector>

#include "qdo/data/datasets.hpp"
#include "qdo/decode/decoder_registry.hpp"
#include "qdo/decode/tiled.hpp"
#include "qdo/data/io.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/asbuilt/reconstruct.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/decode/wiener.hpp"

#include "bench_util.hpp"

namespace fs = std::filesystem;
using namespace qdo;

namespace {

// A smooth bands x n x n scene in [0, 1] (a few cosines per band).
RealStack smooth_scene(std::size_t bands, std::size_t n, unsigned seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  RealStack x(bands, n, n, 0.0);
  for (std::size_t b = 0; b < bands; ++b)
    for (int k = 0; k < 3; ++k) {
      const double fy = u(rng) * 0.02, fx = u(rng) * 0.02, ph = u(rng) * 6.28, a = 0.1 + 0.1 * u(rng);
      for (std::size_t y = 0; y < n; ++y)
        for (std::size_t xx = 0; xx < n; ++xx) x(b, y, xx) += a * (1 + std::cos(6.2831853 * (fy * double(y) + fx * double(xx)) + ph));
    }
  for (double& v : x.data) v = std::min(1.0, v / 1.3);
  return x;
}

}  // namespace

int main(int argc, char** argv) {
  std::string qdo = "build/qdo", run, preset = "small", out;
  std::size_t size = 1024;
  int repeats = 3;
  std::string boundary = "mirror", boundaries, scene_kind = "synthetic";
  for (int i = 1; i < argc; i += 2) {
    const std::string k = i + 1 < argc ? argv[i] : "--help", v = i + 1 < argc ? argv[i + 1] : "";
    if (k == "--qdo") qdo = v;
    else if (k == "--run") run = v;
    else if (k == "--preset") preset = v;
    else if (k == "--size") size = std::size_t(std::max(16, std::atoi(v.c_str())));
    else if (k == "--repeats") repeats = std::max(1, std::atoi(v.c_str()));
    else if (k == "--out") out = v;
    else if (k == "--boundary") boundary = v;
    else if (k == "--boundaries") boundaries = v;
    else if (k == "--scene" && (v == "synthetic" || v == "smooth")) scene_kind = v;
    else {
      std::fprintf(stderr,
                   "usage: bench_reconstruct [--qdo build/qdo] [--run RUN] [--preset small] [--size 1024] [--repeats 3] [--out FILE.md] "
                   "[--boundary mirror] [--boundaries circular,mirror,linear] [--scene synthetic|smooth]\n");
      return 2;
    }
  }
  const fs::path tmp = fs::temp_directory_path() / ("qdo_bench_reconstruct_" + std::to_string(::getpid()));
  fs::create_directories(tmp);
  if (run.empty()) {
    run = (tmp / "run").string();
    const std::string cmd = qdo + " design --preset " + preset +
                            " --mode qdo+a --epochs 1 --steps-per-epoch 1 --synthetic-scenes 8 --out " + run + " > /dev/null 2>&1";
    const int st = std::system(cmd.c_str());
    if (!WIFEXITED(st) || WEXITSTATUS(st) != 0) {
      std::fprintf(stderr, "bench_reconstruct: failed: %s\n", cmd.c_str());
      return 1;
    }
  }
  const RunFolder folder(run);
  const DesignRunOptions ro = folder.config();
  const SystemConfig& cfg = ro.cfg;
  const std::size_t s = cfg.sensor_size_px();
  const RealStack psf = read_psf_stack_file(folder.psf_path()).psf_sensor;
  const Eigen::MatrixXd srf = sensor_response(cfg);
  // The capture: a scene through the run's PSF, linearly (the centre size x size of the circular
  // capture of a scene size + S on a side: no light wraps into it), 16-bit RGB.
  const std::size_t wide = size + s, off = s / 2;
  // synthetic: the kind of scene the run's prior was estimated on; smooth: one it does not describe.
  const RealStack scene_wide = scene_kind == "smooth" ? smooth_scene(cfg.bands, wide, 5) : synthetic_scene(cfg, wide, 5);
  const RealStack y_wide = wiener::simulate_measurement(scene_wide, wiener::psf_to_otf(psf, wide, wide), srf);
  RealStack y(3, size, size), scene(cfg.bands, size, size);
  for (std::size_t c = 0; c < 3; ++c)
    for (std::size_t r = 0; r < size; ++r)
      for (std::size_t x = 0; x < size; ++x) y(c, r, x) = std::round(std::clamp(y_wide(c, r + off, x + off), 0.0, 1.0) * 65535.0);
  for (std::size_t b = 0; b < cfg.bands; ++b)
    for (std::size_t r = 0; r < size; ++r)
      for (std::size_t x = 0; x < size; ++x) scene(b, r, x) = scene_wide(b, r + off, x + off);
  const std::string cap = (tmp / "capture.png").string();
  write_png16_rgb(cap, y);

  Runtime rt;
  ReconstructOptions o;
  o.run = run;
  o.boundary_set = true;
  o.boundary = tile_boundary_from_string(boundary, "--boundary");
  o.capture.captures = {cap};
  o.quiet = true;
  o.regions = parse_regions("100,100;" + std::to_string(size / 2) + "," + std::to_string(size / 2), false, "--points");
  for (const auto& r : parse_regions("200,200,64,64", true, "--boxes")) o.regions.push_back(r);
  std::map<std::string, std::vector<double>> stage;
  std::vector<std::string> order;
  std::vector<double> total;
  std::size_t tiles = 0;
  for (int k = 0; k <= repeats; ++k) {
    o.out = (tmp / ("out" + std::to_string(k))).string();
    const auto t0 = bench::Clock::now();
    const ReconstructResult r = reconstruct(rt, o);
    const double t = bench::seconds_since(t0);
    tiles = r.tiles;
    if (k == 0) {
      for (const auto& [name, sec] : r.seconds) order.push_back(name);
      continue;  // warm-up
    }
    for (const auto& [name, sec] : r.seconds) stage[name].push_back(sec);
    total.push_back(t);
    fs::remove_all(o.out);
  }
  // Baseline: the decoder on one tile, as many times as there are tiles.
  DecoderInputs in;
  in.spec = ro.decoder;
  in.psf = psf;
  in.srf = srf;
  in.prior = folder.prior(s);
  in.noise_sigma = ro.decoder_noise_sigma;
  const auto dec = make_decoder(in);
  RealStack tile(3, s, s);
  for (std::size_t c = 0; c < 3; ++c)
    for (std::size_t r = 0; r < s; ++r)
      for (std::size_t x = 0; x < s; ++x) tile(c, r, x) = y(c, r, x) / 65535.0;
  const bench::Timing one = bench::time_it(1, std::max(3, repeats), [&] { (void)dec->decode(tile); });

  std::string text = "| stage | median s | min-max s |\n|---|---|---|\n";
  auto row = [&](const std::string& name, const std::vector<double>& v) {
    const bench::Timing t = bench::summarize(v);
    text += "| " + name + " | " + bench::fmt("%.3f", t.median) + " | " + bench::fmt("%.3f", t.min) + "-" + bench::fmt("%.3f", t.max) + " |\n";
  };
  for (const auto& name : order) row(name, stage[name]);
  row("total (reconstruct())", total);
  text += "| baseline: one " + std::to_string(s) + " x " + std::to_string(s) + " Wiener decode x " + std::to_string(tiles) + " tiles | " +
          bench::fmt("%.3f", one.median * double(tiles)) + " | " + bench::fmt("%.3f", one.min * double(tiles)) + "-" +
          bench::fmt("%.3f", one.max * double(tiles)) + " |\n";
  std::printf("reconstruct: %zu x %zu RGB capture (linear), %s preset (%zu bands, S = %zu), %zu tiles, Wiener decoder, %s boundary, device %s; "
              "%d runs after 1 warm-up\n%s",
              size, size, preset.c_str(), cfg.bands, s, tiles, boundary.c_str(), rt.info().name.c_str(), repeats, text.c_str());
  if (!boundaries.empty()) {
    // The whole command per boundary, with the cube's error against the scene beside it.
    std::string t2 = "| boundary | total median s | min-max s | interior relative RMS vs the scene |\n|---|---|---|---|\n";
    for (const std::string& b : bench::split_items(boundaries, ',')) {
      o.boundary = tile_boundary_from_string(b, "--boundaries");
      std::vector<double> ts;
      double err = 0;
      for (int k = 0; k <= repeats; ++k) {
        o.out = (tmp / ("b_" + b + std::to_string(k))).string();
        const auto t0 = bench::Clock::now();
        const ReconstructResult r = reconstruct(rt, o);
        const double t = bench::seconds_since(t0);
        if (k > 0) ts.push_back(t);
        double d2 = 0, s2 = 0;
        const std::size_t e = 16;
        for (std::size_t p = 0; p < r.cube.planes; ++p)
          for (std::size_t yy = e; yy + e < size; ++yy)
            for (std::size_t xx = e; xx + e < size; ++xx) {
              d2 += std::pow(r.cube(p, yy, xx) - scene(p, yy, xx), 2);
              s2 += std::pow(scene(p, yy, xx), 2);
            }
        err = std::sqrt(d2 / s2);
        fs::remove_all(o.out);
      }
      const bench::Timing t = bench::summarize(ts);
      t2 += "| " + b + " | " + bench::fmt("%.3f", t.median) + " | " + bench::fmt("%.3f", t.min) + "-" + bench::fmt("%.3f", t.max) + " | " +
            bench::fmt("%.4f", err) + " |\n";
    }
    std::printf("\nthe whole command per tile boundary (%d runs after 1 warm-up each):\n%s", repeats, t2.c_str());
    text += "\n" + t2;
  }
  if (!out.empty()) std::ofstream(out) << text;
  fs::remove_all(tmp);
  return 0;
}
