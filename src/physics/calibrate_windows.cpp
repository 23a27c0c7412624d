// The raw frames of a point-source sweep reduced for a fit in the measurement domain
// (calibrate.hpp: reduce_psf_frames): calibrate_psf's reading, checks, hot pixels, transients,
// noise and centre, then each band's S x S window of the frames themselves with its
// Poisson-Gaussian variance, its pixels' gains and what is usable.
#include <algorithm>
#include <array>
#include <cmath>
#include <set>

#include "qdo/physics/calibrate.hpp"
#include "qdo/physics/flat_field.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/raw_reference.hpp"
#include "qdo/runtime/error.hpp"

namespace qdo {

RawPsfWindows reduce_psf_frames(const SystemConfig& cfg, const std::string& frames_dir, const std::string& darks_dir,
                                const CalibrationOptions& opt_in) {
  CalibrationOptions opt = opt_in;
  // The raw model has no background term: the darks alone remove the sensor's offset, and darks
  // that were not taken as the frames were are refused (calibrate's --background none).
  opt.ring_background = false;
  RawPsfWindows w;
  w.calibration = calibrate_psf(cfg, frames_dir, darks_dir, opt);  // every check and refusal, the centre
  const CalibrationResult& c = w.calibration;
  const std::size_t bands = cfg.bands, s = cfg.sensor_size_px(), rows = c.frame_rows, cols = c.frame_cols;
  const double white = cfg.white_level_dn();
  w.s = s;
  w.top = c.centre_row - long(s / 2);
  w.left = c.centre_col - long(s / 2);
  w.dn_full_scale = cfg.gain * (white - cfg.black_level_dn);
  if (!(w.dn_full_scale > 0))
    reject("gain", to_str(cfg.gain) + " with black_level_dn " + to_str(cfg.black_level_dn),
           "a positive gain x (white level - black level): the DN of full scale");
  // The window inside the frame: calibrate_psf refused a crop that leaves it.
  const std::size_t top = std::size_t(w.top), left = std::size_t(w.left);

  // The mean dark and the flat field (as calibrate_psf makes them), and the read noise of one
  // frame from the darks' spread about their mean: the mean over the pixels (hot ones left out) of
  // each pixel's sample variance over the dark frames, which holds the read noise and the codes'
  // rounding (a far finer estimate than the MAD of a lit frame's integer codes).
  const std::size_t n_darks = c.darks.size();
  const double code_step = cfg.bit_depth == 0 ? 1.0 / 65535.0 : 1.0;  // one code of the files, DN
  std::vector<Map2D> dark_frames;
  Map2D dark(rows, cols);
  for (const auto& p : c.darks) {
    dark_frames.push_back(read_raw_frame(cfg, p));
    for (std::size_t i = 0; i < dark.data.size(); ++i) dark.data[i] += dark_frames.back().data[i] / double(n_darks);
  }
  double dark_var_dn2 = 0;
  if (n_darks >= 2) {
    std::size_t pixels = 0;
    for (std::size_t i = 0; i < dark.data.size(); ++i) {
      if (c.hot_map[i]) continue;
      double ss = 0;
      for (const Map2D& f : dark_frames) ss += (f.data[i] - dark.data[i]) * (f.data[i] - dark.data[i]);
      dark_var_dn2 += ss / double(n_darks - 1);
      ++pixels;
    }
    dark_var_dn2 /= double(std::max<std::size_t>(pixels, 1));
  }
  dark_frames.clear();
  Map2D flat;
  if (!c.whites.empty()) {
    RealStack ws(1, rows, cols, 0.0);
    for (const auto& p : c.whites) {
      const Map2D f = read_raw_frame(cfg, p);
      for (std::size_t i = 0; i < ws.data.size(); ++i)
        ws.data[i] += (f.data[i] - dark.data[i]) / double(c.whites.size());
    }
    FlatField ff = flat_field(ws, cfg.cfa, "--white");
    flat = Map2D(rows, cols);
    flat.data = std::move(ff.gain.data);
  }
  const bool mosaic = cfg.cfa != Cfa::None;
  const Eigen::MatrixXd srf = sensor_response(cfg);  // 3 x bands
  PixelGain gain;
  gain.cfa = cfg.cfa;
  gain.min_response = mosaic ? opt.min_response : 0.0;
  gain.flat = flat.data.empty() ? nullptr : &flat;
  gain.dead = c.hot_map;
  gain.cols = cols;
  for (std::size_t b = 0; b < bands; ++b) {
    const double top_srf = std::max({srf(0, long(b)), srf(1, long(b)), srf(2, long(b))});
    std::array<double, 3> r{1, 1, 1};
    if (mosaic)
      for (long k = 0; k < 3; ++k) r[std::size_t(k)] = top_srf > 0 ? srf(k, long(b)) / top_srf : 0;
    gain.response.push_back(r);
  }
  w.colour.resize(s * s);
  for (std::size_t y = 0; y < s; ++y)
    for (std::size_t x = 0; x < s; ++x) w.colour[y * s + x] = cfa_channel(cfg.cfa, top + y, left + x);

  // Shot noise: one electron is gain x (white - black) / full well DN (calibrate_psf's shot_dn).
  const double shot_dn =
      cfg.full_well_photons > 0 ? cfg.gain * (white - cfg.black_level_dn) / cfg.full_well_photons : 0.0;
  w.signal = RealStack(bands, s, s, 0.0);
  w.variance = RealStack(bands, s, s, 0.0);
  w.gain = RealStack(bands, s, s, 0.0);
  w.read_variance = RealStack(bands, s, s, 0.0);
  w.shot_per_signal = RealStack(bands, s, s, 0.0);
  std::size_t first = 0;  // the band's first file in c.files
  for (std::size_t b = 0; b < bands; ++b) {
    const std::size_t k = c.exposures[b];
    // The transients of this band inside the window: (exposure, window index).
    std::set<std::pair<std::size_t, std::size_t>> transient;
    for (const auto& t : c.transients)
      if (t[0] == b && t[2] >= top && t[2] < top + s && t[3] >= left && t[3] < left + s)
        transient.insert({t[1], (t[2] - top) * s + (t[3] - left)});
    std::vector<double> sum(s * s, 0.0);
    std::vector<std::size_t> used(s * s, 0);
    for (std::size_t e = 0; e < k; ++e) {
      const Map2D f = read_raw_frame(cfg, c.files[first + e]);
      for (std::size_t y = 0; y < s; ++y)
        for (std::size_t x = 0; x < s; ++x) {
          const std::size_t i = y * s + x;
          const double code = f(top + y, left + x);
          // A code at 0 was clipped below (read noise under the black level): no measurement.
          // (A code at the white level was refused by calibrate_psf: saturated.)
          if (code <= 0 || transient.count({e, i})) continue;
          sum[i] += code - dark(top + y, left + x);
          ++used[i];
        }
    }
    first += k;
    // The read variance of the mean of n exposures less the mean dark: with two darks or more,
    // (1 / n + 1 / darks) x one frame's, that from the darks' spread and at least the rounding's
    // 1 / 12 code^2 (noise-free codes are still rounded); with one dark, calibrate's noise of the
    // band's mean (the MAD of its unlit pixels: read noise, the dark's and rounding, at least
    // 0.5 DN / sqrt(k)) times k / n.
    const double frame_var_dn2 = std::max(dark_var_dn2, code_step * code_step / 12);
    const auto read_var = [&](double n) {
      return n_darks >= 2 ? frame_var_dn2 * (1 / n + 1 / double(n_darks))
                          : c.noise_dn[b] * c.noise_dn[b] * double(k) / n;
    };
    std::vector<double> d_dn(s * s, 0.0), g(s * s, 0.0);
    for (std::size_t y = 0; y < s; ++y)
      for (std::size_t x = 0; x < s; ++x) {
        const std::size_t i = y * s + x;
        if (!used[i]) continue;
        d_dn[i] = sum[i] / double(used[i]);
        g[i] = gain(b, top + y, left + x);
      }
    // The expected signal of each pixel for its shot noise: its gain times the PSF its 8
    // neighbours measure (least squares over their gains), never its own value, so that a pixel's
    // weight does not follow its own noise (weights independent of the data they weigh leave the
    // weighted fit unbiased).
    for (std::size_t y = 0; y < s; ++y)
      for (std::size_t x = 0; x < s; ++x) {
        const std::size_t i = y * s + x;
        if (!(g[i] > 0)) continue;
        double num = 0, den = 0;
        for (long dy = -1; dy <= 1; ++dy)
          for (long dx = -1; dx <= 1; ++dx) {
            const long yy = long(y) + dy, xx = long(x) + dx;
            if ((!dy && !dx) || yy < 0 || xx < 0 || yy >= long(s) || xx >= long(s)) continue;
            const std::size_t q = std::size_t(yy) * s + std::size_t(xx);
            num += g[q] * d_dn[q];
            den += g[q] * g[q];
          }
        const double expected_dn = den > 0 ? std::max(g[i] * num / den, 0.0) : std::max(d_dn[i], 0.0);
        const double n = double(used[i]);
        const double var_dn2 = read_var(n) + shot_dn * expected_dn / n;
        w.signal(b, y, x) = d_dn[i] / w.dn_full_scale;
        w.variance(b, y, x) = var_dn2 / (w.dn_full_scale * w.dn_full_scale);
        w.read_variance(b, y, x) = read_var(n) / (w.dn_full_scale * w.dn_full_scale);
        w.shot_per_signal(b, y, x) = shot_dn / (n * w.dn_full_scale);
        w.gain(b, y, x) = g[i];
        ++w.usable;
      }
  }
  return w;
}

}  // namespace qdo
