// bench_objpts: the PSF stack's time against the number of object points.
//
// For each preset (small, paper; the band-limited angular spectrum, so off-axis points are exact)
// and each point count P in --points (default 1,4,9,16: a grid of distances x field angles within
// the sampling limits, the first point on axis), it measures in one run:
//   1. Simulator::compute_psf() + queue.finish() of the batched stack (P x bands planes, one pass),
//      median / min / max of --repeats runs after --warmup;
//   2. compute_psf() + psf_sensor_vjp() (forward and adjoint to dL/dH, summed over the points);
//   3. the FFT floor of the same transforms: the runtime's plan of P x bands planes of M x M with
//      the field's zero-padding hint, one forward + one inverse on a device buffer (baseline);
//   4. P separate one-point simulators run back to back (what the batch replaces; P > 1 only).
// Speed is never asserted; this program only reports a markdown table (stdout, or --out FILE).
//
// Usage: bench_objpts [--presets small,paper] [--points 1,4,9,16] [--repeats 5] [--warmup 1]
//                     [--precision f32] [--out FILE.md]
// Device: QDO_DEVICE (see runtime.hpp); kernel disk cache: QDO_CACHE_DIR.
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <iostream>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"
#include "qdo/runtime/fft.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/runtime/types.hpp"

#include "bench_util.hpp"

namespace {

using qdo::bench::fmt;
using qdo::split_items;
using qdo::bench::time_it;
using qdo::bench::Timing;

struct Options {
  std::vector<std::string> presets = {"small", "paper"};
  std::vector<std::size_t> points = {1, 4, 9, 16};
  int repeats = 5, warmup = 1;
  qdo::Precision precision = qdo::Precision::F32;
  std::string out;
};

Options parse(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    const auto value = [&]() -> std::string {
      if (i + 1 >= argc) qdo::reject(a, "(missing)", "a value");
      return argv[++i];
    };
    if (a == "--presets") o.presets = split_items(value());
    else if (a == "--points") {
      o.points.clear();
      for (const auto& s : split_items(value())) o.points.push_back(std::size_t(std::stoul(s)));
    } else if (a == "--repeats") o.repeats = std::stoi(value());
    else if (a == "--warmup") o.warmup = std::stoi(value());
    else if (a == "--precision") o.precision = qdo::precision_from_string(value());
    else if (a == "--out") o.out = value();
    else qdo::reject("argument", a, "--presets, --points, --repeats, --warmup, --precision or --out");
  }
  if (o.repeats < 1) qdo::reject("--repeats", o.repeats, ">= 1");
  return o;
}

// P object points: distances {1, 2, 4, inf} m crossed with field angles on a ring inside the
// supported field (half the largest angle), the first point on axis.
std::vector<qdo::ObjectPoint> points_for(const qdo::SystemConfig& c, std::size_t count) {
  const double a = 0.5 * qdo::max_field_angle_deg(c, 1.0);
  const double ds[4] = {1.0, 2.0, 4.0, INFINITY};
  std::vector<qdo::ObjectPoint> v;
  for (std::size_t k = 0; k < count; ++k) {
    const double phi = 2.0 * M_PI * double(k) / double(count);
    const double r = k == 0 ? 0.0 : a;
    v.push_back(qdo::ObjectPoint{ds[k % 4], r * std::cos(phi), r * std::sin(phi)});
  }
  return v;
}

std::string ms(const Timing& t) { return fmt("%.1f", t.median * 1e3) + " (" + fmt("%.1f", t.min * 1e3) + "-" + fmt("%.1f", t.max * 1e3) + ")"; }

}  // namespace

int main(int argc, char** argv) {
  try {
    const Options opt = parse(argc, argv);
    qdo::Runtime rt;
    std::ostringstream md;
    md << "Device: " << rt.info().name << " (" << qdo::bench::cpu_model() << "), precision " << qdo::to_string(opt.precision)
       << ", FFT backend " << qdo::to_string(rt.fft_backend()) << "; medians of " << opt.repeats << " runs after " << opt.warmup
       << " warm-up (min-max in brackets), ms.\n\n";
    md << "| preset | points | planes | FFT floor (fwd+inv) | compute_psf | / FFT floor | per point | compute_psf + vjp | "
          "P one-point simulators |\n|---|---|---|---|---|---|---|---|---|\n";
    for (const std::string& preset : opt.presets) {
      qdo::SystemConfig base = qdo::preset_config(preset);
      base.propagator = qdo::Propagator::AngularSpectrum;
      const qdo::Map2D h = qdo::lens_design(base, 550);
      for (std::size_t np : opt.points) {
        qdo::SystemConfig c = base;
        c.object_points = points_for(base, np);
        c.validate();
        const std::size_t planes = np * c.bands, m = qdo::PropagationGeometry::from_config(c).m, n = c.n;
        std::cerr << preset << ": " << np << " points (" << planes << " planes)...\n";
        qdo::Simulator sim(rt, c, opt.precision);
        sim.set_heights(h);
        const Timing fwd = time_it(opt.warmup, opt.repeats, [&] {
          sim.compute_psf();
          rt.queue().finish();
        });
        const qdo::RealStack g(planes, sim.sensor_size(), sim.sensor_size(), 1e-3);
        const Timing both = time_it(opt.warmup, opt.repeats, [&] {
          sim.compute_psf();
          (void)sim.psf_sensor_vjp(g);
        });
        // The FFT floor: the same transforms on a device buffer, nothing else.
        qdo::FftPlan& fft = rt.fft(m, m, planes, opt.precision, rt.fft_backend(), qdo::FftZeroPad{n, m, n, m});
        const std::size_t bytes = planes * m * m * 2 * qdo::real_size(opt.precision);
        cl::Buffer buf(rt.context(), CL_MEM_READ_WRITE, bytes);
        if (opt.precision == qdo::Precision::F64)
          rt.queue().enqueueFillBuffer(buf, 0.0, 0, bytes);
        else
          rt.queue().enqueueFillBuffer(buf, 0.0f, 0, bytes);
        rt.queue().finish();
        const Timing floor = time_it(opt.warmup, opt.repeats, [&] {
          fft.forward(buf);
          fft.inverse(buf);
          rt.queue().finish();
        });
        std::string separate = "-";
        if (np > 1) {
          std::vector<std::unique_ptr<qdo::Simulator>> sims;
          for (std::size_t q = 0; q < np; ++q) {
            sims.push_back(std::make_unique<qdo::Simulator>(rt, qdo::point_config(c, q), opt.precision));
            sims.back()->set_heights(h);
          }
          separate = ms(time_it(opt.warmup, opt.repeats, [&] {
            for (auto& s : sims) s->compute_psf();
            rt.queue().finish();
          }));
        }
        md << "| " << preset << " (N = " << n << ", M = " << m << ") | " << np << " | " << planes << " | " << ms(floor) << " | "
           << ms(fwd) << " | " << fmt("%.2f", fwd.median / floor.median) << " | " << fmt("%.1f", fwd.median * 1e3 / double(np))
           << " | " << ms(both) << " | " << separate << " |\n";
        std::cerr << "  compute_psf " << fmt("%.1f ms", fwd.median * 1e3) << ", FFT floor " << fmt("%.1f ms", floor.median * 1e3)
                  << "\n";
      }
    }
    if (opt.out.empty()) {
      std::cout << md.str();
    } else {
      qdo::write_text_atomic(opt.out, md.str());
    }
    return 0;
  } catch (const qdo::InputError& e) {
    std::cerr << "bench_objpts: " << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "bench_objpts: " << e.what() << "\n";
    return 1;
  }
}
