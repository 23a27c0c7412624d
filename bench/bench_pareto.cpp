// bench_pareto: run time against error for every knob that trades one for the other.
//
// Workloads (paper physics: 31 bands 400-700 nm, 4 um pitch, z = 50 mm, d = 1 m, N = --n):
//   psf    the PSF stack on the sensor grid. Axes: float32 / float64 / float32 with float64 phase,
//          padding per side (N/8, N/4 = the paper's, N/2), hence the FFT size M (always rounded up
//          to a 7-smooth length: clFFT has radices 2, 3, 5, 7 only), the number of spectral samples
//          (31, 16, 11, 7 bands), and the FFT backend. Beside each: the bare FFT floor (one forward
//          plus one inverse batched 2-D FFT of bands x M x M, nothing else) and the CPU reference.
//   image  RGB sensor images of the three CAVE scenes (one batch) through the PSF of the lens
//          design: per-band linear convolution + sensor integration, and the bare convolution FFTs.
//   step   one optimiser step: the PSF forward alone and forward + adjoint dL/dH.
//   sweep  a 5-level PSF sweep: five quantized designs sequentially and batched in one pass.
// Error reference: float64, padding N/2 per side (M = 2N, generous), the 2-D path, all 31 bands,
// compared as the RGB PSF (3 x S x S: each band's sensor PSF weighted by the camera response,
// what the sensor sees of a white point) so that configurations with fewer bands are comparable;
// "band err" is the per-band sensor PSF stack error where the band grids agree.
// Timing: median (min, max) of --repeats runs after one warm-up; each configuration gets a fresh
// Runtime and its program build/load and FFT plan bake times are reported apart, never in a median.
// Nothing is asserted: this program only reports.
//
// Usage: bench_pareto [--n 1024] [--repeats 5] [--sections psf,image,step,sweep,psnr]
//                     [--cave DIR] [--no-cpu] [--out FILE.md]
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <functional>
#include <iostream>
#include <memory>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "qdo/data/data_root.hpp"
#include "qdo/data/config.hpp"
#include "qdo/physics/cpu_reference.hpp"
#include "qdo/data/datasets.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/fft.hpp"
#include "qdo/physics/camera.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/radial.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/runtime/types.hpp"
#include "qdo/decode/wiener.hpp"

#include "bench_util.hpp"

using namespace qdo;

namespace {

using qdo::bench::Clock;
using qdo::bench::seconds_since;
using qdo::split_items;

struct Options {
  std::size_t n = 1024;
  int repeats = 5;
  std::set<std::string> sections{"psf", "image", "step", "sweep", "psnr"};
  std::string cave = "cave";  // a dataset name under the data root (qdo data), or a folder
  bool cpu = true;
  std::string out;
};

// The sorted samples are kept (the report prints median, min, max and count of them).
struct Timing {
  std::vector<double> s;  // sorted seconds
  double median() const { return s.empty() ? NAN : s[s.size() / 2]; }
};

// `repeats` runs of f() after one unmeasured warm-up run.
Timing timed(int repeats, const std::function<void()>& f) { return {qdo::bench::sorted_seconds(1, repeats, f)}; }

struct Row {
  std::string workload, config;
  Timing t;
  double units = 1;           // work units per run (bands, images, ...)
  std::string unit = "bands";
  double err = NAN, band_err = NAN;
  std::string note;
};
struct Setup {
  std::string config;
  double build_s = 0, bake_s = 0;
  int built = 0, loaded = 0;
};

std::vector<Row> rows;
std::vector<Setup> setups;
std::vector<std::string> psnr_lines;

void print_row(const Row& r) {
  std::fprintf(stderr, "  %-6s %-58s %9.1f ms  err %.2e  %s\n", r.workload.c_str(), r.config.c_str(), 1e3 * r.t.median(),
               r.err, r.note.c_str());
}
void add(Row r) {
  print_row(r);
  rows.push_back(std::move(r));
}
void add_setup(const std::string& config, const Runtime& rt) {
  setups.push_back({config, rt.build_seconds(), rt.fft_bake_seconds(), rt.programs_built(), rt.programs_loaded_from_disk()});
}

double rel_l2(const std::vector<double>& a, const std::vector<double>& b) {
  double num = 0, den = 0;
  for (std::size_t i = 0; i < a.size(); ++i) {
    num += (a[i] - b[i]) * (a[i] - b[i]);
    den += b[i] * b[i];
  }
  return den > 0 ? std::sqrt(num / den) : std::sqrt(num);
}

// RGB PSF (3 x S x S): sum_b srf(c, b) psf_b, srf rows summing to 1 (sensor_response()).
RealStack rgb_psf(const RealStack& psf, const Eigen::MatrixXd& srf) {
  const std::size_t ss = psf.rows * psf.cols;
  RealStack out(3, psf.rows, psf.cols);
  for (std::size_t c = 0; c < 3; ++c)
    for (std::size_t b = 0; b < psf.planes; ++b) {
      const double w = srf(Eigen::Index(c), Eigen::Index(b));
      for (std::size_t e = 0; e < ss; ++e) out.data[c * ss + e] += w * psf.data[b * ss + e];
    }
  return out;
}

SystemConfig paper(std::size_t n) {
  SystemConfig c = preset_config("paper");
  c.n = n;
  c.padding_px = n / 4;
  return c;
}

struct Reference {
  SystemConfig cfg;
  RealStack psf_sensor, rgb;
  Map2D heights;
};

// Bare FFT floor: forward + inverse of `batch` x rows x cols on a device buffer.
Row fft_floor(const std::string& workload, std::size_t rows_, std::size_t cols, std::size_t batch, Precision p, int repeats,
              FftBackend backend) {
  Runtime rt("", backend);
  const std::string label = backend == FftBackend::VkFFT ? "VkFFT" : "clFFT";
  FftPlan& plan = rt.fft(rows_, cols, batch, p);
  cl::Buffer buf(rt.context(), CL_MEM_READ_WRITE, batch * rows_ * cols * 2 * real_size(p));
  rt.queue().enqueueFillBuffer(buf, cl_uchar(0), 0, batch * rows_ * cols * 2 * real_size(p));
  rt.queue().finish();
  Row r;
  r.workload = workload;
  r.config = label + " FFT floor " + to_string(p) + " (fwd + inv, " + std::to_string(batch) + " x " + std::to_string(rows_) +
             " x " + std::to_string(cols) + ")";
  r.t = timed(repeats, [&] {
    plan.forward(buf);
    plan.inverse(buf);
    rt.queue().finish();
  });
  r.units = double(batch);
  r.note = "plan bake " + to_str(plan.bake_seconds()) + " s";
  return r;
}

void section_psf(const Options& o, const Reference& ref) {
  const std::size_t n = o.n;
  const Map2D& h = ref.heights;
  struct Cfg {
    std::string label;
    Precision p;
    bool p64;
    std::size_t pad, bands;
    FftBackend fft = FftBackend::ClFFT;
  };
  std::vector<Cfg> cfgs{
      {"2-D f32, pad N/4 (default)", Precision::F32, false, n / 4, 31},
      {"2-D f64, pad N/4", Precision::F64, false, n / 4, 31},
      {"2-D f32 + f64 phase, pad N/4", Precision::F32, true, n / 4, 31},
      {"2-D f32, pad N/4, VkFFT", Precision::F32, false, n / 4, 31, FftBackend::VkFFT},
      {"2-D f64, pad N/4, VkFFT", Precision::F64, false, n / 4, 31, FftBackend::VkFFT},
      {"2-D f32, pad N/8", Precision::F32, false, n / 8, 31},
      {"2-D f32, pad N/2", Precision::F32, false, n / 2, 31},
      {"2-D f64, pad N/2", Precision::F64, false, n / 2, 31},
      {"2-D f32, pad N/4, 16 bands (20 nm)", Precision::F32, false, n / 4, 16},
      {"2-D f32, pad N/4, 11 bands (30 nm)", Precision::F32, false, n / 4, 11},
      {"2-D f32, pad N/4, 7 bands (50 nm)", Precision::F32, false, n / 4, 7},
  };
  std::set<std::pair<std::size_t, int>> floors;  // (M, precision x backend) floors already measured
  for (const Cfg& c : cfgs) {
    SystemConfig cfg = ref.cfg;
    cfg.padding_px = c.pad;
    cfg.bands = c.bands;
    cfg.wavelength_step_nm = 300.0 / double(c.bands - 1);
    Runtime rt("", c.fft);
    Simulator sim(rt, cfg, c.p, 1, c.p64);
    add_setup("psf: " + c.label, rt);
    sim.set_heights(h);
    Row r;
    r.workload = "psf";
    const std::size_t m = sim.geometry().m;
    r.config = c.label + ", M = " + std::to_string(m);
    r.t = timed(o.repeats, [&] {
      sim.compute_psf();
      rt.queue().finish();
    });
    r.units = double(cfg.bands);
    const RealStack ps = sim.psf_sensor();
    r.err = rel_l2(rgb_psf(ps, sim.srf()).data, ref.rgb.data);
    if (c.bands == 31) r.band_err = rel_l2(ps.data, ref.psf_sensor.data);
    const int key = (c.p == Precision::F64 ? 64 : 32) + (c.fft == FftBackend::VkFFT ? 1 : 0);
    if (!floors.count({m, key}) && c.bands == 31) {
      floors.insert({m, key});
      Row f = fft_floor("psf", m, m, cfg.bands, c.p, o.repeats, c.fft);
      r.note = "x" + to_str(std::round(100 * r.t.median() / f.t.median()) / 100) + " of FFT floor";
      add(r);
      add(f);
    } else {
      add(r);
    }
  }
  for (Precision p : {Precision::F32, Precision::F64}) {
    Runtime rt;
    const auto t0 = Clock::now();
    RadialEngine eng(rt, ref.cfg, p);
    const double setup_s = seconds_since(t0);
    add_setup("psf: radial " + to_string(p) + " (tables " + to_str(std::round(setup_s * 100) / 100) + " s, incl. build)", rt);
    const std::vector<double> rings = ring_heights_of_map(h);
    Row r;
    r.workload = "psf";
    r.config = "radial (Hankel) " + to_string(p) + ", K = " + std::to_string(eng.tables().k);
    r.t = timed(o.repeats, [&] {
      eng.compute_psf(rings);
      rt.queue().finish();
    });
    r.units = double(ref.cfg.bands);
    const RealStack ps = eng.psf_sensor();
    r.err = rel_l2(rgb_psf(ps, sensor_response(ref.cfg)).data, ref.rgb.data);
    r.band_err = rel_l2(ps.data, ref.psf_sensor.data);
    add(r);
  }
  if (o.cpu) {
    Row r;
    r.workload = "psf";
    r.config = "CPU reference f64 (FFTW, 1 thread), pad N/4";
    SystemConfig cfg = ref.cfg;
    RealStack ps;
    const AreaWeights w = AreaWeights::make(cfg.n, cfg.pitch_m, cfg.sensor_size_px(), cfg.sensor_pitch_m);
    r.t = timed(std::max(1, o.repeats / 3), [&] {
      ps = ref::resample_area(ref::psf_stack(cfg, h).psf, w);
      ref::normalize_planes(ps);
    });
    r.units = double(cfg.bands);
    r.err = rel_l2(rgb_psf(ps, sensor_response(cfg)).data, ref.rgb.data);
    r.band_err = rel_l2(ps.data, ref.psf_sensor.data);
    add(r);
  }
}

void section_image(const Options& o, const Reference& ref) {
  std::vector<RealStack> scenes;
  for (const char* f : {"balloons_256.mat", "chart_and_stuffed_toy_256.mat", "cloth_256.mat"})
    scenes.push_back(load_scene(o.cave + "/" + f));
  SystemConfig cfg = ref.cfg;
  cfg.read_noise_sigma = 0;
  cfg.full_well_photons = 0;
  std::vector<RealStack> want;
  {
    Runtime rt;
    Simulator sim(rt, cfg, Precision::F64);
    sim.set_heights(ref.heights);
    sim.compute_psf();
    SkipOptions exact;
    exact.exact = true;
    want = Camera(sim).images(scenes, exact);
  }
  std::vector<double> want_flat;
  for (const auto& w : want) want_flat.insert(want_flat.end(), w.data.begin(), w.data.end());
  for (Precision p : {Precision::F32, Precision::F64}) {
    Runtime rt;
    Simulator sim(rt, cfg, p);
    sim.set_heights(ref.heights);
    sim.compute_psf();
    std::vector<RealStack> got;
    Row r;
    r.workload = "image";
    r.config = "3 CAVE scenes 256 x 256, unskipped, " + to_string(p);
    Camera cam(sim);
    SkipOptions exact;
    exact.exact = true;
    r.t = timed(o.repeats, [&] { got = cam.images(scenes, exact); });
    add_setup("image: " + r.config, rt);
    std::vector<double> flat;
    for (const auto& g : got) flat.insert(flat.end(), g.data.begin(), g.data.end());
    r.units = 3;
    r.unit = "images";
    double mx = 0;
    for (std::size_t i = 0; i < flat.size(); ++i) mx = std::max(mx, std::fabs(flat[i] - want_flat[i]));
    r.err = mx;
    r.note = "err = max abs vs f64 unskipped";
    add(r);
    // The skipping imager on the same PSF: exact reorganisation, the defaults, looser budgets.
    Camera imager(sim);
    const std::vector<std::pair<std::string, SkipOptions>> variants{
        {"exact (no rule)", [] { SkipOptions x; x.exact = true; return x; }()},
        {"default tolerances (3e-7 total)", SkipOptions{}},
        {"total tolerance 1e-4", SkipOptions::split(1e-4)},
        {"total tolerance 1e-2", SkipOptions::split(1e-2)}};
    for (const auto& [label, opt] : variants) {
      Row ri;
      ri.workload = "image";
      ri.config = "Camera " + label + ", " + to_string(p);
      ri.t = timed(o.repeats, [&] { got = imager.images(scenes, opt); });
      flat.clear();
      for (const auto& g : got) flat.insert(flat.end(), g.data.begin(), g.data.end());
      double m2 = 0;
      for (std::size_t i = 0; i < flat.size(); ++i) m2 = std::max(m2, std::fabs(flat[i] - want_flat[i]));
      ri.err = m2;
      ri.units = 3;
      ri.unit = "images";
      const SkipReport& rep = imager.last_report();
      ri.note = "bound " + to_str(rep.total_bound) + "; x" + to_str(std::round(10 * r.t.median() / ri.t.median()) / 10) +
                " faster than unskipped; " + to_str(rep.bands_skipped.size()) + " bands, " + to_str(rep.tiles_skipped) +
                " tiles skipped, crop radius " + to_str(rep.crop_radius_px) + " of " + to_str(sim.sensor_size() / 2);
      add(ri);
    }
    const std::size_t s = sim.sensor_size();
    const std::size_t py = fast_fft_size(256 + s - 1);
    add(fft_floor("image", py, py, 3 * cfg.bands, p, o.repeats, FftBackend::ClFFT));
    add(fft_floor("image", py, py, 3 * cfg.bands, p, o.repeats, FftBackend::VkFFT));
  }
}

void section_step(const Options& o, const Reference& ref) {
  for (Precision p : {Precision::F32, Precision::F64}) {
    Runtime rt;
    Simulator sim(rt, ref.cfg, p);
    sim.set_heights(ref.heights);
    const std::size_t s = sim.sensor_size();
    // dL/dpsf of L = <psf_sensor, psf_reference> (overlap with the reference PSF: a smooth,
    // physically meaningful objective, so the 2-D and radial gradients can be compared).
    const RealStack& g = ref.psf_sensor;
    (void)s;
    Row fwd;
    fwd.workload = "step";
    fwd.config = "2-D forward (PSF on the sensor grid), " + to_string(p);
    fwd.t = timed(o.repeats, [&] {
      sim.compute_psf();
      rt.queue().finish();
    });
    fwd.units = double(ref.cfg.bands);
    add(fwd);
    Row both;
    both.workload = "step";
    both.config = "2-D forward + adjoint dL/dH, " + to_string(p);
    Map2D gh;
    both.t = timed(o.repeats, [&] {
      sim.compute_psf();
      gh = sim.psf_sensor_vjp(g);
    });
    both.units = double(ref.cfg.bands);
    both.note = "x" + to_str(std::round(100 * both.t.median() / fwd.t.median()) / 100) + " of forward";
    add(both);
    add_setup("step: " + to_string(p), rt);
    RadialEngine eng(rt, ref.cfg, p);
    const std::vector<double> rings = ring_heights_of_map(ref.heights);
    Row rf;
    rf.workload = "step";
    rf.config = "radial forward, " + to_string(p);
    rf.t = timed(o.repeats, [&] {
      eng.compute_psf(rings);
      rt.queue().finish();
    });
    rf.units = double(ref.cfg.bands);
    rf.note = "x" + to_str(std::round(10 * fwd.t.median() / rf.t.median()) / 10) + " faster than 2-D";
    add(rf);
    Row rb;
    rb.workload = "step";
    rb.config = "radial forward + adjoint dL/dh (rings), " + to_string(p);
    std::vector<double> gr;
    rb.t = timed(o.repeats, [&] {
      eng.compute_psf(rings);
      gr = eng.psf_sensor_vjp(g);
    });
    rb.units = double(ref.cfg.bands);
    // The 2-D gradient summed over each ring's pixels is the ring gradient of the 2-D path.
    const std::size_t n = ref.cfg.n;
    std::vector<double> g2(n / 2, 0.0);
    for (std::size_t i = 0; i < n; ++i)
      for (std::size_t j = 0; j < n; ++j) {
        const double di = double(i) - double(n / 2), dj = double(j) - double(n / 2);
        const std::size_t k = std::size_t(std::floor(std::sqrt(di * di + dj * dj)));
        if (k < n / 2) g2[k] += gh(i, j);
      }
    double dotp = 0, na = 0, nb = 0;
    for (std::size_t k = 0; k < g2.size(); ++k) {
      dotp += g2[k] * gr[k];
      na += g2[k] * g2[k];
      nb += gr[k] * gr[k];
    }
    rb.note = "x" + to_str(std::round(100 * rb.t.median() / rf.t.median()) / 100) + " of radial forward; x" +
              to_str(std::round(10 * both.t.median() / rb.t.median()) / 10) + " faster than 2-D; gradient cosine to 2-D " +
              to_str(std::round(1000 * dotp / std::sqrt(na * nb)) / 1000);
    add(rb);
  }
}

// Wiener reconstruction PSNR on the CAVE scenes through the PSFs of one design from different
// paths (the criterion for the radial path): the 2-D path, the radial path, and the reference.
void section_psnr(const Options& o, const Reference& ref) {
  std::vector<RealStack> scenes;
  for (const char* f : {"balloons_256.mat", "chart_and_stuffed_toy_256.mat", "cloth_256.mat"})
    scenes.push_back(load_scene(o.cave + "/" + f));
  const auto prior = wiener::estimate_prior(scenes, 16);
  const auto srf = sensor_response(ref.cfg);
  Quantizer q4;
  q4.levels = 4;
  const std::vector<std::pair<std::string, Map2D>> designs{
      {"lens", ref.heights}, {"lens, 4 levels", quantize_heights(ref.heights, ref.cfg.h_max_m(), q4, 1.0)}};
  for (const auto& [name, h] : designs) {
    auto psnr_of = [&](const RealStack& psf) {
      double acc = 0;
      for (const RealStack& sc : scenes) {
        const auto otf = wiener::psf_to_otf(psf, sc.rows, sc.cols);
        acc += metrics::psnr(wiener::decode_mismatched(sc, otf, otf, srf, prior, 0.001), sc);
      }
      return acc / double(scenes.size());
    };
    Runtime rt;
    SystemConfig rc = ref.cfg;
    rc.padding_px = o.n / 2;
    Simulator sref(rt, rc, Precision::F64);
    sref.set_heights(h);
    sref.compute_psf();
    const double p_ref = psnr_of(sref.psf_sensor());
    Simulator s2(rt, ref.cfg, Precision::F32);
    s2.set_heights(h);
    s2.compute_psf();
    const double p_2d = psnr_of(s2.psf_sensor());
    RadialEngine eng(rt, ref.cfg, Precision::F32);
    eng.compute_psf(ring_heights_of_map(h));
    const double p_rad = psnr_of(eng.psf_sensor());
    char buf[400];
    std::snprintf(buf, sizeof buf,
                  "| %s | %.3f | %.3f | %.3f | %+.3f | %+.3f |\n", name.c_str(), p_ref, p_2d, p_rad, p_rad - p_2d, p_2d - p_ref);
    psnr_lines.push_back(buf);
    std::fprintf(stderr, "  psnr   %s", buf);
  }
}

void section_sweep(const Options& o, const Reference& ref) {
  const std::vector<int> levels{2, 4, 8, 16, 32};
  std::vector<Map2D> maps;
  for (int l : levels) {
    Quantizer q;
    q.levels = l;
    maps.push_back(quantize_heights(ref.heights, ref.cfg.h_max_m(), q, 1.0));
  }
  {
    Runtime rt;
    Simulator sim(rt, ref.cfg, Precision::F32);
    Row r;
    r.workload = "sweep";
    r.config = "5 levels, one design at a time, f32";
    r.t = timed(std::max(1, o.repeats / 2), [&] {
      for (const Map2D& m : maps) {
        sim.set_heights(m);
        sim.compute_psf();
      }
      rt.queue().finish();
    });
    r.units = double(5 * ref.cfg.bands);
    add(r);
  }
  {
    Runtime rt;
    Simulator sim(rt, ref.cfg, Precision::F32, maps.size());
    Row r;
    r.workload = "sweep";
    r.config = "5 levels batched in one pass (designs = 5), f32";
    r.t = timed(std::max(1, o.repeats / 2), [&] {
      sim.set_heights_batch(maps);
      sim.compute_psf();
      rt.queue().finish();
    });
    r.units = double(5 * ref.cfg.bands);
    add(r);
  }
  {
    Runtime rt;
    RadialEngine eng(rt, ref.cfg, Precision::F32);
    Row r;
    r.workload = "sweep";
    r.config = "5 levels, radial path, f32 (tables shared)";
    r.t = timed(std::max(1, o.repeats / 2), [&] {
      for (const Map2D& m : maps) eng.compute_psf(ring_heights_of_map(m));
      rt.queue().finish();
    });
    r.units = double(5 * ref.cfg.bands);
    add(r);
  }
}

std::string machine() {
  const std::string cpu = qdo::bench::cpu_model();
  Runtime rt;
  const DeviceInfo& d = rt.info();
  return "CPU: " + cpu + ", " + std::to_string(std::thread::hardware_concurrency()) + " hardware threads; OpenCL device: " +
         d.platform + " / " + d.name + " (driver " + d.driver_version + ", " + std::to_string(d.compute_units) +
         " compute units, fp64 " + (d.fp64 ? "yes" : "no") + ")";
}

void write_report(const Options& o, double total_s) {
  std::ostringstream md;
  md << "Machine: " << machine() << "\n\nN = " << o.n << ", repeats = " << o.repeats
     << " (median (min, max) after one warm-up). err = relative L2 error of the RGB PSF (3 x S x S) against "
        "the float64 / pad N/2 / 2-D / 31-band reference unless the note says otherwise; band err = the same for the "
        "per-band sensor PSF stack.\n\n";
  md << "| workload | configuration | median ms | min ms | max ms | runs | throughput | err | band err | note |\n";
  md << "|---|---|---:|---:|---:|---:|---:|---:|---:|---|\n";
  char buf[512];
  for (const Row& r : rows) {
    auto e = [](double v) {
      if (std::isnan(v)) return std::string("-");
      char b[32];
      std::snprintf(b, sizeof b, "%.2e", v);
      return std::string(b);
    };
    std::snprintf(buf, sizeof buf, "| %s | %s | %.1f | %.1f | %.1f | %zu | %.1f %s/s | %s | %s | %s |\n", r.workload.c_str(),
                  r.config.c_str(), 1e3 * r.t.median(), 1e3 * r.t.s.front(), 1e3 * r.t.s.back(), r.t.s.size(),
                  r.units / r.t.median(), r.unit.c_str(), e(r.err).c_str(), e(r.band_err).c_str(), r.note.c_str());
    md << buf;
  }
  md << "\nSetup per configuration (fresh Runtime; not in the times above):\n\n| configuration | program build/load s | "
        "built / from disk | FFT plan bake s |\n|---|---:|---:|---:|\n";
  for (const Setup& s : setups) {
    std::snprintf(buf, sizeof buf, "| %s | %.2f | %d / %d | %.2f |\n", s.config.c_str(), s.build_s, s.built, s.loaded, s.bake_s);
    md << buf;
  }
  if (!psnr_lines.empty()) {
    md << "\nWiener reconstruction PSNR (dB, mean over the three CAVE scenes, decoder noise 0.001, prior from the same "
          "scenes) through the PSFs of the same design from each path:\n\n| design | reference (f64, pad N/2, 2-D) | 2-D f32 "
          "| radial f32 | radial - 2-D | 2-D - reference |\n|---|---:|---:|---:|---:|---:|\n";
    for (const auto& l : psnr_lines) md << l;
  }
  md << "\nTotal wall time " << to_str(std::round(total_s)) << " s.\n";
  std::cout << md.str();
  if (!o.out.empty()) {
    const std::string tmp = o.out + ".tmp";
    std::ofstream f(tmp);
    f << md.str();
    f.close();
    if (!f || std::rename(tmp.c_str(), o.out.c_str()) != 0) throw Error("bench_pareto: could not write " + o.out);
  }
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto val = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::cerr << "bench_pareto: missing value after " << a << "\n";
        std::exit(2);
      }
      return argv[++i];
    };
    if (a == "--n") o.n = std::stoul(val());
    else if (a == "--repeats") o.repeats = std::stoi(val());
    else if (a == "--sections") {
      const auto v = split_items(val());
      o.sections = std::set<std::string>(v.begin(), v.end());
    } else if (a == "--cave") o.cave = val();
    else if (a == "--no-cpu") o.cpu = false;
    else if (a == "--out") o.out = val();
    else {
      std::cerr << "usage: bench_pareto [--n 1024] [--repeats 5] [--sections psf,image,step,sweep,psnr] [--cave DIR] [--no-cpu] "
                   "[--out FILE.md]\n";
      return a == "--help" ? 0 : 2;
    }
  }
  try {
    if (o.n < 32 || o.n % 8) reject("--n", o.n, "a multiple of 8, at least 32");
    o.cave = resolve_dataset(o.cave, "--cave");
    if (o.repeats < 1) reject("--repeats", o.repeats, ">= 1");
    const auto t0 = Clock::now();
    Reference ref;
    ref.cfg = paper(o.n);
    ref.heights = lens_design(ref.cfg, 550);
    {
      SystemConfig rc = ref.cfg;
      rc.padding_px = o.n / 2;
      Runtime rt;
      Simulator sim(rt, rc, Precision::F64);
      sim.set_heights(ref.heights);
      sim.compute_psf();
      ref.psf_sensor = sim.psf_sensor();
      ref.rgb = rgb_psf(ref.psf_sensor, sim.srf());
      std::fprintf(stderr, "reference: f64, pad N/2 (M = %zu), 31 bands; %s\n", sim.geometry().m, sim.sampling().summary().c_str());
    }
    if (o.sections.count("psf")) section_psf(o, ref);
    if (o.sections.count("image")) section_image(o, ref);
    if (o.sections.count("step")) section_step(o, ref);
    if (o.sections.count("sweep")) section_sweep(o, ref);
    if (o.sections.count("psnr")) section_psnr(o, ref);
    write_report(o, seconds_since(t0));
  } catch (const std::exception& e) {
    std::cerr << "bench_pareto: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
