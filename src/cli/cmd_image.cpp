// qdo image: the RGB sensor image of one scene through a design, with the skipping rules of
// Camera (include/qdo/camera.hpp) and a JSON report of what was skipped and the bound.
#include <cstdio>
#include <fstream>

#include "cli.hpp"
#include "qdo/error.hpp"
#include "qdo/camera.hpp"
#include "qdo/io.hpp"
#include "qdo/scenes.hpp"
#include "qdo/simulator.hpp"

using namespace qdo;
using namespace qdo::cli;

namespace qdo::cli {

int cmd_image(const Args& a) {
  const SystemConfig cfg = load_config(a);
  const Precision p = precision_from_string(a.get("precision"));
  SkipOptions opt = SkipOptions::split(parse_double("--tolerance", a.get("tolerance")),
                                       tile_mode_from_string(a.get("tiles")),
                                       std::size_t(parse_int("--tile-px", a.get("tile-px"), 8, 4096)));
  opt.exact = a.has("exact");
  opt.validate();
  if (!a.has("design")) reject("--design", "(missing)", "lens:NM, flat, or a design .h5 file");
  const Map2D h = design_heights(cfg, a);
  const RealStack scene = scene_from_args(cfg, a);
  const std::string dir = out_dir(a);
  Runtime rt(a.get("device"));
  Simulator sim(rt, cfg, p);
  sim.set_heights(h);
  sim.compute_psf();
  Camera im(sim);
  const auto t0 = std::chrono::steady_clock::now();
  RealStack rgb = im.images({scene}, opt).front();
  const double secs = seconds_since(t0);
  const SkipReport& r = im.last_report();
  const SensorClip clip = clip_to_full_scale(rgb, "sensor image");
  write_rgb_png(dir + "/sensor.png", rgb);
  write_text_atomic(dir + "/skip.json", r.to_json() + "\n");
  std::printf("scene %zu x %zu x %zu -> sensor 3 x %zu x %zu in %.3f s (%s)\n"
              "skipped: %zu/%zu bands, PSF crop radius %zu of %zu px, %zu/%zu tiles; FFT grid %zu x %zu\n"
              "error bound %.3g (bands %.3g, crop %.3g, tiles %.3g; tolerance %.3g) in units of full scale\n"
              "%s\n"
              "wrote %s/sensor.png, skip.json\n",
              scene.planes, scene.rows, scene.cols, rgb.rows, rgb.cols, secs, to_string(p).c_str(), r.bands_skipped.size(),
              r.bands, r.crop_radius_px, r.sensor_psf_px / 2, r.tiles_skipped, r.tiles_total, r.grid_rows, r.grid_cols,
              r.total_bound, r.band_bound, r.crop_bound, r.tile_bound, r.tolerance, clip_summary(clip).c_str(), dir.c_str());
  return 0;
}

}  // namespace qdo::cli
