// bench_psf: timing and accuracy of the PSF stack (REFERENCE §1 physics) for several DOE sizes.
//
// For each N (paper preset physics: 31 bands, 4 um pitch, z = 50 mm, d = 1 m, padding N/4 per
// side, design = lens_design(cfg, 550 nm)) it measures
//   1. OpenCL Simulator::compute_psf() + queue.finish() per precision (median/min/max of
//      --repeats runs after --warmup runs); program build/load and FFT plan bake reported apart;
//   2. the FFT floors, in the same run: (a) the bare FFTW floor, fftwf/fftw on a host array with
//      every core (FFTW_MEASURE), one forward + one inverse 2-D FFT of bands x M x M complex values,
//      unpruned: the fastest FFT on the machine for the transforms compute_psf needs; (b) the
//      transforms compute_psf itself runs (the runtime's backend, with the field's zero-padding
//      hint) on a device buffer, nothing else. The ratio column is the PSF time over (a);
//      (c) the memory floor of compute_psf's passes outside the FFT (memory_floor below);
//   2b. compute_psf + psf_sensor_vjp (forward and adjoint to dL/dH) and its ratio to compute_psf;
//   1b. on CPU devices with the FFTW backend, 1 and 2b again with the host fusion off
//      (Simulator::set_host_fusion(false): pruned FFT plan + kernels), same run; 1c. 1 with the
//      field not kept (Simulator::set_keep_field(false): streamed, as `qdo psf` runs it);
//   3. the CPU reference ref::psf_stack (double, FFTW_ESTIMATE, single thread);
//   4. the error of each OpenCL PSF stack (bands x N x N) against the CPU reference.
// Speed is never asserted; this program only reports.
//
// Usage: bench_psf [--sizes 256,512,1024] [--repeats 5] [--warmup 1] [--precision f32,f64]
//                  [--no-cpu] [--out FILE.md]
// Device: QDO_DEVICE (see runtime.hpp); kernel disk cache: QDO_CACHE_DIR.
#include <fftw3.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <fstream>
#include <iostream>
#include <memory>
#include <optional>
#include <random>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/physics/cpu_reference.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/fft.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/runtime/types.hpp"

#include "bench_util.hpp"

namespace {

using qdo::bench::Clock;
using qdo::bench::cpu_model;
using qdo::bench::fmt;
using qdo::bench::seconds_since;
using qdo::split_items;
using qdo::bench::summarize;
using qdo::bench::time_it;
using qdo::bench::Timing;

struct Options {
  std::vector<std::size_t> sizes{256, 512, 1024};
  int repeats = 5, warmup = 1;
  std::vector<qdo::Precision> precisions{qdo::Precision::F32, qdo::Precision::F64};
  bool cpu = true;
  std::string out;
};

[[noreturn]] void usage(const std::string& err) {
  if (!err.empty()) std::cerr << "bench_psf: " << err << "\n";
  std::cerr << "usage: bench_psf [--sizes 256,512,1024] [--repeats R=5] [--warmup W=1] [--precision f32,f64]\n"
               "                 [--no-cpu] [--out FILE.md]\n";
  std::exit(err.empty() ? 0 : 2);
}

Options parse(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) usage("missing value after " + a);
      return argv[++i];
    };
    try {
      if (a == "--sizes") {
        o.sizes.clear();
        for (const auto& s : split_items(value(), ',')) o.sizes.push_back(static_cast<std::size_t>(std::stoul(s)));
        if (o.sizes.empty()) usage("--sizes needs at least one size");
      } else if (a == "--repeats") {
        o.repeats = std::stoi(value());
        if (o.repeats < 1) usage("--repeats must be >= 1");
      } else if (a == "--warmup") {
        o.warmup = std::stoi(value());
        if (o.warmup < 0) usage("--warmup must be >= 0");
      } else if (a == "--precision") {
        o.precisions.clear();
        for (const auto& s : split_items(value(), ',')) o.precisions.push_back(qdo::precision_from_string(s));
        if (o.precisions.empty()) usage("--precision needs at least one of f32, f64");
      } else if (a == "--no-cpu") {
        o.cpu = false;
      } else if (a == "--out") {
        o.out = value();
      } else if (a == "--help" || a == "-h") {
        usage("");
      } else {
        usage("unknown argument " + a);
      }
    } catch (const std::logic_error&) {  // stoi/stoul failures
      usage("bad value for " + a);
    } catch (const qdo::Error& e) {
      usage(e.what());
    }
  }
  return o;
}

struct ErrStats {
  double rel_l2 = 0;       // ||a - b||_2 / ||b||_2 over the whole stack
  double max_abs_rel = 0;  // max |a - b| / max |b|
};

ErrStats compare(const std::vector<double>& a, const std::vector<double>& ref) {
  double num = 0, den = 0, max_abs = 0, max_ref = 0;
  for (std::size_t i = 0; i < a.size() && i < ref.size(); ++i) {
    const double d = a[i] - ref[i];
    num += d * d;
    den += ref[i] * ref[i];
    max_abs = std::max(max_abs, std::abs(d));
    max_ref = std::max(max_ref, std::abs(ref[i]));
  }
  ErrStats e;
  e.rel_l2 = den > 0 ? std::sqrt(num / den) : 0;
  e.max_abs_rel = max_ref > 0 ? max_abs / max_ref : 0;
  return e;
}

// The bare FFTW floor: a forward and an inverse 2-D FFT of bands x m x m complex values on a
// host array (fftwf for f32, fftw for f64), planned with FFTW_MEASURE on every core.
template <typename Complex, typename Plan, typename MakePlan, typename Exec, typename Destroy>
Timing fftw_floor_impl(std::size_t m, std::size_t bands, int warmup, int repeats, MakePlan make, Exec exec, Destroy destroy) {
  std::vector<Complex> a(bands * m * m);
  for (auto& v : a) v[0] = v[1] = 0;
  const int n[2] = {int(m), int(m)};
  Plan f = make(n, int(bands), a.data(), FFTW_FORWARD), b = make(n, int(bands), a.data(), FFTW_BACKWARD);
  for (auto& v : a) v[0] = v[1] = 1;
  const Timing t = time_it(warmup, repeats, [&] {
    exec(f);
    exec(b);
  });
  destroy(f);
  destroy(b);
  return t;
}
Timing fftw_floor(qdo::Precision p, std::size_t m, std::size_t bands, const Options& opt) {
  const int threads = int(std::max(1u, std::thread::hardware_concurrency()));
  if (p == qdo::Precision::F64) {
    fftw_init_threads();
    fftw_plan_with_nthreads(threads);
    const Timing t = fftw_floor_impl<fftw_complex, fftw_plan>(
        m, bands, opt.warmup, opt.repeats,
        [](const int* n, int howmany, fftw_complex* d, int sign) {
          return fftw_plan_many_dft(2, n, howmany, d, nullptr, 1, n[0] * n[1], d, nullptr, 1, n[0] * n[1], sign, FFTW_MEASURE);
        },
        [](fftw_plan pl) { fftw_execute(pl); }, [](fftw_plan pl) { fftw_destroy_plan(pl); });
    fftw_plan_with_nthreads(1);
    return t;
  }
  fftwf_init_threads();
  fftwf_plan_with_nthreads(threads);
  const Timing t = fftw_floor_impl<fftwf_complex, fftwf_plan>(
      m, bands, opt.warmup, opt.repeats,
      [](const int* n, int howmany, fftwf_complex* d, int sign) {
        return fftwf_plan_many_dft(2, n, howmany, d, nullptr, 1, n[0] * n[1], d, nullptr, 1, n[0] * n[1], sign, FFTW_MEASURE);
      },
      [](fftwf_plan pl) { fftwf_execute(pl); }, [](fftwf_plan pl) { fftwf_destroy_plan(pl); });
  fftwf_plan_with_nthreads(1);
  return t;
}

// The memory floor of compute_psf's passes outside the FFT, on host arrays with every core: the
// same bytes moved the same number of times, with no arithmetic beyond a multiply: (1) write the
// bands x M x M complex window (the DOE field kernel writes it all, zeros included), (2) read and
// write it once (the transfer-function pass), (3) read the N x N crop and write the intensity
// (bands x N x N real), (4) read that and write the S x S sensor stack (2 x 2 box, S = N/2), (5)
// read and write the sensor stack (normalisation). An unfused pipeline cannot be faster than
// this floor plus the FFT floor; only fusing passes into the transforms would go below it.
Timing memory_floor(qdo::Precision p, std::size_t n, std::size_t m, std::size_t bands, const Options& opt) {
  const unsigned threads = std::max(1u, std::thread::hardware_concurrency());
  const auto run = [&](auto zero) {
    using T = decltype(zero);
    std::vector<T> field(bands * m * m * 2), native(bands * n * n), sensor(bands * (n / 2) * (n / 2));
    const std::size_t s = n / 2;
    const auto per_band = [&](auto&& f) {
      std::vector<std::thread> pool;
      for (unsigned t = 0; t < threads; ++t)
        pool.emplace_back([&, t] {
          for (std::size_t b = t; b < bands; b += threads) f(b);
        });
      for (auto& th : pool) th.join();
    };
    return time_it(opt.warmup, opt.repeats, [&] {
      per_band([&](std::size_t b) {
        T* w = field.data() + b * m * m * 2;
        std::fill(w, w + m * m * 2, T(0.5));
      });
      per_band([&](std::size_t b) {
        T* w = field.data() + b * m * m * 2;
        for (std::size_t i = 0; i < m * m * 2; ++i) w[i] *= T(0.999);
      });
      per_band([&](std::size_t b) {
        const T* w = field.data() + b * m * m * 2;
        T* o = native.data() + b * n * n;
        for (std::size_t y = 0; y < n; ++y)
          for (std::size_t x = 0; x < n; ++x) {
            const T re = w[2 * (y * m + x)], im = w[2 * (y * m + x) + 1];
            o[y * n + x] = re * re + im * im;
          }
      });
      per_band([&](std::size_t b) {
        const T* in = native.data() + b * n * n;
        T* o = sensor.data() + b * s * s;
        for (std::size_t y = 0; y < s; ++y)
          for (std::size_t x = 0; x < s; ++x)
            o[y * s + x] = in[2 * y * n + 2 * x] + in[2 * y * n + 2 * x + 1] + in[(2 * y + 1) * n + 2 * x] +
                           in[(2 * y + 1) * n + 2 * x + 1];
      });
      per_band([&](std::size_t b) {
        T* o = sensor.data() + b * s * s;
        T sum = 0;
        for (std::size_t i = 0; i < s * s; ++i) sum += o[i];
        for (std::size_t i = 0; i < s * s; ++i) o[i] /= sum;
      });
    });
  };
  return p == qdo::Precision::F64 ? run(0.0) : run(0.0f);
}

// One row of the results table.
struct Row {
  std::size_t n = 0, m = 0;
  std::string path;            // "OpenCL f32", "clFFT floor f64", "CPU ref f64", ...
  std::optional<Timing> t;     // absent when the configuration failed
  std::size_t bands = 0;
  std::string floor_ratio;     // PSF time / FFT floor, OpenCL rows only
  bool ratio_to_floor = false; // floor_ratio to be filled in once the floor is measured
  std::string rel_l2, max_err; // OpenCL rows with a CPU reference only
  std::string note;
};

struct Setup {
  std::size_t n = 0;
  std::string precision;
  double build_s = 0, bake_s = 0;
  int built = 0, loaded = 0;
};

std::string table(const std::vector<Row>& rows) {
  std::ostringstream o;
  o << "| N | M | path | median ms | min ms | max ms | runs | bands/s | / FFT floor | rel. L2 err | max abs err / max |\n"
       "|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|\n";
  for (const auto& r : rows) {
    o << "| " << r.n << " | " << r.m << " | " << r.path << " | ";
    if (r.t) {
      o << fmt("%.1f", r.t->median * 1e3) << " | " << fmt("%.1f", r.t->min * 1e3) << " | "
        << fmt("%.1f", r.t->max * 1e3) << " | " << r.t->runs << " | "
        << (r.bands ? fmt("%.1f", double(r.bands) / r.t->median) : std::string("-")) << " | ";
    } else {
      o << "- | - | - | - | - | ";
    }
    o << (r.floor_ratio.empty() ? "-" : r.floor_ratio) << " | " << (r.rel_l2.empty() ? "-" : r.rel_l2) << " | "
      << (r.max_err.empty() ? "-" : r.max_err) << " |";
    if (!r.note.empty()) o << " " << r.note;
    o << "\n";
  }
  return o.str();
}

std::string setup_table(const std::vector<Setup>& s) {
  std::ostringstream o;
  o << "| N | precision | program build/load s | programs built / loaded from disk | FFT plan bake s |\n"
       "|---:|---|---:|---:|---:|\n";
  for (const auto& x : s)
    o << "| " << x.n << " | " << x.precision << " | " << fmt("%.2f", x.build_s) << " | " << x.built << " / "
      << x.loaded << " | " << fmt("%.2f", x.bake_s) << " |\n";
  return o.str();
}

}  // namespace

int main(int argc, char** argv) {
  const Options opt = parse(argc, argv);
  const auto t_start = Clock::now();

  std::string device_line;
  try {
    qdo::Runtime probe;
    const auto& i = probe.info();
    device_line = i.platform + " / " + i.name + " (" + i.type + ", driver " + i.driver_version + ", " + i.version +
                  ", " + std::to_string(i.compute_units) + " compute units, fp64 " + (i.fp64 ? "yes" : "no") + ")";
  } catch (const std::exception& e) {
    std::cerr << "bench_psf: no OpenCL device: " << e.what() << "\n";
    return 1;
  }
  const std::string machine = "CPU: " + cpu_model() + ", nproc " + std::to_string(std::thread::hardware_concurrency()) +
                              "; OpenCL device: " + device_line;
  std::cout << "bench_psf: PSF stack (paper physics: 31 bands, 4 um pitch, z = 50 mm, d = 1 m, padding N/4,"
               " lens_design 550 nm)\n"
            << "repeats " << opt.repeats << ", warmup " << opt.warmup << "\n\n"
            << std::flush;

  std::vector<Row> rows;
  std::vector<Setup> setups;
  std::vector<std::string> notes;

  for (const std::size_t n : opt.sizes) {
    qdo::SystemConfig cfg = qdo::preset_config("paper");
    cfg.n = n;
    cfg.padding_px = n / 4;  // N/4 per side, as in the paper
    std::optional<qdo::Map2D> design;
    std::size_t m = 0;
    try {
      cfg.validate();
      m = qdo::PropagationGeometry::from_config(cfg).m;
      design = qdo::lens_design(cfg, 550);
    } catch (const std::exception& e) {
      Row r;
      r.n = n;
      r.path = "config";
      r.note = std::string("FAILED: ") + e.what();
      rows.push_back(r);
      std::cerr << "N = " << n << ": " << r.note << "\n";
      continue;
    }
    const std::size_t bands = cfg.bands;
    bool sampling_noted = false;  // one sampling note per N (physics, not speed)
    auto note_sampling = [&](const qdo::SamplingReport& rep, const std::string& from) {
      if (sampling_noted) return;
      sampling_noted = true;
      std::size_t under = 0;
      for (const auto& b : rep.bands) under += b.undersampled ? 1 : 0;
      notes.push_back("N = " + std::to_string(n) + " (M = " + std::to_string(m) + "): Fresnel transfer function under-sampled in " +
                      std::to_string(under) + " of " + std::to_string(rep.bands.size()) +
                      " bands; worst aliased spectral energy fraction " + fmt("%.2e", rep.worst_aliased_fraction()) +
                      (rep.any_inaccurate() ? " (above the 1e-4 tolerance: the PSF is aliased at this N with z = 50 mm)" : "") +
                      "; worst field energy outside the N x N crop " + fmt("%.2e", rep.worst_energy_outside()) + " [" +
                      from + "].");
    };

    // 3. CPU reference (bands x N x N, double). Stateless, so no warmup; fewer runs when slow.
    std::optional<qdo::RealStack> ref_psf;
    if (opt.cpu) {
      Row r;
      r.n = n;
      r.m = m;
      r.path = "CPU ref f64 (FFTW, 1 thread)";
      r.bands = bands;
      try {
        std::vector<double> t;
        int runs = opt.repeats;
        for (int i = 0; i < runs; ++i) {
          const auto t0 = Clock::now();
          qdo::ref::PsfResult res = qdo::ref::psf_stack(cfg, *design);
          t.push_back(seconds_since(t0));
          if (!ref_psf) {
            ref_psf = std::move(res.psf);
            note_sampling(res.sampling, "CPU reference");
          }
          if (i == 0 && t[0] > 2.0 && runs > 3) {
            runs = 3;
            notes.push_back("N = " + std::to_string(n) + ": CPU reference timed over 3 runs (one run took " +
                            fmt("%.1f", t[0]) + " s).");
          }
        }
        r.t = summarize(t);
      } catch (const std::exception& e) {
        r.note = std::string("FAILED: ") + e.what();
      }
      std::cerr << "N = " << n << " CPU reference: " << (r.t ? fmt("%.1f ms", r.t->median * 1e3) : r.note) << "\n";
      rows.push_back(r);
    }

    for (const qdo::Precision p : opt.precisions) {
      const std::string ps = qdo::to_string(p);
      Row psf_row, fft_row, floor_row, mem_row;
      std::vector<Row> extra_rows;
      psf_row.n = fft_row.n = n;
      psf_row.m = fft_row.m = m;
      psf_row.bands = fft_row.bands = bands;
      psf_row.path = "OpenCL " + ps + " compute_psf";
      try {
        // A fresh Runtime per configuration: its FFT plans and buffers are freed afterwards,
        // and program build/load is measured per configuration (disk cache after the first).
        qdo::Runtime rt;
        const double build0 = rt.build_seconds(), bake0 = rt.fft_bake_seconds();
        const int built0 = rt.programs_built(), loaded0 = rt.programs_loaded_from_disk();
        qdo::Simulator sim(rt, cfg, p);
        Setup s;
        s.n = n;
        s.precision = ps;
        s.build_s = rt.build_seconds() - build0;
        s.bake_s = rt.fft_bake_seconds() - bake0;
        s.built = rt.programs_built() - built0;
        s.loaded = rt.programs_loaded_from_disk() - loaded0;
        setups.push_back(s);

        sim.set_heights(*design);
        // 1. compute_psf: DOE field, FFT, transfer function, IFFT, crop, normalise, resample.
        psf_row.t = time_it(opt.warmup, opt.repeats, [&] {
          sim.compute_psf();
          rt.queue().finish();
        });
        note_sampling(sim.sampling(), "OpenCL " + ps);
        if (ref_psf) {
          const qdo::RealStack psf = sim.psf_native();  // bands x N x N
          const ErrStats e = compare(psf.data, ref_psf->data);
          psf_row.rel_l2 = fmt("%.2e", e.rel_l2);
          psf_row.max_err = fmt("%.2e", e.max_abs_rel);
        }
        std::cerr << "N = " << n << " OpenCL " << ps << ": " << fmt("%.1f ms", psf_row.t->median * 1e3) << "\n";

        // 2b. Forward + adjoint: compute_psf, then dL/dH for a fixed gradient on the sensor stack.
        {
          qdo::RealStack g(bands, sim.sensor_size(), sim.sensor_size());
          std::mt19937_64 rng(7);
          std::uniform_real_distribution<double> u(-1, 1);
          for (double& v : g.data) v = u(rng);
          Row adj;
          adj.n = n;
          adj.m = m;
          adj.bands = bands;
          adj.path = "OpenCL " + ps + " compute_psf + psf_sensor_vjp (forward + adjoint)";
          const auto forward = [&] {
            sim.compute_psf();
            rt.queue().finish();
          };
          const auto forward_adjoint = [&] {
            sim.compute_psf();
            (void)sim.psf_sensor_vjp(g);
          };
          adj.t = time_it(opt.warmup, opt.repeats, forward_adjoint);
          adj.floor_ratio = fmt("%.2f x fwd", adj.t->median / psf_row.t->median);
          extra_rows.push_back(adj);
          // 1b. With the host fusion off (CPU devices with the FFTW backend only): the pruned
          // FFT plan plus the transfer-function, crop and adjoint kernels, the path of every
          // other backend; same heights, same gradient, same run.
          if (sim.uses_host_propagation()) {
            // The forward timed under one setting, with its error against the reference.
            const auto forward_row = [&](const std::string& what) {
              Row r;
              r.n = n;
              r.m = m;
              r.bands = bands;
              r.path = "OpenCL " + ps + " compute_psf, " + what;
              r.t = time_it(opt.warmup, opt.repeats, forward);
              if (ref_psf) {
                const ErrStats e = compare(sim.psf_native().data, ref_psf->data);
                r.rel_l2 = fmt("%.2e", e.rel_l2);
                r.max_err = fmt("%.2e", e.max_abs_rel);
              }
              r.ratio_to_floor = true;
              std::cerr << "N = " << n << " OpenCL " << ps << " " << what << ": " << fmt("%.1f ms", r.t->median * 1e3) << "\n";
              return r;
            };
            sim.set_host_fusion(false);
            const Row off = forward_row("host fusion off (pruned FFT plan + kernels)");
            Row off_adj = off;
            off_adj.rel_l2 = off_adj.max_err = "";
            off_adj.ratio_to_floor = false;
            off_adj.path = "OpenCL " + ps + " compute_psf + psf_sensor_vjp, host fusion off";
            off_adj.t = time_it(opt.warmup, opt.repeats, forward_adjoint);
            off_adj.floor_ratio = fmt("%.2f x fwd", off_adj.t->median / off.t->median);
            extra_rows.push_back(off);
            extra_rows.push_back(off_adj);
            sim.set_host_fusion(true);
            // 1c. The field not kept (Simulator::set_keep_field(false), as `qdo psf` runs it):
            // field and propagation streamed a few planes at a time through one small buffer.
            sim.set_keep_field(false);
            extra_rows.push_back(forward_row("field not kept (streamed; `qdo psf`)"));
            sim.set_keep_field(true);
          }
        }
        // 2. (b) The transforms compute_psf runs: its own plan (backend and hint), on a device buffer.
        const std::string backend = qdo::to_string(rt.fft_backend());
        fft_row.path = backend + " " + ps + " (fwd + inv; compute_psf's plan and zero-padding hint)";
        try {
          qdo::FftPlan& fft = rt.fft(m, m, bands, p, rt.fft_backend(), qdo::FftZeroPad{n, m, n, m});
          const std::size_t bytes = bands * m * m * 2 * qdo::real_size(p);
          cl::Buffer buf(rt.context(), CL_MEM_READ_WRITE, bytes);
          if (p == qdo::Precision::F64)
            rt.queue().enqueueFillBuffer(buf, 0.0, 0, bytes);
          else
            rt.queue().enqueueFillBuffer(buf, 0.0f, 0, bytes);
          rt.queue().finish();
          fft_row.t = time_it(opt.warmup, opt.repeats, [&] {
            fft.forward(buf);
            fft.inverse(buf);
            rt.queue().finish();
          });
          std::cerr << "N = " << n << " " << backend << " " << ps << ": " << fmt("%.1f ms", fft_row.t->median * 1e3) << "\n";
        } catch (const std::exception& e) {
          fft_row.note = std::string("FAILED: ") + e.what();
        }
        // 2. (a) The bare FFTW floor on a host array, every core, unpruned.
        floor_row.n = n;
        floor_row.m = m;
        floor_row.bands = bands;
        floor_row.path = "bare FFTW " + ps + " floor (host array, " + std::to_string(std::thread::hardware_concurrency()) +
                         " threads, fwd + inv)";
        floor_row.t = fftw_floor(p, m, bands, opt);
        psf_row.floor_ratio = fmt("%.2f", psf_row.t->median / floor_row.t->median);
        for (Row& r : extra_rows)
          if (r.ratio_to_floor && r.t) r.floor_ratio = fmt("%.2f", r.t->median / floor_row.t->median);
        std::cerr << "N = " << n << " bare FFTW floor " << ps << ": " << fmt("%.1f ms", floor_row.t->median * 1e3) << "\n";
        // 2. (c) The memory floor of the passes outside the FFT; its ratio column holds
        // (FFT floor + memory floor) / FFT floor, the best an unfused pipeline can reach.
        mem_row.n = n;
        mem_row.m = m;
        mem_row.bands = bands;
        mem_row.path = "memory floor of the non-FFT passes (host arrays, " +
                       std::to_string(std::thread::hardware_concurrency()) + " threads: field write, TF read+write, crop, resample, normalise)";
        mem_row.t = memory_floor(p, n, m, bands, opt);
        mem_row.floor_ratio = fmt("%.2f (with the FFT floor)", (floor_row.t->median + mem_row.t->median) / floor_row.t->median);
        std::cerr << "N = " << n << " memory floor " << ps << ": " << fmt("%.1f ms", mem_row.t->median * 1e3) << "\n";
      } catch (const cl::Error& e) {
        psf_row.note = std::string("FAILED: ") + e.what() + " " + qdo::cl_error_name(e.err());
        std::cerr << "N = " << n << " OpenCL " << ps << ": " << psf_row.note << "\n";
      } catch (const std::exception& e) {
        psf_row.note = std::string("FAILED: ") + e.what();
        std::cerr << "N = " << n << " OpenCL " << ps << ": " << psf_row.note << "\n";
      }
      rows.push_back(psf_row);
      for (const Row& r : extra_rows) rows.push_back(r);
      if (psf_row.t) rows.push_back(fft_row);
      if (floor_row.t) rows.push_back(floor_row);
      if (mem_row.t) rows.push_back(mem_row);
    }
  }

  const double total_s = seconds_since(t_start);
  std::ostringstream md;
  md << "Machine: " << machine << "\n\n"
     << "Times: median (min, max) of `runs` runs after " << opt.warmup
     << " warmup run(s); OpenCL times are compute_psf() + queue.finish(). "
        "bands/s = bands / median. Errors: OpenCL PSF stack (bands x N x N) against the CPU reference "
        "(double, FFTW).\n\n"
     << table(rows) << "\n"
     << "Setup, not included above (per configuration, fresh Runtime):\n\n"
     << setup_table(setups);
  for (const auto& nt : notes) md << "\n" << nt << "\n";
  md << "\nTotal benchmark wall time: " << fmt("%.1f", total_s) << " s.\n";

  std::cout << md.str() << std::flush;
  if (!opt.out.empty()) {
    std::ofstream f(opt.out);
    f << "# bench_psf\n\n" << md.str();
    if (!f) {
      std::cerr << "bench_psf: could not write " << opt.out << "\n";
      return 1;
    }
    std::cout << "wrote " << opt.out << "\n";
  }
  return 0;
}
