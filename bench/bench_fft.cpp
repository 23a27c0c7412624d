// bench_fft: the bare batched 2-D FFT of the project's workloads on each FFT backend (clFFT,
// VkFFT, and FFTW on a CPU device), so the two can be compared on time, plan bake time and accuracy.
//
// Workloads (complex interleaved, in place, batch x rows x cols, see fft.hpp):
//   PSF:  bands x M x M for each M of --psf (the PSF window M = 1.5 N: 384, 768, 1536 for
//         N = 256, 512, 1024); unless --no-zero-pad also the VkFFT plan with the zero-padding hint of
//         an N x N field stored with its optical axis at index 0 (zero block [N/2, M - N/2) on
//         both axes, FftZeroPad), the layout the PSF path could use;
//   conv: bands x P x P for each P of --conv (the linear-convolution grid: 1024 for a 512 scene
//         and a 512 sensor PSF, 768 for 512 + 256, 512 for 256 + 256).
// For each workload, precision and backend it reports: the plan bake time (Runtime::fft,
// VkFFT's kernel generation and builds included), the first forward + inverse (PoCL compiles
// each kernel's work-group function at its first launch), the median / min / max of
// forward + inverse + queue.finish() over --repeats runs after --warmup runs, the rate in
// GFlop/s (5 n log2 n per transform of n points, two transforms per run), the time relative to
// clFFT, and the error of the forward transform of one seeded random input against FFTW in
// double (relative L2 over the whole batch, max abs error / max abs value). The input is drawn
// in float32 and promoted, so one FFTW reference serves both precisions.
// Speed is never asserted; this program only reports. Bake and first-call times depend on
// PoCL's kernel cache (POCL_KERNEL_CACHE, ~/.cache/pocl): on a warm cache they are loads.
//
// Usage: bench_fft [--psf 384,768,1536] [--conv 512,768,1024] [--bands 31] [--repeats 5]
//                  [--warmup 1] [--precision f32,f64] [--backends clfft,vkfft,fftw] [--no-zero-pad]
//                  [--no-error] [--out FILE.md]
// Quick check (< 1 min): bench_fft --psf 384 --conv 512 --bands 4 --repeats 3
// Device: QDO_DEVICE (see runtime.hpp).
#include <clFFT.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <fstream>
#include <iostream>
#include <map>
#include <optional>
#include <random>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "qdo/runtime/error.hpp"
#include "qdo/runtime/fft.hpp"
#include "qdo/runtime/fftw2.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/runtime/types.hpp"

#include "bench_util.hpp"

namespace {

using qdo::bench::Clock;
using qdo::bench::cpu_model;
using qdo::bench::fmt;
using qdo::bench::seconds_since;
using qdo::split_items;
using qdo::bench::Timing;

struct Options {
  std::vector<std::size_t> psf{384, 768, 1536}, conv{512, 768, 1024};
  std::size_t bands = 31;
  int repeats = 5, warmup = 1;
  std::vector<qdo::Precision> precisions{qdo::Precision::F32, qdo::Precision::F64};
  std::vector<qdo::FftBackend> backends;  // empty: clFFT, VkFFT and, on a CPU device, FFTW
  bool zero_pad = true, error = true;
  std::string out;
};

[[noreturn]] void usage(const std::string& err) {
  if (!err.empty()) std::cerr << "bench_fft: " << err << "\n";
  std::cerr << "usage: bench_fft [--psf 384,768,1536] [--conv 512,768,1024] [--bands B=31] [--repeats R=5]\n"
               "                 [--warmup W=1] [--precision f32,f64] [--backends clfft,vkfft,fftw] [--no-zero-pad]\n"
               "                 [--no-error] [--out FILE.md]\n"
               "  --psf/--conv take square sizes (an empty list: --psf none); --no-zero-pad drops the VkFFT\n"
               "  plan with the PSF field's zero-padding hint (N = 2M/3); --no-error skips FFTW.\n";
  std::exit(err.empty() ? 0 : 2);
}

std::vector<std::size_t> sizes(const std::string& v) {
  std::vector<std::size_t> out;
  if (v == "none") return out;
  for (const auto& s : split_items(v, ',')) {
    const unsigned long n = std::stoul(s);
    if (n < 2) usage("sizes must be >= 2");
    out.push_back(static_cast<std::size_t>(n));
  }
  return out;
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
      if (a == "--psf") {
        o.psf = sizes(value());
      } else if (a == "--conv") {
        o.conv = sizes(value());
      } else if (a == "--bands") {
        const int b = std::stoi(value());
        if (b < 1) usage("--bands must be >= 1");
        o.bands = static_cast<std::size_t>(b);
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
      } else if (a == "--backends") {
        o.backends.clear();
        for (const auto& s : split_items(value(), ',')) o.backends.push_back(qdo::fft_backend_from_string(s, "--backends"));
        if (o.backends.empty()) usage("--backends needs at least one of clfft, vkfft, fftw");
      } else if (a == "--no-zero-pad") {
        o.zero_pad = false;
      } else if (a == "--no-error") {
        o.error = false;
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
  if (o.psf.empty() && o.conv.empty()) usage("nothing to run: --psf and --conv are both empty");
  return o;
}

// One workload: batch x rows x cols, with an optional zero-padding hint.
struct Workload {
  std::string name;  // "PSF N=256", "conv"
  std::size_t batch = 0, rows = 0, cols = 0;
  qdo::FftZeroPad zero_pad;  // any() only for the hinted PSF variant
};

bool in_zero_block(const qdo::FftZeroPad& z, std::size_t y, std::size_t x) {
  return (y >= z.row_begin && y < z.row_end) || (x >= z.col_begin && x < z.col_end);
}

// Plane t of the benchmark input (rows x cols complex, row-major), re and im uniform in [-1, 1]
// drawn in float32 (exact in both precisions), seeded by the plane index, zero in the hint's
// block. Regenerated on demand so the whole batch never has to be kept in double on the host.
std::vector<qdo::cdouble> input_plane(const Workload& w, std::size_t t) {
  std::mt19937_64 rng(1000 + t);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  std::vector<qdo::cdouble> p(w.rows * w.cols);
  for (std::size_t y = 0; y < w.rows; ++y)
    for (std::size_t x = 0; x < w.cols; ++x) {
      const float re = u(rng), im = u(rng);
      p[y * w.cols + x] = in_zero_block(w.zero_pad, y, x) ? qdo::cdouble(0, 0) : qdo::cdouble(re, im);
    }
  return p;
}

// Interleaved (re, im) bytes of the whole batch in precision p.
std::vector<char> input_bytes(const Workload& w, qdo::Precision p) {
  const std::size_t plane = w.rows * w.cols;
  std::vector<char> bytes(w.batch * plane * 2 * qdo::real_size(p));
  for (std::size_t t = 0; t < w.batch; ++t) {
    const auto v = input_plane(w, t);
    for (std::size_t i = 0; i < plane; ++i) {
      const std::size_t k = 2 * (t * plane + i);
      if (p == qdo::Precision::F64) {
        reinterpret_cast<double*>(bytes.data())[k] = v[i].real();
        reinterpret_cast<double*>(bytes.data())[k + 1] = v[i].imag();
      } else {
        reinterpret_cast<float*>(bytes.data())[k] = float(v[i].real());
        reinterpret_cast<float*>(bytes.data())[k + 1] = float(v[i].imag());
      }
    }
  }
  return bytes;
}

struct ErrStats {
  double rel_l2 = 0, max_abs_rel = 0;
};

// The forward transform in `bytes` (precision p) against FFTW in double, plane by plane.
ErrStats forward_error(const Workload& w, qdo::Precision p, const std::vector<char>& bytes) {
  const std::size_t plane = w.rows * w.cols;
  double num = 0, den = 0, max_abs = 0, max_ref = 0;
  for (std::size_t t = 0; t < w.batch; ++t) {
    qdo::ComplexStack ref(1, w.rows, w.cols);
    ref.data = input_plane(w, t);
    qdo::fftw2(ref, true);
    for (std::size_t i = 0; i < plane; ++i) {
      const std::size_t k = 2 * (t * plane + i);
      const qdo::cdouble got =
          p == qdo::Precision::F64
              ? qdo::cdouble(reinterpret_cast<const double*>(bytes.data())[k], reinterpret_cast<const double*>(bytes.data())[k + 1])
              : qdo::cdouble(reinterpret_cast<const float*>(bytes.data())[k], reinterpret_cast<const float*>(bytes.data())[k + 1]);
      const double d = std::abs(got - ref.data[i]), r = std::abs(ref.data[i]);
      num += d * d;
      den += r * r;
      max_abs = std::max(max_abs, d);
      max_ref = std::max(max_ref, r);
    }
  }
  return {den > 0 ? std::sqrt(num / den) : 0, max_ref > 0 ? max_abs / max_ref : 0};
}

struct Row {
  Workload w;
  std::string precision, backend;
  std::optional<Timing> t;  // absent when the configuration failed
  double bake_s = 0, first_s = 0;
  std::optional<ErrStats> err;
  std::string vs_clfft, note;
};

double gflops(const Workload& w, double seconds) {
  const double n = double(w.rows * w.cols);
  return 2.0 * double(w.batch) * 5.0 * n * std::log2(n) / seconds * 1e-9;
}

Row run_one(qdo::Runtime& rt, const Workload& w, qdo::Precision p, qdo::FftBackend b, const Options& opt) {
  Row r;
  r.w = w;
  r.precision = qdo::to_string(p);
  r.backend = qdo::to_string(b) + (w.zero_pad.any() ? " + zero-pad hint" : "");
  try {
    qdo::FftPlan& plan = rt.fft(w.rows, w.cols, w.batch, p, b, w.zero_pad);
    r.bake_s = plan.bake_seconds();
    std::vector<char> bytes = input_bytes(w, p);
    cl::Buffer buf(rt.context(), CL_MEM_READ_WRITE | CL_MEM_COPY_HOST_PTR, bytes.size(), bytes.data());
    auto once = [&] {
      plan.forward(buf);
      plan.inverse(buf);
      rt.queue().finish();
    };
    // The first call after the bake: PoCL compiles each kernel's work-group function here.
    const auto t_first = Clock::now();
    once();
    r.first_s = seconds_since(t_first);
    if (opt.error) {
      rt.queue().enqueueWriteBuffer(buf, CL_TRUE, 0, bytes.size(), bytes.data());
      plan.forward(buf);
      rt.queue().enqueueReadBuffer(buf, CL_TRUE, 0, bytes.size(), bytes.data());
      r.err = forward_error(w, p, bytes);
      plan.inverse(buf);  // back to the input (up to rounding): the timed runs see bounded data
      rt.queue().finish();
    }
    r.t = qdo::bench::time_it(opt.warmup, opt.repeats, once);
  } catch (const std::exception& e) {
    r.note = e.what();
  }
  return r;
}

std::string table_header() {
  return "| workload | batch x rows x cols | prec | backend | bake s | first call s | median ms | min ms | max ms | runs "
         "| GFlop/s | time / clFFT | rel. L2 err vs FFTW | max abs err / max |\n"
         "|---|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n";
}

std::string table_row(const Row& r) {
  std::ostringstream o;
  o << "| " << r.w.name << " | " << r.w.batch << " x " << r.w.rows << " x " << r.w.cols << " | " << r.precision
    << " | " << r.backend << " | ";
  if (!r.t) {
    o << "failed: " << r.note << " | | | | | | | | | |\n";
    return o.str();
  }
  o << fmt("%.3f", r.bake_s) << " | " << fmt("%.3f", r.first_s) << " | " << fmt("%.1f", r.t->median * 1e3) << " | "
    << fmt("%.1f", r.t->min * 1e3) << " | " << fmt("%.1f", r.t->max * 1e3) << " | " << r.t->runs << " | "
    << fmt("%.2f", gflops(r.w, r.t->median)) << " | " << (r.vs_clfft.empty() ? "-" : r.vs_clfft) << " | "
    << (r.err ? fmt("%.2e", r.err->rel_l2) : "-") << " | " << (r.err ? fmt("%.2e", r.err->max_abs_rel) : "-")
    << " |\n";
  return o.str();
}

}  // namespace

int main(int argc, char** argv) {
  Options opt = parse(argc, argv);
  const auto t_start = Clock::now();

  std::vector<Workload> work;
  for (std::size_t m : opt.psf) {
    const std::size_t n = m * 2 / 3;  // M = 1.5 N (padding N/4 per side)
    work.push_back({"PSF N=" + std::to_string(n), opt.bands, m, m, {}});
    if (opt.zero_pad) work.push_back({"PSF N=" + std::to_string(n), opt.bands, m, m, {n / 2, m - n / 2, n / 2, m - n / 2}});
  }
  for (std::size_t p : opt.conv) work.push_back({"conv", opt.bands, p, p, {}});

  // One Runtime for everything (explicit backends per plan); plans stay cached, so peak device
  // memory is that of the largest buffer plus the plans' own scratch.
  std::optional<qdo::Runtime> rt;
  try {
    rt.emplace();
  } catch (const std::exception& e) {
    std::cerr << "bench_fft: no OpenCL device: " << e.what() << "\n";
    return 1;
  }
  const auto& i = rt->info();
  if (opt.backends.empty()) {
    opt.backends = {qdo::FftBackend::ClFFT, qdo::FftBackend::VkFFT};
    if (i.type == "CPU") opt.backends.push_back(qdo::FftBackend::FFTW);
  }
  cl_uint cmaj = 0, cmin = 0, cpatch = 0;
  clfftGetVersion(&cmaj, &cmin, &cpatch);
  const std::string machine =
      "CPU: " + cpu_model() + ", nproc " + std::to_string(std::thread::hardware_concurrency()) + "; OpenCL device: " +
      i.platform + " / " + i.name + " (" + i.type + ", driver " + i.driver_version + ", " + i.version + ", " +
      std::to_string(i.compute_units) + " compute units, fp64 " + (i.fp64 ? "yes" : "no") + "); clFFT " +
      std::to_string(cmaj) + "." + std::to_string(cmin) + "." + std::to_string(cpatch) + ", VkFFT " +
      qdo::vkfft_version() + ", " + qdo::fftw_library_version();
  std::cout << "bench_fft: batched 2-D complex FFT, forward + inverse in place\n"
            << machine << "\nrepeats " << opt.repeats << ", warmup " << opt.warmup << "\n\n"
            << std::flush;

  std::vector<Row> rows;
  std::cout << table_header();
  for (const Workload& w : work)
    for (qdo::Precision p : opt.precisions) {
      if (p == qdo::Precision::F64 && !rt->has_fp64()) continue;
      for (qdo::FftBackend b : opt.backends) {
        if (w.zero_pad.any() && b == qdo::FftBackend::ClFFT) continue;  // clFFT ignores the hint
        rows.push_back(run_one(*rt, w, p, b, opt));
        std::cout << table_row(rows.back()) << std::flush;
      }
    }
  // Time relative to the clFFT row of the same workload (without hint) and precision.
  for (Row& r : rows)
    for (const Row& c : rows)
      if (c.backend == "clfft" && c.t && r.t && c.w.name == r.w.name && c.w.batch == r.w.batch &&
          c.w.rows == r.w.rows && c.w.cols == r.w.cols && c.precision == r.precision)
        r.vs_clfft = fmt("%.2f", r.t->median / c.t->median);

  std::ostringstream md;
  md << "## Bare FFT: clFFT vs VkFFT (bench_fft)\n\n"
     << machine << "\n\n"
     << "Batched 2-D complex FFT, in place, forward + inverse + finish per run; median / min / max over " << opt.repeats
     << " runs after " << opt.warmup << " warm-up. Bake: plan creation (kernel generation and builds"
     << "; loads when PoCL's kernel cache is warm); first call: the first forward + inverse after the bake (PoCL"
     << " compiles work-group functions at first launch). GFlop/s: 5 n log2 n per transform of n points. Error: the forward transform of one seeded random input"
        " (float32 values) against FFTW in double.\n\n"
     << table_header();
  for (const Row& r : rows) md << table_row(r);
  md << "\nTotal wall time " << fmt("%.1f", seconds_since(t_start)) << " s.\n";
  std::cout << "\n" << md.str();
  if (!opt.out.empty()) {
    std::ofstream f(opt.out);
    f << md.str();
    if (!f) {
      std::cerr << "bench_fft: cannot write " << opt.out << "\n";
      return 1;
    }
    std::cout << "wrote " << opt.out << "\n";
  }
  return 0;
}
