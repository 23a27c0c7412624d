// bench_range: one optimiser step of a design over a range of object points
// (Designer::range_step) against the one-point step in the same run (the baseline): the `small`
// preset (or --preset), qdo+a, radial parameterization (the radial engine, one per point), the
// Wiener expected-error objective on the device. Rows: one point at 1 m; P = 4 distances
// (0.5, 1, 2, 5 m) with points_per_step K = 1, 2 and 4. Median of --repeats steps after one
// warm-up step (and one gradient at every point, which builds each point's radial engine), min
// and max beside it; kernel build time reported apart. Speed is never asserted.
//
// Usage: bench_range [--preset small] [--repeats 5] [--precision f32] [--out FILE.md]
#include <cstdio>
#include <fstream>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "qdo/data/datasets.hpp"
#include "qdo/design/design.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/decode/wiener.hpp"
#include "qdo/decode/wiener_device.hpp"

#include "bench_util.hpp"

using namespace qdo;

int main(int argc, char** argv) {
  std::string preset = "small", out;
  int repeats = 5;
  Precision prec = Precision::F32;
  for (int i = 1; i < argc; i += 2) {
    const std::string k = i + 1 < argc ? argv[i] : "--help", v = i + 1 < argc ? argv[i + 1] : "";
    if (k == "--preset") preset = v;
    else if (k == "--repeats") repeats = std::stoi(v);
    else if (k == "--precision") prec = precision_from_string(v);
    else if (k == "--out") out = v;
    else {
      std::fprintf(stderr, "usage: bench_range [--preset small] [--repeats 5] [--precision f32] [--out FILE.md]\n");
      return 2;
    }
  }
  Runtime rt;
  const SystemConfig base = preset_config(preset);
  SystemConfig range = base;
  range.object_points = object_point_grid({0.5, 1.0, 2.0, 5.0}, {{0.0, 0.0}});
  range.validate();
  std::printf("device: %s (%s), precision %s, preset %s (N = %zu), CPU %s\n", rt.info().name.c_str(), rt.info().platform.c_str(),
              to_string(prec).c_str(), preset.c_str(), base.n, qdo::bench::cpu_model().c_str());
  const std::size_t s = base.sensor_size_px();
  const SceneIndex idx = SceneIndex::synthetic(base, 4, s, 1);
  std::vector<RealStack> scenes;
  for (std::size_t i = 0; i < idx.size(); ++i) scenes.push_back(idx.load(i));
  const wiener::SpectralPrior prior = wiener::estimate_prior(scenes, 16);
  wiener::DeviceObjective dev(rt, prec, sensor_response(base), prior, 1e-3, s);
  const DevicePsfObjective device = [&dev](const cl::Buffer& psf, cl::Buffer& grad) { return dev.expected(psf, grad); };
  const PointObjective unused = [](std::size_t, const RealStack&, RealStack&) -> double { return 0; };

  std::ostringstream md;
  md << "| preset | N | step | median s | min s | max s | steps | / one point |\n|---|---:|---|---:|---:|---:|---:|---:|\n";
  double baseline = 0;
  auto run = [&](const std::string& name, const SystemConfig& cfg, std::size_t k) {
    std::vector<std::unique_ptr<Simulator>> sims;
    std::vector<HeightMapPsfSource*> list;
    for (std::size_t p = 0; p < cfg.point_count(); ++p) {
      sims.push_back(std::make_unique<Simulator>(rt, cfg.point_count() == 1 ? cfg : point_config(cfg, p), prec));
      list.push_back(sims.back().get());
    }
    DesignOptions o;
    o.points_per_step = k;
    o.seed = 1;
    Designer d(list, o);
    std::vector<double> p0(base.n / 2);
    for (std::size_t i = 0; i < p0.size(); ++i) p0[i] = cfg.h_max_m() * (0.2 + 0.6 * double(i % 7) / 7.0);
    DesignState st = d.initial_state(p0);
    const double b0 = rt.build_seconds();
    std::vector<std::size_t> all(cfg.point_count());
    for (std::size_t i = 0; i < all.size(); ++i) all[i] = i;
    d.range_gradient(st, all, unused, &device);  // warm-up: every point's radial engine built, kernels compiled
    d.range_step(st, unused, &device);
    std::printf("%s: setup (first step) kernels %.2f s\n", name.c_str(), rt.build_seconds() - b0);
    const qdo::bench::Timing t = qdo::bench::summarize(qdo::bench::sorted_seconds(0, repeats, [&] { d.range_step(st, unused, &device); }));
    if (baseline == 0) baseline = t.median;
    char b[512];
    std::snprintf(b, sizeof b, "| %s | %zu | %s | %.3f | %.3f | %.3f | %d | %.2f |\n", preset.c_str(), base.n, name.c_str(), t.median,
                  t.min, t.max, t.runs, t.median / baseline);
    md << b;
    std::printf("%-40s median %.3f s (min %.3f, max %.3f, %d steps), %.2f x one point\n", name.c_str(), t.median, t.min, t.max,
                t.runs, t.median / baseline);
    std::fflush(stdout);
  };
  run("one point (1 m), baseline", base, 1);
  for (std::size_t k : {1, 2, 4}) run("P = 4 distances, K = " + std::to_string(k) + " per step", range, k);
  std::printf("\n%s", md.str().c_str());
  if (!out.empty()) std::ofstream(out) << md.str();
  return 0;
}
