// qdo image: the RGB sensor image of one scene with the skipping rules of Camera
// (include/qdo/physics/camera.hpp) and a JSON report of what was skipped and the bound.
#include <chrono>
#include <cstdio>
#include <string>

#include "cli.hpp"
#include "options.hpp"
#include "qdo/data/io.hpp"
#include "qdo/design/psf_spec.hpp"
#include "qdo/physics/camera.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/runtime.hpp"

namespace qdo::cli {

static int cmd_image(const Args& a) {
  const SystemConfig cfg = load_config(a);
  const Precision p = precision_from_string(a.get("precision"));
  SkipOptions opt = SkipOptions::split(parse_double("--tolerance", a.get("tolerance"), 0, 1, "(units of full scale)"),
                                       tile_mode_from_string(a.get("tiles")),
                                       std::size_t(parse_int("--tile-px", a.get("tile-px"), 8, 4096)));
  opt.exact = a.has("exact");
  opt.validate();
  const PsfInput in = psf_input(cfg, a);
  const RealStack scene = scene_from_args(cfg, a);
  const std::string dir = out_dir(a);
  Runtime rt(a.get("device"));
  SpecPsfSource src = make_psf_source(rt, cfg, p, in);
  src.compute();
  Camera im(src.source());
  const auto t0 = std::chrono::steady_clock::now();
  RealStack rgb = im.images({scene}, opt).front();
  const double secs = seconds_since(t0);
  const SkipReport& r = im.last_report();
  const SensorClip clip = clip_to_full_scale(rgb, "sensor image");
  write_rgb_png(dir + "/sensor.png", rgb);
  write_text_atomic(dir + "/skip.json", r.to_json() + "\n");
  std::printf("PSF: %s\nscene %zu x %zu x %zu -> sensor 3 x %zu x %zu in %.3f s (%s)\n"
              "skipped: %zu/%zu bands, PSF crop radius %zu of %zu px, %zu/%zu tiles; FFT grid %zu x %zu\n"
              "error bound %.3g (bands %.3g, crop %.3g, tiles %.3g; tolerance %.3g) in units of full scale\n"
              "%s\n"
              "wrote %s/sensor.png, skip.json\n",
              src.source().describe().c_str(), scene.planes, scene.rows, scene.cols, rgb.rows, rgb.cols, secs,
              to_string(p).c_str(), r.bands_skipped.size(), r.bands, r.crop_radius_px, r.sensor_psf_px / 2, r.tiles_skipped,
              r.tiles_total, r.grid_rows, r.grid_cols, r.total_bound, r.band_bound, r.crop_bound, r.tile_bound, r.tolerance,
              clip_summary(clip).c_str(), dir.c_str());
  return 0;
}

namespace {
// qdo image: its entry in the command table (help order 140).
const RegisterCommand registered_image(140, [] {
  using namespace opts;
  CommandSpec c{"image", "the RGB sensor image of one scene with the skipping rules of Camera and a skip report", "", "",
                   {preset(), config(), design_spec(), psf_file(), levels_post(), placement(), scene(), key(), resample_bands(), precision(),
                    device(), opt("tolerance", "error bound of the skipped work, in units of full scale, in [0, 1]", "3e-7"),
                    flag("exact", "skip nothing"), opt("tiles", "tiled convolution: off, on or auto", "off"),
                    opt("tile-px", "tile size in sensor pixels, an integer in [8, 4096]", "64"), out_dir_opt()},
                   cmd_image};
  return c;
});
}  // namespace

}  // namespace qdo::cli
