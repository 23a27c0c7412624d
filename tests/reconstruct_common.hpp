// What the reconstruct suite's files share (tests/test_reconstruct*.cpp): scenes, the run's
// camera and decoder, and the cube a reconstruction writes.
#pragma once
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <memory>
#include <random>

#include "commands_common.hpp"
#include "common.hpp"
#include "qdo/decode/decoder_registry.hpp"
#include "qdo/decode/tiled.hpp"
#include "qdo/data/io.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/decode/wiener.hpp"

namespace qdo::test::reconstruct_suite {

namespace fs = std::filesystem;
using qdo::test::commands_suite::tiny;

// A smooth scene (bands x rows x cols in [0, 1]): a few cosines per band, as natural images are
// dominated by low frequencies.
inline RealStack smooth_scene(std::size_t bands, std::size_t rows, std::size_t cols, unsigned seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  RealStack x(bands, rows, cols, 0.0);
  for (std::size_t b = 0; b < bands; ++b)
    for (int k = 0; k < 3; ++k) {
      const double fy = u(rng) * 0.08, fx = u(rng) * 0.08, ph = u(rng) * 6.28, a = 0.1 + 0.1 * u(rng);
      for (std::size_t y = 0; y < rows; ++y)
        for (std::size_t xx = 0; xx < cols; ++xx) x(b, y, xx) += a * (1 + std::cos(6.2831853 * (fy * double(y) + fx * double(xx)) + ph));
    }
  for (double& v : x.data) v = std::min(1.0, v / 1.3);
  return x;
}

// The code values of a linear RGB image (3 x H x W) in a 16-bit container at gain 1, black 0:
// round(clamp(v, 0, 1) * 65535) plus `offset` DN.
inline RealStack to_dn(const RealStack& rgb, double offset = 0) {
  RealStack dn = rgb;
  for (double& v : dn.data) v = std::round(std::clamp(v, 0.0, 1.0) * 65535.0) + offset;
  return dn;
}

inline RealStack read_cube_h5(const fs::path& p) {
  const H5Dataset d = h5_read(p.string(), "/cube");
  REQUIRE(d.shape.size() == 3);
  RealStack c(d.shape[0], d.shape[1], d.shape[2]);
  c.data = d.data;
  return c;
}

// The run's sensor image of a scene through its psf.h5, noiseless (the circular camera of the
// Wiener decoder's model).
inline RealStack camera_image(const fs::path& run, const RealStack& scene) {
  const PsfStackFile f = read_psf_stack_file((run / "psf.h5").string());
  return wiener::simulate_measurement(scene, wiener::psf_to_otf(f.psf_sensor, scene.rows, scene.cols), sensor_response(tiny()));
}

// The run's decoder as `qdo eval` builds it (the registry's Wiener decoder for the run's PSF,
// prior and noise sigma); with TileBoundary::Linear the Wiener decoder of the linear boundary as
// reconstruct builds it (linear_tile_wiener, on the 2S grid).
inline std::unique_ptr<Decoder> run_decoder(const fs::path& run, TileBoundary boundary = TileBoundary::Circular) {
  const RunFolder folder(run.string());
  const DesignRunOptions o = folder.config();
  if (boundary == TileBoundary::Linear)
    return linear_tile_wiener(read_psf_stack_file((run / "psf.h5").string()).psf_sensor, sensor_response(o.cfg),
                              folder.prior(o.cfg.sensor_size_px()), o.decoder_noise_sigma, o.cfg.sensor_size_px());
  DecoderInputs in;
  in.spec = o.decoder;
  in.psf = read_psf_stack_file((run / "psf.h5").string()).psf_sensor;
  in.srf = sensor_response(o.cfg);
  in.prior = folder.prior(o.cfg.sensor_size_px());
  in.noise_sigma = o.decoder_noise_sigma;
  return make_decoder(in);
}

inline double max_abs_diff(const RealStack& a, const RealStack& b) {
  REQUIRE(a.data.size() == b.data.size());
  double m = 0;
  for (std::size_t i = 0; i < a.data.size(); ++i) m = std::max(m, std::fabs(a.data[i] - b.data[i]));
  return m;
}

}  // namespace qdo::test::reconstruct_suite
