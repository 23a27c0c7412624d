// bench_varying: depth-layered and spatially varying images (include/qdo/physics/varying.hpp) on
// the small preset (N = 256, 31 bands, S = 128) with the band-limited angular
// spectrum and a diffractive lens (lens_design at 550 nm).
//
// For each scene size in --sizes (default 256), in one run:
//   1. baseline: the shift-invariant Camera (on-axis PSF, SkipOptions::exact) on the same scene;
//   2. field, overlap-add: K = G x G field points (a regular grid of angles up to --field of the
//      largest supported angle at infinity, PSFs from one batched Simulator, recentred on the host),
//      bilinear hat weights, source placement; the reference image of the rows below;
//   3. field, low rank R = 1 .. K or --ranks (SVD of the recentred field PSFs, weights u_r = sum_k a_kr w_k):
//      time and the image error max|img - overlap-add| / max|overlap-add| beside the PSF truncation
//      error: which is faster at the same error;
//   4. depth: D = --layers on-axis points (distances 0.05 m .. infinity), a depth map of vertical
//      strips using the first n layers (n = 1 .. D), output placement (the release's rule) and source
//      placement: the cost against the number of layers actually used (the others are skipped).
// Medians of --repeats runs after --warmup (min-max in brackets), ms; each timed call includes the
// scene upload and the image read-back. Speed is never asserted; the table goes to stdout or --out.
//
// Usage: bench_varying [--sizes 256,512] [--grid 3] [--field 0.8] [--ranks 1,2,4] [--layers 4] [--repeats 5]
//                      [--warmup 1] [--precision f32] [--out FILE.md]
// Device: QDO_DEVICE (see runtime.hpp); kernel disk cache: QDO_CACHE_DIR.
#include <cmath>
#include <cstdio>
#include <exception>
#include <iostream>
#include <limits>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "qdo/physics/camera.hpp"
#include "qdo/data/config.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"
#include "qdo/physics/point_psf.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/runtime/types.hpp"
#include "qdo/physics/varying.hpp"

#include "bench_util.hpp"

namespace {

using qdo::bench::fmt;
using qdo::split_items;
using qdo::bench::time_it;
using qdo::bench::Timing;

struct Options {
  std::vector<std::size_t> sizes = {256};
  std::size_t grid = 3, layers = 4;
  std::vector<std::size_t> ranks;  // empty: 1 .. K
  double field = 0.8;
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
    if (a == "--sizes") {
      o.sizes.clear();
      for (const auto& s : split_items(value())) o.sizes.push_back(std::size_t(std::stoul(s)));
    } else if (a == "--grid") o.grid = std::size_t(std::stoul(value()));
    else if (a == "--ranks") {
      for (const auto& s : split_items(value())) o.ranks.push_back(std::size_t(std::stoul(s)));
    } else if (a == "--layers") o.layers = std::size_t(std::stoul(value()));
    else if (a == "--field") o.field = std::stod(value());
    else if (a == "--repeats") o.repeats = std::stoi(value());
    else if (a == "--warmup") o.warmup = std::stoi(value());
    else if (a == "--precision") o.precision = qdo::precision_from_string(value());
    else if (a == "--out") o.out = value();
    else qdo::reject("argument", a, "--sizes, --grid, --field, --ranks, --layers, --repeats, --warmup, --precision or --out");
  }
  if (o.repeats < 1) qdo::reject("--repeats", o.repeats, ">= 1");
  if (o.grid < 1 || o.grid > 7) qdo::reject("--grid", o.grid, "1 .. 7 (field points per axis)");
  if (o.layers < 1 || o.layers > 8) qdo::reject("--layers", o.layers, "1 .. 8");
  if (!(o.field > 0 && o.field <= 1)) qdo::reject("--field", o.field, "(0, 1]: a fraction of the largest supported angle");
  return o;
}

std::string ms(const Timing& t) { return fmt("%.1f", t.median * 1e3) + " (" + fmt("%.1f", t.min * 1e3) + "-" + fmt("%.1f", t.max * 1e3) + ")"; }

qdo::RealStack random_scene(std::size_t b, std::size_t n, unsigned seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  qdo::RealStack c(b, n, n);
  for (auto& v : c.data) v = u(rng);
  return c;
}

double rel_err(const qdo::RealStack& a, const qdo::RealStack& ref) {
  double e = 0, m = 0;
  for (std::size_t i = 0; i < a.size(); ++i) {
    e = std::max(e, std::fabs(a.data[i] - ref.data[i]));
    m = std::max(m, std::fabs(ref.data[i]));
  }
  return m > 0 ? e / m : e;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    const Options opt = parse(argc, argv);
    const double inf = std::numeric_limits<double>::infinity();
    qdo::Runtime rt;
    std::ostringstream md;
    md << "Device: " << rt.info().name << " (" << qdo::bench::cpu_model() << "), precision " << qdo::to_string(opt.precision)
       << ", FFT backend " << qdo::to_string(rt.fft_backend()) << "; medians of " << opt.repeats << " runs after " << opt.warmup
       << " warm-up (min-max in brackets), ms.\n\n";
    qdo::SystemConfig base = qdo::preset_config("small");
    base.propagator = qdo::Propagator::AngularSpectrum;
    base.read_noise_sigma = 0;
    base.full_well_photons = 0;
    base.validate();
    const qdo::Map2D heights = qdo::lens_design(base, 550);
    const std::size_t nb = base.bands;

    // Field PSFs: a G x G grid of angles at infinity, one batched Simulator, recentred on the host.
    const double amax = qdo::max_field_angle_deg(base, inf), a = opt.field * amax;
    std::vector<double> angles;
    for (std::size_t i = 0; i < opt.grid; ++i)
      angles.push_back(opt.grid == 1 ? 0.0 : -a + 2 * a * double(i) / double(opt.grid - 1));
    const qdo::FieldGrid fg = qdo::field_grid(base, inf, angles, angles);
    const std::size_t kk = fg.points.size();
    qdo::SystemConfig fcfg = base;
    fcfg.object_points = fg.points;
    fcfg.validate();
    std::cerr << "field PSFs: " << kk << " points x " << nb << " bands...\n";
    qdo::RealStack field_psfs;
    {
      qdo::Simulator sim(rt, fcfg, opt.precision);
      sim.set_heights(heights);
      sim.compute_psf();
      const qdo::RealStack stack = sim.psf_sensor();
      field_psfs = qdo::RealStack(stack.planes, stack.rows, stack.cols);
      for (std::size_t k = 0; k < kk; ++k) {
        const qdo::RealStack r = qdo::recentre_on_chief_ray(qdo::point_planes(stack, k, nb), fcfg, fg.points[k]);
        std::copy(r.data.begin(), r.data.end(), field_psfs.plane(k * nb));
      }
    }
    // Depth PSFs: D on-axis points.
    const double dists[8] = {0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0, inf};
    std::vector<double> layers;
    for (std::size_t i = 0; i < opt.layers; ++i) layers.push_back(opt.layers == 1 ? inf : dists[(i * 7) / (opt.layers - 1)]);
    qdo::SystemConfig dcfg = base;
    for (double d : layers) dcfg.object_points.push_back(qdo::ObjectPoint{d, 0, 0});
    dcfg.validate();
    std::cerr << "depth PSFs: " << layers.size() << " layers x " << nb << " bands...\n";
    qdo::Simulator dsim(rt, dcfg, opt.precision);
    dsim.set_heights(heights);
    dsim.compute_psf();
    const qdo::RealStack depth_psfs = dsim.psf_sensor();

    std::vector<qdo::LowRankPsf> ranks;
    std::vector<std::size_t> rank_list = opt.ranks;
    if (rank_list.empty())
      for (std::size_t r = 1; r <= kk; ++r) rank_list.push_back(r);
    for (std::size_t r : rank_list) {
      if (r < 1 || r > kk) qdo::reject("--ranks", r, "1 .. K = " + std::to_string(kk) + " (the field points)");
      ranks.push_back(qdo::low_rank_psf(field_psfs, nb, r));
    }

    md << "Small preset (N = 256, " << nb << " bands, S = " << base.sensor_size_px() << "), asm, lens at 550 nm; field grid " << opt.grid
       << " x " << opt.grid << " up to " << fmt("%.2f", a) << " deg (" << fmt("%.0f", 100 * opt.field)
       << " % of the supported " << fmt("%.2f", amax) << " deg) at infinity; depth layers";
    for (double d : layers) md << " " << (std::isinf(d) ? std::string("inf") : fmt("%g", d));
    md << " m.\n\n";
    md << "| scene | operator | components kept | forward / inverse FFTs | time | error vs overlap-add | PSF truncation |\n"
          "|---|---|---|---|---|---|---|\n";
    for (std::size_t n : opt.sizes) {
      std::cerr << "scene " << n << " x " << n << "...\n";
      const qdo::RealStack scene = random_scene(nb, n, 7);
      const std::string sz = std::to_string(n) + " x " + std::to_string(n);
      // 1. Baseline: the shift-invariant camera with the on-axis field PSF.
      {
        qdo::Camera cam(rt, base, opt.precision);
        cam.set_psf(qdo::point_planes(field_psfs, kk / 2, nb));
        qdo::SkipOptions exact;
        exact.exact = true;
        const std::vector<qdo::RealStack> batch{scene};  // built once, outside the timed call
        const Timing t = time_it(opt.warmup, opt.repeats, [&] { (void)cam.images(batch, exact); });
        const auto& r = cam.last_report();
        md << "| " << sz << " | Camera (shift-invariant, baseline) | 1 | " << r.forward_ffts << " / " << r.inverse_ffts << " | " << ms(t)
           << " | - | - |\n";
      }
      // 2. Field, overlap-add.
      const qdo::RealStack wts = qdo::field_grid_weights(n, n, fg.rows_px, fg.cols_px);
      qdo::RealStack ola;
      {
        qdo::VaryingCamera v(rt, base, opt.precision, kk);
        v.set_psfs(field_psfs);
        ola = v.images(scene, wts, qdo::PsfPlacement::Source);
        const Timing t = time_it(opt.warmup, opt.repeats, [&] { (void)v.images(scene, wts, qdo::PsfPlacement::Source); });
        const auto& r = v.last_report();
        md << "| " << sz << " | field overlap-add, K = " << kk << ", source | " << r.kept.size() << " | " << r.forward_ffts << " / "
           << r.inverse_ffts << " | " << ms(t) << " | 0 (reference) | 0 |\n";
        std::cerr << "  overlap-add " << fmt("%.1f ms", t.median * 1e3) << "\n";
      }
      // 3. Field, low rank.
      for (const auto& lr : ranks) {
        const std::size_t rr = std::size_t(lr.coeff.cols());
        qdo::VaryingCamera v(rt, base, opt.precision, rr);
        v.set_psfs(lr.psfs);
        const qdo::RealStack u = qdo::combine_weights(wts, lr.coeff);
        const qdo::RealStack img = v.images(scene, u, qdo::PsfPlacement::Source);
        const Timing t = time_it(opt.warmup, opt.repeats, [&] { (void)v.images(scene, u, qdo::PsfPlacement::Source); });
        const auto& r = v.last_report();
        md << "| " << sz << " | field low rank R = " << rr << ", source | " << r.kept.size() << " | " << r.forward_ffts << " / "
           << r.inverse_ffts << " | " << ms(t) << " | " << fmt("%.2e", rel_err(img, ola)) << " | " << fmt("%.2e", lr.truncation_error)
           << " |\n";
        std::cerr << "  rank " << rr << " " << fmt("%.1f ms", t.median * 1e3) << "\n";
      }
      // 4. Depth: a map of vertical strips using the first `used` layers.
      qdo::VaryingCamera dv(dsim);
      for (std::size_t used = 1; used <= layers.size(); ++used) {
        qdo::Map2D depth(n, n);
        for (std::size_t y = 0; y < n; ++y)
          for (std::size_t x = 0; x < n; ++x) depth(y, x) = layers[std::min(used - 1, x * used / n)];
        const qdo::RealStack dw = qdo::depth_layer_weights(depth, layers, n, n);
        for (qdo::PsfPlacement pl : {qdo::PsfPlacement::Output, qdo::PsfPlacement::Source}) {
          const Timing t = time_it(opt.warmup, opt.repeats, [&] { (void)dv.images(scene, dw, pl); });
          const auto& r = dv.last_report();
          md << "| " << sz << " | depth, " << used << " of " << layers.size() << " layers used, " << qdo::to_string(pl) << " | "
             << r.kept.size() << " | " << r.forward_ffts << " / " << r.inverse_ffts << " | " << ms(t) << " | - | - |\n";
        }
        std::cerr << "  depth " << used << " layers done\n";
      }
    }
    if (opt.out.empty()) {
      std::cout << md.str();
    } else {
      qdo::write_text_atomic(opt.out, md.str());
    }
    return 0;
  } catch (const qdo::InputError& e) {
    std::cerr << "bench_varying: " << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "bench_varying: " << e.what() << "\n";
    return 1;
  }
}
