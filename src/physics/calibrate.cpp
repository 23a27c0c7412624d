// Measured PSFs from captures (calibrate.hpp): a monochromator sweep of raw frames -> a PSF stack.
#include "qdo/physics/calibrate.hpp"
#include "calibrate_internal.hpp"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <regex>

#include "qdo/runtime/error.hpp"
#include "qdo/physics/flat_field.hpp"
#include "qdo/data/io.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/raw_reference.hpp"

namespace qdo {
namespace fs = std::filesystem;
namespace {

std::string in_quotes(const std::string& p) { return "'" + p + "'"; }
[[noreturn]] void refuse(const std::string& file, const std::string& what) { throw InputError("file " + in_quotes(file) + ": " + what); }

using calibrate_detail::median_of;
// 1.4826 x the median absolute deviation from the median: a Gaussian's sigma, robust to a point.
double mad_sigma(const std::vector<double>& v) {
  const double med = median_of(v);
  std::vector<double> d(v.size());
  for (std::size_t i = 0; i < v.size(); ++i) d[i] = std::abs(v[i] - med);
  return 1.4826 * median_of(d);
}

struct Frame {
  std::string path;
  Map2D dn;  // rows x cols code values
};

// Code values within [0, white]; any pixel at white is saturation (PSF frames only).
void check_codes(const Frame& f, double white, bool refuse_saturated) {
  for (std::size_t i = 0; i < f.dn.data.size(); ++i) {
    const double v = f.dn.data[i];
    if (v < white && v >= 0) continue;
    const std::string px = "pixel (row " + std::to_string(i / f.dn.cols) + ", column " + std::to_string(i % f.dn.cols) + ")";
    if (v > white)
      refuse(f.path, px + " = " + to_str(v) + " DN is above the white level " + to_str(white) +
                         " DN of the sensor settings (bit_depth): another bit depth, or a container shifted left");
    if (refuse_saturated && v >= white)
      refuse(f.path, "saturated: " + px + " is at the white level " + to_str(white) + " DN; capture a shorter exposure");
  }
}

// Predicted share of the signal of each 2 x 2 cell position under a layout at band b.
std::vector<double> cell_shares(Cfa cfa, const Eigen::MatrixXd& srf, std::size_t b) {
  std::vector<double> p(4);
  double sum = 0;
  for (std::size_t k = 0; k < 4; ++k) sum += p[k] = srf(cfa_channel(cfa, k / 2, k % 2), long(b));
  for (auto& v : p) v = sum > 0 ? v / sum : 0.25;
  return p;
}

}  // namespace

Map2D read_raw_frame(const SystemConfig& cfg, const std::string& p) {
  Map2D dn;
  if (is_tiff_path(p) || is_camera_raw_path(p)) {
    CaptureMeta meta;
    const RealStack t = read_capture16(p, &meta);
    if (t.planes != 1) refuse(p, "a raw frame must be a 16-bit grayscale (one sample per pixel) TIFF; this one is RGB");
    // A camera raw file's mosaic layout, black and white levels against the configuration.
    check_camera_raw(meta, to_string(cfg.cfa), cfg.black_level_dn, cfg.white_level_dn(), p);
    dn = Map2D(t.rows, t.cols);
    dn.data = t.data;
  } else {
    dn = read_png16_gray(p);
  }
  // bit_depth 0 (continuous codes, white 1): the 16-bit file holds the fraction of 65535.
  if (cfg.bit_depth == 0)
    for (auto& v : dn.data) v *= 1.0 / 65535.0;
  return dn;
}

double wavelength_from_file_name(const std::string& path) {
  static const std::regex re(R"(.*_([0-9]+(\.[0-9]+)?)nm)", std::regex::icase);
  std::smatch m;
  const std::string stem = fs::path(path).stem().string();
  if (!std::regex_match(stem, m, re)) return -1;
  return std::stod(m[1].str());
}

CalibrationResult calibrate_psf(const SystemConfig& cfg, const std::string& frames_dir, const std::string& darks_dir,
                                const CalibrationOptions& opt) {
  const std::size_t bands = cfg.bands, s = cfg.sensor_size_px();
  const std::vector<double> grid = cfg.wavelengths_nm();
  const double white = cfg.white_level_dn();
  // bit_depth 0 (continuous codes, white 1): the 16-bit file holds the fraction of 65535.
  const double file_scale = cfg.bit_depth == 0 ? 1.0 / 65535.0 : 1.0;
  const bool mosaic = cfg.cfa != Cfa::None;
  // Seconds per step (CalibrationResult::seconds), each lap the time since the previous one.
  std::vector<std::pair<std::string, double>> seconds;
  auto last = std::chrono::steady_clock::now();
  const auto lap = [&](const char* name) {
    const auto now = std::chrono::steady_clock::now();
    seconds.push_back({name, std::chrono::duration<double>(now - last).count()});
    last = now;
  };

  if (opt.mask_windows.empty())
    throw InputError("--mask-windows: empty; give odd window widths in px, ascending, 3 to 255 (default 5,11,23)");
  for (std::size_t k = 0; k < opt.mask_windows.size(); ++k) {
    const std::size_t w = opt.mask_windows[k];
    if (w < 3 || w > 255 || w % 2 == 0 || (k > 0 && w <= opt.mask_windows[k - 1]))
      throw InputError("--mask-windows: " + std::to_string(w) +
                       " is not allowed; give odd window widths in px, strictly ascending, 3 to 255 (default 5,11,23)");
  }

  // 1. Match the file names to the bands (before reading any pixel); a band's several frames are
  // its exposures.
  const std::vector<std::string> files = capture_files(frames_dir, "--frames");
  std::vector<std::vector<std::string>> band_files(bands);
  std::vector<double> band_nm(bands, 0);
  for (const auto& f : files) {
    const double nm = wavelength_from_file_name(f);
    if (nm < 0) refuse(f, "no wavelength in the file name; name PSF frames <anything>_<wavelength>nm.png (e.g. psf_550nm.png)");
    std::size_t b = bands;
    for (std::size_t k = 0; k < bands; ++k)
      if (std::abs(grid[k] - nm) <= kBandAxisToleranceNm) b = k;
    if (b == bands)
      refuse(f, "wavelength " + to_str(nm) + " nm is not a band of the configuration (" + to_str(grid.front()) + " to " +
                    to_str(grid.back()) + " nm in steps of " + to_str(cfg.wavelength_step_nm) + " nm, within " +
                    to_str(kBandAxisToleranceNm) + " nm); remove the frame or use a configuration with that band");
    band_files[b].push_back(f);
    band_nm[b] += nm;
  }
  for (std::size_t b = 0; b < bands; ++b) {
    if (band_files[b].empty())
      throw InputError("--frames " + in_quotes(frames_dir) + ": no frame for the configured band " + to_str(grid[b]) +
                       " nm (expected a file named like psf_" + to_str(grid[b]) + "nm.png)");
    band_nm[b] /= double(band_files[b].size());
  }

  lap("match");
  // 2. Read and check every frame and dark.
  const std::vector<std::string> dark_files = capture_files(darks_dir, "--darks");
  for (const auto& d : dark_files) {
    std::error_code ec;
    for (const auto& bf : band_files)
      for (const auto& f : bf)
        if (std::filesystem::equivalent(d, f, ec))
          refuse(d, "given as a dark (--darks " + in_quotes(darks_dir) + ") but it is also a frame (--frames " +
                        in_quotes(frames_dir) +
                        "); darks are frames taken with the source off, in a folder of their own");
  }
  std::vector<std::vector<Frame>> frames(bands);  // per band, its exposures
  std::vector<Frame> darks;
  std::string first_path;  // the first frame read, and its size
  std::size_t rows = 0, cols = 0;
  auto read = [&](const std::string& p) {
    Frame f{p, read_raw_frame(cfg, p)};
    if (first_path.empty()) {
      first_path = p;
      rows = f.dn.rows;
      cols = f.dn.cols;
    } else if (f.dn.rows != rows || f.dn.cols != cols) {
      refuse(p, "size " + std::to_string(f.dn.rows) + " x " + std::to_string(f.dn.cols) + " differs from the " +
                    std::to_string(rows) + " x " + std::to_string(cols) + " of " + in_quotes(first_path) +
                    " (rows x columns); every frame and dark must have one size");
    }
    return f;
  };
  for (std::size_t b = 0; b < bands; ++b)
    for (const auto& p : band_files[b]) {
      frames[b].push_back(read(p));
      check_codes(frames[b].back(), white, true);
    }
  for (const auto& p : dark_files) {
    darks.push_back(read(p));
    check_codes(darks.back(), white, false);
  }
  std::vector<Frame> whites;
  if (!opt.white_dir.empty())
    for (const auto& p : capture_files(opt.white_dir, "--white")) {
      whites.push_back(read(p));
      check_codes(whites.back(), white, true);  // a clipped white would bend the flat field
    }
  if (rows < s || cols < s)
    refuse(first_path, "frame " + std::to_string(rows) + " x " + std::to_string(cols) +
                           " is smaller than the sensor grid's S x S = " + std::to_string(s) + " x " +
                           std::to_string(s));
  const Eigen::MatrixXd srf = sensor_response(cfg);  // 3 x bands

  lap("read");
  // 3. The mean dark, its noise and its hot pixels.
  Map2D dark(rows, cols);
  for (const auto& d : darks)
    for (std::size_t i = 0; i < dark.data.size(); ++i) dark.data[i] += d.dn.data[i] / double(darks.size());
  const double dark_med = median_of(dark.data), dark_sigma = std::max(mad_sigma(dark.data), 0.5 * file_scale);
  std::vector<char> hot(rows * cols, 0);
  std::size_t hot_count = 0;
  for (std::size_t i = 0; i < hot.size(); ++i)
    hot_count += hot[i] = dark.data[i] > dark_med + opt.hot_sigma * dark_sigma;
  // The flat field (1 x rows x cols, mean 1) of the white frames over the mean dark.
  RealStack flat;
  std::array<double, 3> r_channel_gains{};
  std::vector<std::string> white_files;
  if (!whites.empty()) {
    RealStack w(1, rows, cols, 0.0);
    for (const auto& f : whites)
      for (std::size_t i = 0; i < w.data.size(); ++i) w.data[i] += (f.dn.data[i] - dark.data[i]) / double(whites.size());
    FlatField ff = flat_field(w, cfg.cfa, "--white " + in_quotes(opt.white_dir));
    flat = std::move(ff.gain);
    r_channel_gains = ff.channel_gains;
    for (const auto& f : whites) white_files.push_back(f.path);
  }
  Map2D flat_map;
  if (!flat.data.empty()) {
    flat_map = Map2D(rows, cols);
    flat_map.data = flat.data;
  }
  // Shot noise: one electron is gain x (white - black) / full well DN; its variance per DN of
  // signal is that many DN². No full well configured: read noise alone.
  const double shot_dn =
      cfg.full_well_photons > 0 ? cfg.gain * (white - cfg.black_level_dn) / cfg.full_well_photons : 0.0;
  // Each pixel's gain at each band (step 5), the darks' hot pixels dead.
  PixelGain gain;
  gain.cfa = cfg.cfa;
  gain.min_response = mosaic ? opt.min_response : 0.0;
  gain.flat = flat_map.data.empty() ? nullptr : &flat_map;
  gain.dead = hot;
  gain.cols = cols;
  for (std::size_t b = 0; b < bands; ++b) {
    const double top = std::max({srf(0, long(b)), srf(1, long(b)), srf(2, long(b))});
    std::array<double, 3> w{1, 1, 1};
    if (mosaic)
      for (long c = 0; c < 3; ++c) w[std::size_t(c)] = top > 0 ? srf(c, long(b)) / top : 0;
    gain.response.push_back(w);
  }

  CalibrationResult r;
  r.channel_gains = r_channel_gains;
  r.whites = white_files;
  for (const auto& bf : band_files) {
    r.files.insert(r.files.end(), bf.begin(), bf.end());
    r.exposures.push_back(bf.size());
  }
  r.wavelengths_nm = band_nm;
  r.darks = dark_files;
  r.frame_rows = rows;
  r.frame_cols = cols;
  r.peak_snr.resize(bands);
  r.noise_dn.resize(bands);
  r.background_dn.resize(bands);
  lap("dark");
  // Per band: the exposures over the dark (DN), each one's sigma, the transients (step 4) and the
  // band's mean with its count of exposures used per pixel.
  std::vector<std::vector<Map2D>> expo(bands);
  std::vector<std::vector<double>> expo_sigma(bands);
  std::vector<std::vector<Map2D>> excess(bands);
  std::vector<std::vector<std::vector<char>>> transient(bands);
  std::vector<Map2D> mean(bands);
  std::vector<std::vector<std::uint16_t>> used(bands);  // per band, rows x cols: exposures in the mean
  const auto average = [&](std::size_t b) {             // the band's mean over the exposures not transient there
    const std::size_t k = expo[b].size();
    mean[b] = Map2D(rows, cols);
    used[b].assign(rows * cols, 0);
    for (std::size_t i = 0; i < rows * cols; ++i) {
      double sum = 0;
      std::size_t n = 0;
      for (std::size_t e = 0; e < k; ++e)
        if (!transient[b][e][i]) sum += expo[b][e].data[i], ++n;
      mean[b].data[i] = n ? sum / double(n) : 0.0;
      used[b][i] = std::uint16_t(std::min<std::size_t>(n, 65535));
    }
  };
  for (std::size_t b = 0; b < bands; ++b) {
    const std::size_t k = frames[b].size();
    for (std::size_t e = 0; e < k; ++e) {
      Map2D m(rows, cols);
      for (std::size_t i = 0; i < m.data.size(); ++i) m.data[i] = frames[b][e].dn.data[i] - dark.data[i];
      expo_sigma[b].push_back(std::max(mad_sigma(m.data), 0.5 * file_scale));
      expo[b].push_back(std::move(m));
    }
    frames[b].clear();  // the codes are no longer needed
    // 4 (exposures). Transients against the band's other exposures.
    excess[b] = exposure_excess(expo[b], expo_sigma[b], shot_dn, opt.hot_sigma, hot);
    transient[b].assign(k, std::vector<char>(rows * cols, 0));
    for (std::size_t e = 0; e < k; ++e)
      for (std::size_t i = 0; i < rows * cols; ++i)
        transient[b][e][i] = !hot[i] && excess[b][e].data[i] > opt.hot_sigma;
    average(b);
    const Map2D& m = mean[b];
    const double sigma = std::max(mad_sigma(m.data), 0.5 * file_scale / std::sqrt(double(k)));
    r.noise_dn[b] = sigma;
    // The darks against this frame's own background: its 10th percentile is the background's
    // (-1.2816 sigma for Gaussian noise) wherever at least a tenth of the frame is unlit, and
    // light can only raise it. Darks taken at another exposure, gain or temperature shift it.
    {
      std::vector<double> v = m.data;
      const std::size_t q = v.size() / 10;
      std::nth_element(v.begin(), v.begin() + long(q), v.end());
      const double offset = v[q] + 1.2816 * sigma;
      r.background_dn[b] = offset;
      if (std::abs(offset) > 3 * sigma) {
        const std::string what = "after the mean dark is subtracted, the frame's background sits at " + to_str(offset) +
                                 " DN (noise sigma " + to_str(sigma) + " DN; darks that match give 0 +- " + to_str(3 * sigma) +
                                 "): the darks in " + in_quotes(darks_dir) + " were not taken as this frame was " +
                                 "(exposure, gain, black level, temperature)";
        if (!opt.ring_background || offset < 0)
          refuse(band_files[b][0],
                 what +
                     (offset < 0 ? "; a dark brighter than the frame's unlit pixels is not a dark of it. "
                                 : "; --background ring would subtract a constant offset, or ") +
                     "take darks with the frames' settings");
        r.notes.push_back(band_files[b][0] + ": " + what + "; --background ring subtracts it as a constant");
      }
    }
  }
  // 4 (adjacent bands). Each exposure's values against the ceiling the adjacent bands' means set.
  for (std::size_t b = 0; b < bands; ++b) {
    const std::size_t k = expo[b].size();
    for (std::size_t e = 0; e < k; ++e) {
      const Map2D ceiling =
          adjacent_band_ceiling(b, mean, r.noise_dn, r.exposures, gain, expo_sigma[b][e], shot_dn, opt.hot_sigma);
      for (std::size_t i = 0; i < rows * cols; ++i)
        // Marked 2: the means the other bands are tested against stay as they were until the end.
        if (!transient[b][e][i] && expo[b][e].data[i] > ceiling.data[i] && (k == 1 || excess[b][e].data[i] > 3))
          transient[b][e][i] = 2;
    }
    for (std::size_t e = 0; e < k; ++e)
      for (std::size_t i = 0; i < rows * cols; ++i)
        if (transient[b][e][i]) r.transients.push_back({b, e, i / cols, i % cols});
  }
  for (std::size_t b = 0; b < bands; ++b) {
    average(b);
    expo[b].clear();
    excess[b].clear();
  }
  r.hot_pixels = hot_count * bands + r.transients.size();
  r.hot_map = hot;

  std::vector<Map2D> sig(bands);  // per band, rows x cols: dark-subtracted mean, flat divided (DN)
  std::vector<double> cell(4, 0), worst(bands, 0);
  std::vector<std::vector<double>> cell_b(bands, std::vector<double>(4, 0));
  for (std::size_t b = 0; b < bands; ++b) {
    Map2D m = mean[b];
    const double sigma = r.noise_dn[b], med = median_of(m.data);
    if (!flat.data.empty())
      for (std::size_t i = 0; i < m.data.size(); ++i) m.data[i] /= flat.data[i];
    // 6. Peak SNR, over the pixels measured.
    double peak = -1e300;
    for (std::size_t i = 0; i < m.data.size(); ++i)
      if (!hot[i] && used[b][i]) peak = std::max(peak, m.data[i] - med);
    r.peak_snr[b] = peak / sigma;
    if (r.peak_snr[b] < opt.min_snr)
      refuse(band_files[b][0], "too dark: peak SNR " + to_str(r.peak_snr[b]) + " (peak " + to_str(peak) +
                                   " DN above the dark, noise " + to_str(sigma) + " DN) is below --min-snr " +
                                   to_str(opt.min_snr));
    for (std::size_t y = 0; y < rows; ++y)  // the 2 x 2 cell signals, with "cfa": "none" too (5a)
      for (std::size_t x = 0; x < cols; ++x)
        if (!hot[y * cols + x] && used[b][y * cols + x] && m(y, x) - med > 3 * sigma)
          cell_b[b][(y & 1) * 2 + (x & 1)] += m(y, x) - med;
    sig[b] = std::move(m);
  }

  lap("hot pixels and SNR");
  // 5a. The mosaic layout against the configured one, "none" (a monochrome sensor: the four
  // cells share a band's light equally) among the candidates: mosaic frames calibrated as
  // monochrome were read as speckle full of hot pixels.
  {
    const Cfa layouts[5] = {Cfa::None, Cfa::RGGB, Cfa::GRBG, Cfa::GBRG, Cfa::BGGR};
    const auto shares = [&](Cfa c, std::size_t b) { return c == Cfa::None ? std::vector<double>(4, 0.25) : cell_shares(c, srf, b); };
    double err[5] = {0, 0, 0, 0, 0}, err_cfg = 0;
    for (std::size_t b = 0; b < bands; ++b) {
      double tot = 0;
      for (double v : cell_b[b]) tot += v;
      if (tot <= 0) continue;
      for (int l = 0; l < 5; ++l) {
        const auto p = shares(layouts[l], b);
        for (std::size_t k = 0; k < 4; ++k) err[l] += std::pow(cell_b[b][k] / tot - p[k], 2);
      }
      const auto p = shares(cfg.cfa, b);
      double e = 0;
      for (std::size_t k = 0; k < 4; ++k) e += std::pow(cell_b[b][k] / tot - p[k], 2);
      worst[b] = e;
      err_cfg += e;
    }
    const int best = int(std::min_element(err, err + 5) - err);
    if (layouts[best] != cfg.cfa && err_cfg > 4 * err[best] && err_cfg > 1e-3 * double(bands)) {
      const std::size_t wb = std::size_t(std::max_element(worst.begin(), worst.end()) - worst.begin());
      refuse(band_files[wb][0], "the capture's colour mosaic does not match the sensor settings: \"cfa\": \"" +
                                    to_string(cfg.cfa) + "\" fits the 2 x 2 cell signals of the sweep " +
                                    to_str(err_cfg / std::max(err[best], 1e-300)) + " times worse than \"" +
                                    to_string(layouts[best]) + "\" (this frame worst); check the configuration's cfa");
    }
  }

  // 5b. The joint estimate of each band's PSF (joint_pixel_estimate) from the mean over the dark
  // (not flat divided: the gain holds the flat). noise_scale[b]: each pixel's error sd over the
  // band's sigma (step 7); info[b]: sigma² / the variance of the pixel's own estimate (step 8's
  // signal mask).
  std::vector<Map2D> noise_scale(bands), info(bands);
  for (std::size_t b = 0; b < bands; ++b) {
    const double sigma = r.noise_dn[b], k = double(r.exposures[b]);
    Map2D g(rows, cols), rv(rows, cols);
    for (std::size_t y = 0; y < rows; ++y)
      for (std::size_t x = 0; x < cols; ++x) {
        const std::size_t i = y * cols + x, n = used[b][i];
        g.data[i] = n ? gain(b, y, x) : 0.0;
        rv.data[i] = n ? sigma * sigma * k / double(n) : 0.0;
      }
    JointEstimate je = joint_pixel_estimate(mean[b], g, rv, shot_dn / k);
    mean[b] = Map2D();
    sig[b] = std::move(je.value);
    noise_scale[b] = std::move(je.sd);
    for (double& v : noise_scale[b].data) v /= sigma;
    info[b] = std::move(je.info);
    for (double& v : info[b].data) v *= sigma * sigma;
  }

  lap("mosaic");
  // 7. The common centre (choose_centre).
  const CentreChoice centre = choose_centre(sig, noise_scale, r.noise_dn, s, opt);
  const long cy = centre.row, cx = centre.col;
  r.centre_rule = centre.rule;
  if (!centre.note.empty()) r.notes.push_back(centre.note);
  lap("centre");
  r.centre_row = cy;
  r.centre_col = cx;
  const long y0 = cy - long(s / 2), x0 = cx - long(s / 2);
  if (y0 < 0 || x0 < 0 || y0 + long(s) > long(rows) || x0 + long(s) > long(cols))
    refuse(first_path, "the S x S = " + std::to_string(s) + " x " + std::to_string(s) +
                           " crop around the centre (row " + std::to_string(cy) + ", column " + std::to_string(cx) +
                           ") leaves the " + std::to_string(rows) + " x " + std::to_string(cols) +
                           " frame (every frame shares the centre); centre the point source or give --centre");

  // 8. Crop, background, signal mask, normalise (crop_band).
  r.psf = RealStack(bands, s, s);
  for (std::size_t b = 0; b < bands; ++b) {
    const Map2D band = crop_band(sig[b], info[b], r.noise_dn[b], std::size_t(y0), std::size_t(x0), s, opt.floor_sigma,
                                 opt.ring_background, opt.mask_windows);
    double sum = 0;
    for (double v : band.data) sum += v;
    if (!(sum > 0)) refuse(band_files[b][0], "no signal above the background in the S x S crop");
    std::copy(band.data.begin(), band.data.end(), r.psf.data.begin() + long(b * s * s));
  }
  lap("crop, background and normalise");
  r.seconds = seconds;
  return r;
}

}  // namespace qdo
