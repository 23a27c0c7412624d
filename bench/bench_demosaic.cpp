// bench_demosaic: the demosaic stage (include/qdo/physics/demosaic.hpp) on the device, forward and
// transpose, bilinear and Malvar-He-Cutler, against its CPU reference (ref::demosaic, double, one
// thread) as the baseline, in the same run. Input: one seeded random RGGB raw plane of each size
// (1 x N x N reals), already on the device for the kernel times (the launch and a queue.finish();
// uploads and downloads are timed separately as the host form's overhead). Medians of --repeats
// runs after --warmup runs, with min and max beside each; speed is never asserted.
//
// Usage: bench_demosaic [--sizes 1024,2048] [--repeats 7] [--warmup 2] [--precision f32]
//                       [--ref-repeats 3] [--out FILE.md]
// Device: QDO_DEVICE (see runtime.hpp).
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "qdo/physics/demosaic.hpp"
#include "qdo/physics/demosaic_reference.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/runtime.hpp"

#include "bench_util.hpp"

namespace {

using qdo::bench::cpu_model;
using qdo::bench::fmt;
using qdo::split_items;
using qdo::bench::time_it;
using qdo::bench::Timing;

[[noreturn]] void usage(const std::string& err) {
  if (!err.empty()) std::cerr << "bench_demosaic: " << err << "\n";
  std::cerr << "usage: bench_demosaic [--sizes 1024,2048] [--repeats R=7] [--warmup W=2] [--precision f32|f64]\n"
               "                      [--ref-repeats R=3] [--out FILE.md]\n";
  std::exit(err.empty() ? 0 : 2);
}

std::string ms(const Timing& t) {
  return fmt("%.3f", 1e3 * t.median) + " ms (" + fmt("%.3f", 1e3 * t.min) + " .. " + fmt("%.3f", 1e3 * t.max) + ")";
}

}  // namespace

int main(int argc, char** argv) {
  std::vector<std::size_t> sizes{1024, 2048};
  int repeats = 7, warmup = 2, ref_repeats = 3;
  qdo::Precision prec = qdo::Precision::F32;
  std::string out;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) usage("missing value after " + a);
      return argv[++i];
    };
    try {
      if (a == "--sizes") {
        sizes.clear();
        for (const auto& s : split_items(value())) {
          const unsigned long n = std::stoul(s);
          if (n < 3 || n > 16384) usage("--sizes must lie in [3, 16384]");
          sizes.push_back(n);
        }
      } else if (a == "--repeats") {
        repeats = std::stoi(value());
        if (repeats < 1) usage("--repeats must be >= 1");
      } else if (a == "--warmup") {
        warmup = std::stoi(value());
        if (warmup < 0) usage("--warmup must be >= 0");
      } else if (a == "--ref-repeats") {
        ref_repeats = std::stoi(value());
        if (ref_repeats < 1) usage("--ref-repeats must be >= 1");
      } else if (a == "--precision") {
        prec = qdo::precision_from_string(value());
      } else if (a == "--out") {
        out = value();
      } else if (a == "--help" || a == "-h") {
        usage("");
      } else {
        usage("unknown argument " + a);
      }
    } catch (const std::logic_error&) {
      usage("bad value for " + a);
    } catch (const qdo::Error& e) {
      usage(e.what());
    }
  }
  qdo::Runtime rt;
  std::ostringstream md;
  md << "# bench_demosaic\n\ndevice: " << rt.info().name << " (" << rt.info().platform << "), CPU " << cpu_model()
     << ", precision " << qdo::to_string(prec) << "; medians of " << repeats << " runs after " << warmup
     << " warm-up (min .. max); CPU reference: medians of " << ref_repeats << " runs after 1 warm-up\n\n"
     << "| size | method | kernel forward | kernel transpose | host form forward (upload + kernel + download) | CPU reference forward | "
        "reference / kernel |\n|---|---|---|---|---|---|---|\n";
  for (std::size_t n : sizes) {
    qdo::RealStack raw(1, n, n);
    std::mt19937_64 rng(n);
    std::uniform_real_distribution<double> u(0, 1);
    for (double& v : raw.data) v = u(rng);
    std::vector<double> flat_g(3 * n * n);
    for (double& v : flat_g) v = u(rng);
    const std::size_t bytes = qdo::real_size(prec);
    std::vector<float> f32(raw.data.begin(), raw.data.end()), g32(flat_g.begin(), flat_g.end());
    const bool f64 = prec == qdo::Precision::F64;
    cl::Buffer d_raw(rt.context(), CL_MEM_READ_WRITE | CL_MEM_COPY_HOST_PTR, n * n * bytes,
                     f64 ? static_cast<void*>(raw.data.data()) : static_cast<void*>(f32.data()));
    cl::Buffer d_g(rt.context(), CL_MEM_READ_WRITE | CL_MEM_COPY_HOST_PTR, 3 * n * n * bytes,
                   f64 ? static_cast<void*>(flat_g.data()) : static_cast<void*>(g32.data()));
    cl::Buffer d_rgb(rt.context(), CL_MEM_READ_WRITE, 3 * n * n * bytes), d_graw(rt.context(), CL_MEM_READ_WRITE, n * n * bytes);
    for (qdo::DemosaicMethod m : {qdo::DemosaicMethod::Bilinear, qdo::DemosaicMethod::MHC}) {
      qdo::DemosaicStage stage(rt, qdo::Cfa::RGGB, m, prec);
      const Timing fwd = time_it(warmup, repeats, [&] {
        stage.run(d_raw, d_rgb, n, n, 1);
        rt.queue().finish();
      });
      const Timing adj = time_it(warmup, repeats, [&] {
        stage.adjoint(d_g, d_graw, n, n, 1);
        rt.queue().finish();
      });
      const Timing host = time_it(1, repeats, [&] { (void)stage.run(std::vector<qdo::RealStack>{raw}); });
      const Timing ref = time_it(1, ref_repeats, [&] { (void)qdo::ref::demosaic(raw, qdo::Cfa::RGGB, m); });
      md << "| " << n << " x " << n << " | " << qdo::to_string(m) << " | " << ms(fwd) << " | " << ms(adj) << " | " << ms(host)
         << " | " << ms(ref) << " | " << fmt("%.1f", ref.median / fwd.median) << " |\n";
      std::fprintf(stderr, "[bench_demosaic] %zu x %zu %s done\n", n, n, qdo::to_string(m).c_str());
    }
  }
  std::cout << md.str();
  if (!out.empty()) {
    std::ofstream f(out);
    f << md.str();
  }
  return 0;
}
