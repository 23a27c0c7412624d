// qdo image as a library call (simulate.hpp): one scene's sensor image with Camera's skipping
// rules and the report of what was skipped.
#include "qdo/asbuilt/simulate.hpp"

#include <chrono>

#include "qdo/data/io.hpp"
#include "qdo/design/option_inputs.hpp"
#include "qdo/physics/camera.hpp"
#include "qdo/runtime/strprintf.hpp"
#include "qdo/runtime/util.hpp"

namespace qdo {

ImagePlan plan_image(const TextOptions& a) {
  ImagePlan q;
  q.cfg = config_from_options(a);
  const SystemConfig& cfg = q.cfg;
  q.precision = precision_from_string(a.get("precision", "f32"));
  SkipOptions& opt = q.skip;
  opt = SkipOptions::split(parse_double("--tolerance", a.get("tolerance", "3e-7"), 0, 1, "(units of full scale)"),
                           tile_mode_from_string(a.get("tiles", "off")),
                           std::size_t(parse_int("--tile-px", a.get("tile-px", "64"), 8, 4096)));
  opt.exact = a.has("exact");
  opt.validate();
  q.psf = psf_input_from_options(cfg, a);
  q.scene = scene_from_options(cfg, a);
  return q;
}

std::string run_image(Runtime& rt, const ImagePlan& q, const std::string& dir) {
  const SystemConfig& cfg = q.cfg;
  const Precision p = q.precision;
  const RealStack& scene = q.scene;
  SpecPsfSource src = make_psf_source(rt, cfg, p, q.psf);
  src.compute();
  Camera im(src.source());
  const auto t0 = std::chrono::steady_clock::now();
  RealStack rgb = im.images({scene}, q.skip).front();
  const double secs = seconds_since(t0);
  const SkipReport& r = im.last_report();
  const SensorClip clip = clip_to_full_scale(rgb, "sensor image");
  write_rgb_png(dir + "/sensor.png", rgb);
  write_text_atomic(dir + "/skip.json", r.to_json() + "\n");
  return strprintf(
      "PSF: %s\nscene %zu x %zu x %zu -> sensor 3 x %zu x %zu in %.3f s (%s)\n"
      "skipped: %zu/%zu bands, PSF crop radius %zu of %zu px, %zu/%zu tiles; FFT grid %zu x %zu\n"
      "error bound %.3g (bands %.3g, crop %.3g, tiles %.3g; tolerance %.3g) in units of full scale\n"
      "%s\n"
      "wrote %s/sensor.png, skip.json\n",
      src.source().describe().c_str(), scene.planes, scene.rows, scene.cols, rgb.rows, rgb.cols, secs,
      to_string(p).c_str(), r.bands_skipped.size(), r.bands, r.crop_radius_px, r.sensor_psf_px / 2, r.tiles_skipped,
      r.tiles_total, r.grid_rows, r.grid_cols, r.total_bound, r.band_bound, r.crop_bound, r.tile_bound, r.tolerance,
      clip_summary(clip).c_str(), dir.c_str());
}

}  // namespace qdo
