// The camera's skipping options and report, the CPU reference of a skipped computation, and the
// sensor's full-scale clip (include/qdo/physics/camera.hpp). The rules themselves are planned in
// Camera::images (camera.cpp).
#include "qdo/physics/camera.hpp"
#include <nlohmann/json.hpp>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numeric>
#include "qdo/physics/cpu_reference.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/fft.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/simulator.hpp"

namespace qdo {

TileMode tile_mode_from_string(const std::string& s) {
  if (s == "off") return TileMode::Off;
  if (s == "on") return TileMode::On;
  if (s == "auto") return TileMode::Auto;
  reject("tiles", s, "one of off, on, auto");
}

std::string to_string(TileMode m) { return m == TileMode::Off ? "off" : m == TileMode::On ? "on" : "auto"; }

SkipOptions SkipOptions::split(double total, TileMode tiles, std::size_t tile_px) {
  if (!std::isfinite(total) || total < 0) reject("tolerance", total, "a finite tolerance >= 0 (units of full scale)");
  SkipOptions o;
  o.band_tolerance = o.crop_tolerance = o.tile_tolerance = total / 3.0;
  o.tiles = tiles;
  o.tile_px = tile_px;
  return o;
}

void SkipOptions::validate() const {
  const std::pair<const char*, double> tols[] = {
      {"band_tolerance", band_tolerance}, {"crop_tolerance", crop_tolerance}, {"tile_tolerance", tile_tolerance}};
  for (const auto& [name, v] : tols)
    if (!std::isfinite(v) || v < 0) reject(name, v, "a finite tolerance >= 0 (units of full scale)");
  if (tile_px < 8 || tile_px > 4096) reject("tile_px", tile_px, "a tile edge of 8 .. 4096 sensor pixels");
}

std::string SkipReport::to_json() const {
  nlohmann::json j;
  j["scenes"] = scenes;
  j["height"] = height;
  j["width"] = width;
  j["bands"] = bands;
  j["bands_kept"] = bands_kept;
  j["bands_skipped"] = bands_skipped;
  j["sensor_psf_px"] = sensor_psf_px;
  j["crop_radius_px"] = crop_radius_px;
  j["cropped"] = cropped;
  j["min_kept_energy"] = min_kept_energy;
  j["grid"] = {grid_rows, grid_cols};
  j["tiled"] = tiled;
  j["tile_px"] = tile_px;
  j["tiles_per_scene"] = {tiles_y, tiles_x};
  j["tiles_total"] = tiles_total;
  j["tiles_skipped"] = tiles_skipped;
  j["forward_ffts"] = forward_ffts;
  j["inverse_ffts"] = inverse_ffts;
  j["bound"] = {{"bands", band_bound}, {"crop", crop_bound}, {"tiles", tile_bound}, {"total", total_bound}};
  j["tolerance"] = tolerance;
  j["psf_generation"] = psf_generation;
  j["otf_reused"] = otf_reused;
  return j.dump(2);
}

std::vector<RealStack> skipped_images_reference(const std::vector<RealStack>& cubes, const RealStack& psf_sensor,
                                                const Eigen::MatrixXd& srf, const SkipReport& report,
                                                ConvolutionMode mode) {
  const std::size_t s = psf_sensor.rows, c = s / 2, bands = psf_sensor.planes;
  if (psf_sensor.cols != s) reject("psf_sensor", to_str(psf_sensor.rows) + " x " + to_str(psf_sensor.cols), "square planes");
  if (srf.rows() != 3 || std::size_t(srf.cols()) != bands)
    reject("srf", to_str(srf.rows()) + " x " + to_str(srf.cols()), "3 x bands with bands = " + to_str(bands));
  if (report.scenes != cubes.size()) reject("cubes.size()", cubes.size(), "the report's scene count (" + to_str(report.scenes) + ")");
  const std::size_t nk = report.bands_kept.size();
  // Cropped PSF of the kept bands.
  RealStack psf(nk, s, s);
  const long r = long(report.crop_radius_px);
  for (std::size_t i = 0; i < nk; ++i)
    for (std::size_t y = 0; y < s; ++y)
      for (std::size_t x = 0; x < s; ++x) {
        const long ty = long(y) - long(c), tx = long(x) - long(c);
        if (std::labs(ty) <= r && std::labs(tx) <= r) psf(i, y, x) = psf_sensor(report.bands_kept[i], y, x);
      }
  Eigen::MatrixXd wk(3, Eigen::Index(nk));
  for (std::size_t i = 0; i < nk; ++i) wk.col(Eigen::Index(i)) = srf.col(Eigen::Index(report.bands_kept[i]));
  std::vector<RealStack> out;
  for (std::size_t k = 0; k < cubes.size(); ++k) {
    const RealStack& cube = cubes[k];
    if (cube.planes != bands || cube.rows != report.height || cube.cols != report.width)
      reject("cubes[" + to_str(k) + "]", to_str(cube.planes) + " x " + to_str(cube.rows) + " x " + to_str(cube.cols),
             "the report's bands x H x W");
    if (nk == 0) {
      out.emplace_back(3, cube.rows, cube.cols);
      continue;
    }
    RealStack x(nk, cube.rows, cube.cols);
    for (std::size_t i = 0; i < nk; ++i)
      for (std::size_t yy = 0; yy < cube.rows; ++yy)
        for (std::size_t xx = 0; xx < cube.cols; ++xx) {
          bool skip = false;
          if (report.tiled) {
            const std::size_t th = std::min(report.tile_px, cube.rows), tw = std::min(report.tile_px, cube.cols);
            skip = report.tile_skipped[(k * report.tiles_y + yy / th) * report.tiles_x + xx / tw] != 0;
          }
          x(i, yy, xx) = skip ? 0.0 : cube(report.bands_kept[i], yy, xx);
        }
    out.push_back(ref::sensor_integrate(ref::convolve(x, psf, mode), wk));
  }
  return out;
}

SensorClip clip_to_full_scale(RealStack& rgb, const std::string& what) {
  SensorClip c;
  c.total = rgb.data.size();
  std::size_t bad = 0;
  for (double& v : rgb.data) {
    if (!std::isfinite(v)) {
      ++bad;
      continue;
    }
    c.max_before = std::max(c.max_before, v);
    if (v > 1.0) {
      v = 1.0;
      ++c.clipped;
    }
  }
  if (bad)
    throw NumericalError(what + ": " + std::to_string(bad) + " of " + std::to_string(c.total) +
                         " sensor values are NaN or Inf (nothing was written)");
  return c;
}

std::string clip_summary(const SensorClip& c) {
  char buf[160];
  if (c.clipped == 0)
    std::snprintf(buf, sizeof buf, "sensor: no value clipped at full scale (max %.4g)", c.max_before);
  else
    std::snprintf(buf, sizeof buf, "sensor: %.4g %% of values (%zu of %zu) clipped at full scale 1 (max %.4g before clipping)",
                  100.0 * c.fraction(), c.clipped, c.total, c.max_before);
  return buf;
}

}  // namespace qdo
