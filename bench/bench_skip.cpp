// bench_skip: sensor images with skipping rules (Camera, include/qdo/physics/camera.hpp) against the
// unskipped Simulator::sensor_images, on the CAVE scenes with the paper physics.
//
// For each design (lens_design at 550 nm; with --radial also a random radial design) it
//   1. computes the unskipped float64 images of the scene batch (the truth) and the unskipped
//      float32 images, whose difference is the float32 rounding noise of the unskipped path;
//   2. times (median of --repeats after --warmup runs) the unskipped float32 path and the imager
//      with each rule alone and all together at the default tolerances and at --loose;
//   3. reports beside each time the measured max / mean |error| against the float64 truth and the
//      bound the imager reported, plus what it skipped;
//   4. repeats the default rows on sparse versions of the scenes (zero outside the central square
//      of a quarter of the side), where empty tiles exist.
// Speed is never asserted; this program only reports.
//
// Usage: bench_skip [--data DIR] [--preset paper|small] [--repeats 3] [--warmup 1]
//                   [--loose 1e-4] [--radial] [--quick] [--out FILE.md]
//   --data    folder of CAVE .mat scenes, or a dataset name under the data root (default cave;
//             qdo data says where that is)
//   --quick   small preset (N = 256, S = 128), scenes centre-cropped to 128 x 128, 1 repeat
// Device: QDO_DEVICE (see runtime.hpp); kernel disk cache: QDO_CACHE_DIR.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "qdo/data/data_root.hpp"
#include "qdo/data/config.hpp"
#include "qdo/data/datasets.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/physics/camera.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/runtime/types.hpp"

#include "bench_util.hpp"

namespace fs = std::filesystem;
using namespace qdo;

namespace {

using qdo::bench::fmt;
using qdo::bench::median_seconds;

struct Options {
  std::string data = "cave", preset = "paper", out;
  int repeats = 3, warmup = 1;
  double loose = 1e-4;
  bool radial = false, quick = false;
};

Options parse(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto next = [&]() -> std::string {
      if (i + 1 >= argc) reject(a, "(missing)", "a value");
      return argv[++i];
    };
    if (a == "--data") o.data = next();
    else if (a == "--preset") o.preset = next();
    else if (a == "--out") o.out = next();
    else if (a == "--repeats") o.repeats = std::stoi(next());
    else if (a == "--warmup") o.warmup = std::stoi(next());
    else if (a == "--loose") o.loose = std::stod(next());
    else if (a == "--radial") o.radial = true;
    else if (a == "--quick") o.quick = true;
    else if (a == "--help" || a == "-h") {
      std::cout << "bench_skip [--data DIR] [--preset paper|small] [--repeats 3] [--warmup 1] [--loose 1e-4] [--radial]"
                   " [--quick] [--out FILE.md]\n";
      std::exit(0);
    } else {
      reject("option", a, "--data, --preset, --repeats, --warmup, --loose, --radial, --quick, --out");
    }
  }
  if (o.quick) {
    o.preset = "small";
    o.repeats = 1;
  }
  if (o.repeats < 1) reject("--repeats", o.repeats, ">= 1");
  if (o.warmup < 0) reject("--warmup", o.warmup, ">= 0");
  if (!std::isfinite(o.loose) || o.loose < 0) reject("--loose", o.loose, "a finite tolerance >= 0");
  return o;
}

struct Err {
  double max = 0, mean = 0;
};
Err error(const std::vector<RealStack>& a, const std::vector<RealStack>& truth) {
  Err e;
  double sum = 0;
  std::size_t n = 0;
  for (std::size_t k = 0; k < a.size(); ++k)
    for (std::size_t i = 0; i < a[k].size(); ++i) {
      const double d = std::fabs(a[k].data[i] - truth[k].data[i]);
      e.max = std::max(e.max, d);
      sum += d;
      ++n;
    }
  e.mean = n ? sum / double(n) : 0;
  return e;
}

}  // namespace

int main(int argc, char** argv) try {
  Options o = parse(argc, argv);
  std::vector<std::string> files;
  o.data = resolve_dataset(o.data, "--data");
  if (!fs::is_directory(o.data)) reject("--data", o.data, "a folder of CAVE .mat scenes");
  for (const auto& e : fs::directory_iterator(o.data))
    if (e.path().extension() == ".mat") files.push_back(e.path().string());
  std::sort(files.begin(), files.end());
  if (files.empty()) reject("--data", o.data, "a folder holding CAVE .mat scenes");

  SystemConfig cfg = preset_config(o.preset);
  cfg.read_noise_sigma = 0;  // noise-free: errors are measured against the unskipped float64 images
  cfg.full_well_photons = 0;
  std::vector<RealStack> scenes;
  for (const auto& f : files) {
    RealStack s = load_scene(f, "auto", cfg.bands);
    if (o.quick) {
      const std::size_t sz = std::min<std::size_t>(128, std::min(s.rows, s.cols));
      s = crop_patch(s, PatchOrigin{(s.rows - sz) / 2, (s.cols - sz) / 2}, sz);
    }
    scenes.push_back(std::move(s));
  }
  const std::size_t h = scenes[0].rows, w = scenes[0].cols;
  for (const auto& s : scenes)
    if (s.rows != h || s.cols != w) reject("--data", o.data, "scenes of one shape (one batch)");

  Runtime rt;
  std::ostringstream md;
  md << "## bench_skip: " << scenes.size() << " CAVE scenes " << h << " x " << w << " x " << cfg.bands << ", preset "
     << o.preset << " (N = " << cfg.n << ", S = " << cfg.sensor_size_px() << "), noise off\n\n"
     << "Device: " << rt.info().platform << " / " << rt.info().name << ". Times: median of " << o.repeats << " after "
     << o.warmup << " warm-up, whole batch in one call (upload, compute, read-back). Errors: |image - unskipped "
        "float64 image| over all pixels and channels, full scale 1.0. Bound: what the imager reports (skipping only; "
        "float32 rounding comes on top).\n\n";

  struct Design {
    std::string name;
    Map2D heights;
  };
  std::vector<Design> designs{{"lens 550 nm", lens_design(cfg, 550)}};
  if (o.radial) {
    std::mt19937_64 rng(7);
    std::uniform_real_distribution<double> u(0.0, cfg.h_max_m());
    std::vector<double> p(parameter_count(Parameterization::Radial, cfg.n));
    for (auto& v : p) v = u(rng);
    designs.push_back({"random radial", expand_parameters(Parameterization::Radial, p, cfg.n, cfg.h_max_m())});
  }

  const SkipOptions defaults;
  for (const auto& d : designs) {
    std::fprintf(stderr, "[bench_skip] %s: PSFs (f64, f32)...\n", d.name.c_str());
    Simulator sim64(rt, cfg, Precision::F64), sim32(rt, cfg, Precision::F32);
    sim64.set_heights(d.heights);
    sim64.compute_psf();
    sim32.set_heights(d.heights);
    sim32.compute_psf();
    Camera cam64(sim64), cam32(sim32);  // the unskipped camera of each (OTFs reused across calls)
    SkipOptions exact;
    exact.exact = true;
    std::fprintf(stderr, "[bench_skip] unskipped float64 truth...\n");
    const auto truth = cam64.images(scenes, exact);
    std::vector<RealStack> img32;
    const double t_un32 = median_seconds(o.warmup, o.repeats, [&] { img32 = cam32.images(scenes, exact); });
    const Err noise32 = error(img32, truth);
    std::vector<RealStack> img64;
    const double t_un64 = median_seconds(0, 1, [&] { img64 = cam64.images(scenes, exact); });

    md << "### " << d.name << "\n\n"
       << "float32 rounding noise of the unskipped path (float32 vs float64 unskipped): max "
       << fmt("%.3g", noise32.max) << ", mean " << fmt("%.3g", noise32.mean) << ".\n\n"
       << "| variant | prec | time [s] | speed-up | max err | mean err | bound | bands skipped | crop r / S/2 | grid | "
          "tiles skipped |\n|---|---|---|---|---|---|---|---|---|---|---|\n";
    auto row = [&](const std::string& name, const std::string& prec, double t, double base, const Err& e,
                   const SkipReport* r) {
      md << "| " << name << " | " << prec << " | " << fmt("%.3f", t) << " | " << fmt("%.2f", base / t) << "x | "
         << fmt("%.3g", e.max) << " | " << fmt("%.3g", e.mean) << " | ";
      if (r) {
        md << fmt("%.3g", r->total_bound) << " | " << r->bands_skipped.size() << "/" << r->bands << " | "
           << r->crop_radius_px << "/" << r->sensor_psf_px / 2 << " | " << r->grid_rows << "x" << r->grid_cols << " | "
           << (r->tiled ? std::to_string(r->tiles_skipped) + "/" + std::to_string(r->tiles_total) : std::string("untiled"))
           << " |\n";
      } else {
        const std::size_t py = fast_fft_size(h + cfg.sensor_size_px() - 1), px = fast_fft_size(w + cfg.sensor_size_px() - 1);
        md << "- | - | - | " << py << "x" << px << " | - |\n";
      }
      std::fprintf(stderr, "[bench_skip]   %-28s %s %8.3f s  max err %.3g\n", name.c_str(), prec.c_str(), t, e.max);
    };
    row("unskipped sensor_images", "f32", t_un32, t_un32, noise32, nullptr);
    row("unskipped sensor_images", "f64", t_un64, t_un32, error(img64, truth), nullptr);

    struct Variant {
      std::string name;
      SkipOptions opt;
    };
    auto only = [](double band, double crop, double tile, TileMode tm) {
      SkipOptions s;
      s.band_tolerance = band;
      s.crop_tolerance = crop;
      s.tile_tolerance = tile;
      s.tiles = tm;
      return s;
    };
    const double b = defaults.band_tolerance, c = defaults.crop_tolerance, t = defaults.tile_tolerance;
    const std::vector<Variant> variants{
        {"exact (rules off)", exact},
        {"bands only (default)", only(b, 0, 0, TileMode::Off)},
        {"crop only (default)", only(0, c, 0, TileMode::Off)},
        {"tiles only (default, 64 px)", only(0, 0, t, TileMode::On)},
        {"all (default)", defaults},
        {"bands only (loose)", only(o.loose / 3, 0, 0, TileMode::Off)},
        {"crop only (loose)", only(0, o.loose / 3, 0, TileMode::Off)},
        {"tiles only (loose, 64 px)", only(0, 0, o.loose / 3, TileMode::On)},
        {"all (loose " + fmt("%.0e", o.loose) + ")", SkipOptions::split(o.loose)},
        {"all (loose, tiles auto)", SkipOptions::split(o.loose, TileMode::Auto)},
        {"crop only (1e-3)", only(0, 1e-3, 0, TileMode::Off)},
        {"crop only (1e-2)", only(0, 1e-2, 0, TileMode::Off)},
    };
    Camera im32(sim32);
    for (const auto& v : variants) {
      std::vector<RealStack> out;
      const double tt = median_seconds(o.warmup, o.repeats, [&] { out = im32.images(scenes, v.opt); });
      row(v.name, "f32", tt, t_un32, error(out, truth), &im32.last_report());
    }
    Camera im64(sim64);
    for (const auto& v : {variants[0], variants[4], variants[8]}) {
      std::vector<RealStack> out;
      const double tt = median_seconds(0, 1, [&] { out = im64.images(scenes, v.opt); });
      row(v.name, "f64", tt, t_un32, error(out, truth), &im64.last_report());
    }
    // Sparse scenes (where tiling can pay): each scene zeroed outside its central quarter-size
    // square (side/4), so most tiles are empty.
    std::vector<RealStack> sparse = scenes;
    for (auto& s : sparse)
      for (std::size_t band = 0; band < s.planes; ++band)
        for (std::size_t y = 0; y < s.rows; ++y)
          for (std::size_t x = 0; x < s.cols; ++x)
            if (y < 3 * s.rows / 8 || y >= 5 * s.rows / 8 || x < 3 * s.cols / 8 || x >= 5 * s.cols / 8) s(band, y, x) = 0;
    const auto sparse_truth = cam64.images(sparse, exact);
    std::vector<RealStack> sp32;
    const double t_sp = median_seconds(o.warmup, o.repeats, [&] { sp32 = cam32.images(sparse, exact); });
    row("sparse: unskipped", "f32", t_sp, t_sp, error(sp32, sparse_truth), nullptr);
    for (const auto& v : {variants[4], variants[3], Variant{"sparse: all (default, tiles auto)", [&] {
                                                              SkipOptions s = defaults;
                                                              s.tiles = TileMode::Auto;
                                                              return s;
                                                            }()}}) {
      std::vector<RealStack> out;
      const double tt = median_seconds(o.warmup, o.repeats, [&] { out = im32.images(sparse, v.opt); });
      row(v.name.rfind("sparse", 0) == 0 ? v.name : "sparse: " + v.name, "f32", tt, t_sp, error(out, sparse_truth),
          &im32.last_report());
    }
    md << "\n";
  }
  std::cout << md.str();
  if (!o.out.empty()) {
    std::ofstream f(o.out);
    if (!f) reject("--out", o.out, "a writable file path");
    f << md.str();
  }
  return 0;
} catch (const qdo::InputError& e) {
  std::cerr << "bench_skip: " << e.what() << "\n";
  return 2;
} catch (const std::exception& e) {
  std::cerr << "bench_skip: " << e.what() << "\n";
  return 1;
}
