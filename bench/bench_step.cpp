// bench_step: one optimiser step of the design loop (forward + adjoint) at the `small` and
// `paper` presets: OpenCL PSF forward alone, PSF forward + adjoint (dL/dH), the Wiener
// expected-error objective and its PSF gradient on the CPU (double, the reference) and on the
// device (wiener::DeviceObjective: float32 with float64 accumulation, pure float32, float64; each
// with its error against the CPU reference), the complete Designer step with either, and the
// CPU reference PSF forward + adjoint (ref::psf_sensor_vjp). Median of --repeats runs after one
// warm-up; kernel build and FFT plan bake time reported apart. Speed is never asserted.
//
// Usage: bench_step [--presets small,paper] [--repeats 3] [--precision f32] [--cpu-repeats 1]
//                   [--out FILE.md]
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "qdo/physics/adjoint.hpp"
#include "qdo/data/datasets.hpp"
#include "qdo/design/design.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/design/recipe.hpp"
#include "qdo/decode/wiener.hpp"
#include "qdo/decode/wiener_device.hpp"

#include "bench_util.hpp"

using namespace qdo;

namespace {

// Sorted run times in seconds of `repeats` runs of f() after one unmeasured warm-up run.
template <typename F>
std::vector<double> timed(int repeats, F&& f) {
  return qdo::bench::sorted_seconds(1, repeats, std::forward<F>(f));
}

using qdo::split_items;

}  // namespace

int main(int argc, char** argv) {
  std::vector<std::string> presets{"small", "paper"};
  int repeats = 3, cpu_repeats = 1;
  Precision prec = Precision::F32;
  std::string out;
  for (int i = 1; i < argc; i += 2) {  // --help, or a flag without its value, prints the usage (exit 2)
    const std::string k = i + 1 < argc ? argv[i] : "--help", v = i + 1 < argc ? argv[i + 1] : "";
    if (k == "--presets") presets = split_items(v);
    else if (k == "--repeats") repeats = std::stoi(v);
    else if (k == "--cpu-repeats") cpu_repeats = std::stoi(v);
    else if (k == "--precision") prec = precision_from_string(v);
    else if (k == "--out") out = v;
    else {
      std::fprintf(stderr, "bench_step: unknown option %s\n", k.c_str());
      return 2;
    }
  }
  Runtime rt;
  std::ostringstream md;
  md << "| preset | N | stage | median s | min s | max s | runs | error vs CPU double |\n"
        "|---|---:|---|---:|---:|---:|---:|---|\n";
  auto row = [&](const std::string& p, std::size_t n, const std::string& stage, const std::vector<double>& t,
                 const std::string& err = "") {
    char b[512];
    std::snprintf(b, sizeof b, "| %s | %zu | %s | %.3f | %.3f | %.3f | %zu | %s |\n", p.c_str(), n, stage.c_str(),
                  t[t.size() / 2], t.front(), t.back(), t.size(), err.c_str());
    md << b;
    std::printf("%-6s N=%-5zu %-58s median %8.3f s  (min %.3f, max %.3f, %zu runs) %s\n", p.c_str(), n, stage.c_str(),
                t[t.size() / 2], t.front(), t.back(), t.size(), err.c_str());
    std::fflush(stdout);
  };
  std::printf("device: %s (%s, driver %s), precision %s\n", rt.info().name.c_str(), rt.info().platform.c_str(),
              rt.info().driver_version.c_str(), to_string(prec).c_str());
  for (const auto& pname : presets) {
    const SystemConfig cfg = preset_config(pname);
    const double b0 = rt.build_seconds(), f0 = rt.fft_bake_seconds();
    Simulator sim(rt, cfg, prec);
    std::printf("%s: setup: kernels %.2f s, FFT plans %.2f s (not in the times below)\n", pname.c_str(), rt.build_seconds() - b0,
                rt.fft_bake_seconds() - f0);
    const Map2D h = lens_design(cfg, 550);
    sim.set_heights(h);
    RealStack g(cfg.bands, sim.sensor_size(), sim.sensor_size(), 1.0 / double(sim.sensor_size()));
    const auto fwd = timed(repeats, [&] {
      sim.compute_psf();
      sim.psf_sensor();
    });
    row(pname, cfg.n, "OpenCL PSF forward (" + to_string(prec) + ")", fwd);
    const auto both = timed(repeats, [&] {
      sim.compute_psf();
      sim.psf_sensor();
      sim.psf_sensor_vjp(g);
    });
    row(pname, cfg.n, "OpenCL PSF forward + adjoint dL/dH (" + to_string(prec) + ")", both);
    std::printf("       forward + adjoint / forward = %.2f\n", both[both.size() / 2] / fwd[fwd.size() / 2]);
    md << "| " << pname << " | " << cfg.n << " | ratio (forward + adjoint) / forward | " << both[both.size() / 2] / fwd[fwd.size() / 2]
       << " | | | | |\n";
    // The Wiener objective (CPU) on the sensor grid with a prior from synthetic scenes.
    const std::size_t s = cfg.sensor_size_px();
    const SceneIndex idx = SceneIndex::synthetic(cfg, 4, s, 1);
    std::vector<RealStack> scenes;
    for (std::size_t i = 0; i < idx.size(); ++i) scenes.push_back(idx.load(i));
    const wiener::SpectralPrior prior = wiener::estimate_prior(scenes, 16);
    const Eigen::MatrixXd srf = sensor_response(cfg);
    sim.compute_psf();
    const RealStack psf = sim.psf_sensor();
    const auto cpu_t = timed(repeats, [&] { wiener::objective_psf(wiener::Loss::Expected, psf, srf, prior, 1e-3); });
    row(pname, cfg.n, "Wiener expected error + PSF gradient (CPU double, reference)", cpu_t);
    const wiener::PsfObjective ref = wiener::objective_psf(wiener::Loss::Expected, psf, srf, prior, 1e-3);
    // The same on the device, per precision; error: |value - ref| / |ref|, gradient rel. L2.
    struct Variant {
      Precision p;
      bool acc64;
      std::string name;
    };
    std::vector<Variant> variants{{Precision::F32, true, "f32, f64 accumulation"}, {Precision::F32, false, "f32 only"}};
    if (rt.has_fp64()) variants.push_back({Precision::F64, true, "f64"});
    else variants[0].name = "f32 (device has no f64: f32 accumulation)";
    for (const Variant& v : variants) {
      const double bw = rt.build_seconds(), fw = rt.fft_bake_seconds();
      wiener::DeviceObjective dev(rt, v.p, srf, prior, 1e-3, s, v.acc64);
      std::printf("       device Wiener (%s) setup: kernels %.2f s, FFT plan %.2f s\n", v.name.c_str(), rt.build_seconds() - bw,
                  rt.fft_bake_seconds() - fw);
      const auto t = timed(repeats, [&] { dev.expected(psf); });
      const wiener::PsfObjective r = dev.expected(psf);
      double num = 0, den = 0;
      for (std::size_t i = 0; i < r.grad_psf.data.size(); ++i) {
        const double e = r.grad_psf.data[i] - ref.grad_psf.data[i];
        num += e * e;
        den += ref.grad_psf.data[i] * ref.grad_psf.data[i];
      }
      char err[128];
      std::snprintf(err, sizeof err, "value %.1e, gradient %.1e", std::fabs(r.value - ref.value) / std::fabs(ref.value),
                    std::sqrt(num / den));
      row(pname, cfg.n, "Wiener expected error + PSF gradient (device, " + v.name + ")", t, err);
      std::printf("       CPU / device = %.1f\n", cpu_t[cpu_t.size() / 2] / t[t.size() / 2]);
    }
    // A complete Designer step (qdo+a, radial parameterization: the radial PSF engine).
    DesignOptions o;
    o.mode = DesignMode::QDOA;
    Designer d(sim, o);
    std::vector<double> p0(cfg.n / 2);
    for (std::size_t k = 0; k < p0.size(); ++k) p0[k] = h(cfg.n / 2, cfg.n / 2 + k);
    DesignState st = d.initial_state(p0);
    const PsfObjective obj = [&](const RealStack& ps, RealStack& gr) {
      auto r = wiener::objective_psf(wiener::Loss::Expected, ps, srf, prior, 1e-3);
      gr = std::move(r.grad_psf);
      return r.value;
    };
    const auto step_cpu = timed(repeats, [&] { d.step(st, obj); });
    row(pname, cfg.n, "complete qdo+a step (OpenCL PSF + CPU Wiener + Adam)", step_cpu);
    wiener::DeviceObjective dev(rt, prec, srf, prior, 1e-3, s);
    const PsfObjective obj_dev = [&](const RealStack& ps, RealStack& gr) {
      auto r = dev.expected(ps);
      gr = std::move(r.grad_psf);
      return r.value;
    };
    const auto step_dev = timed(repeats, [&] { d.step(st, obj_dev); });
    row(pname, cfg.n, "complete qdo+a step (OpenCL PSF + device Wiener + Adam)", step_dev);
    std::printf("       step with device Wiener / step with CPU Wiener = %.3f\n", step_dev[step_dev.size() / 2] / step_cpu[step_cpu.size() / 2]);
    md << "| " << pname << " | " << cfg.n << " | ratio (device-Wiener step) / (CPU-Wiener step), same run | "
       << step_dev[step_dev.size() / 2] / step_cpu[step_cpu.size() / 2] << " | | | | |\n";
    // What `qdo design` runs: the same objective with the PSF and its gradient left on the device.
    const DevicePsfObjective resident = [&](const cl::Buffer& ps, cl::Buffer& gr) { return dev.expected(ps, gr); };
    const auto step_res = timed(repeats, [&] { d.step(st, obj_dev, &resident); });
    row(pname, cfg.n, "complete qdo+a step (device-resident: PSF, device Wiener, adjoint; as qdo design)", step_res);
    std::printf("       device-resident step / step with device Wiener through the host = %.3f\n",
                step_res[step_res.size() / 2] / step_dev[step_dev.size() / 2]);
    md << "| " << pname << " | " << cfg.n << " | ratio (device-resident step) / (CPU-Wiener step), same run | "
       << step_res[step_res.size() / 2] / step_cpu[step_cpu.size() / 2] << " | | | | |\n";
    // The same step under the release's recipe (qdo/design/recipe.hpp): ring-profile L_aq, Keras' Adam,
    // +-20 nm height noise drawn per pixel on the 2-D path (the recipe's), or per ring on the radial one.
    for (const char* path : {"2d", "radial"}) {
      DesignRunOptions ro;
      ro.cfg = cfg;
      apply_recipe("release", ro);
      ro.design.mode = DesignMode::QDOA;
      ro.design.psf_path = psf_path_from_string(path);
      Designer dr(sim, ro.design);
      DesignState sr = dr.initial_state(p0);
      const auto t = timed(repeats, [&] { dr.step(sr, obj_dev, &resident); });
      row(pname, cfg.n, std::string("complete qdo+a step, recipe release, ") + path + " path (device-resident; as qdo design)", t);
      md << "| " << pname << " | " << cfg.n << " | ratio (recipe release, " << path << ") / (the device-resident step above), same run | "
         << t[t.size() / 2] / step_res[step_res.size() / 2] << " | | | | |\n";
    }
    if (cpu_repeats > 0)
      row(pname, cfg.n, "CPU reference PSF forward + adjoint (double, FFTW)",
          timed(cpu_repeats, [&] { ref::psf_sensor_vjp(cfg, h, g); }));
  }
  if (!out.empty()) std::ofstream(out) << md.str();
  return 0;
}
