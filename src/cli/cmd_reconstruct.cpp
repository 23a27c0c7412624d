// qdo reconstruct: captured photos of one scene through the built camera -> a run's decoder with
// the PSF of the camera as built -> cube.h5, srgb.png, spectra.csv / spectra.png (reconstruct.hpp).
#include <cstdio>
#include <string>

#include "cli.hpp"
#include "qdo/error.hpp"
#include "qdo/reconstruct.hpp"
#include "qdo/runtime.hpp"

namespace qdo::cli {

int cmd_reconstruct(const Args& a) {
  ReconstructOptions o;
  if (!a.has("run")) reject("--run", "(missing)", "the run folder whose decoder reconstructs");
  o.run = a.get("run");
  const auto it = a.multi.find("capture");
  if (it != a.multi.end()) o.capture.captures = it->second;
  else if (a.has("capture")) o.capture.captures = {a.get("capture")};
  if (o.capture.captures.empty()) reject("--capture", "(missing)", "one or more 16-bit PNG captures of the scene");
  o.capture.darks_dir = a.get("darks");
  o.psf_file = a.get("psf");
  o.design_file = a.get("design");
  if (a.has("psf") && a.has("design")) reject("--design", o.design_file, "either --psf or --design, not both (the camera as built is one of them)");
  o.capture.exposure = exposure_rule_from_string(a.get("exposure"), "--exposure");
  if (a.has("crop")) {
    const auto v = split_list(a.get("crop"));
    if (v.size() != 4) reject("--crop", a.get("crop"), "ROW,COL,H,W (four integers)");
    o.capture.crop = true;
    o.capture.crop_row = std::size_t(parse_int("--crop", v[0], 0, 1 << 28));
    o.capture.crop_col = std::size_t(parse_int("--crop", v[1], 0, 1 << 28));
    o.capture.crop_rows = std::size_t(parse_int("--crop", v[2], 1, 1 << 28));
    o.capture.crop_cols = std::size_t(parse_int("--crop", v[3], 1, 1 << 28));
  }
  o.capture.demosaic = a.get("demosaic");
  if (o.capture.demosaic != "bilinear" && o.capture.demosaic != "mhc") reject("--demosaic", o.capture.demosaic, "bilinear or mhc");
  if (a.has("overlap")) o.overlap_px = std::size_t(parse_int("--overlap", a.get("overlap"), 1, 1 << 20));
  if (a.has("boundary")) {
    o.boundary_set = true;
    o.boundary = tile_boundary_from_string(a.get("boundary"), "--boundary");
  }
  if (a.has("noise-sigma")) o.noise_sigma = parse_double("--noise-sigma", a.get("noise-sigma"), 0, 10, "(units of full scale)");
  o.regions = parse_regions(a.get("points"), false, "--points");
  for (const auto& r : parse_regions(a.get("boxes"), true, "--boxes")) o.regions.push_back(r);
  o.precision = precision_from_string(a.get("precision"));
  o.out = out_dir(a);
  Runtime rt(a.get("device"));
  const ReconstructResult r = reconstruct(rt, o);
  std::printf("decoder: %s\nPSF: %s\nimage %zu x %zu -> cube %zu x %zu x %zu in %zu tile%s of %zu x %zu px, boundary %s (exposure factor %.6g)\nseconds:",
              r.decoder.c_str(), r.psf.c_str(), r.cube.rows, r.cube.cols, r.cube.planes, r.cube.rows, r.cube.cols, r.tiles,
              r.tiles == 1 ? "" : "s", r.tile_px, r.tile_px, r.boundary.c_str(), r.exposure_factor);
  for (const auto& [k, v] : r.seconds) std::printf(" %s %.3f", k.c_str(), v);
  std::printf("\nwrote %s/cube.h5, srgb.png, spectra.csv, spectra.png, reconstruct.json\n", o.out.c_str());
  return 0;
}

}  // namespace qdo::cli
