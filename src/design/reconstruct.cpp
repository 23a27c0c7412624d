// `qdo reconstruct` (reconstruct.hpp): captures -> signal -> tiles through a run's decoder -> cube,
// sRGB render, spectra.
#include "qdo/reconstruct.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <sstream>

#include "qdo/decoder_registry.hpp"
#include "qdo/demosaic.hpp"
#include "qdo/design_run.hpp"
#include "qdo/embedded.hpp"
#include "qdo/error.hpp"
#include "qdo/io.hpp"
#include "qdo/network_decoder.hpp"
#include "qdo/optics.hpp"
#include "qdo/psf_source.hpp"
#include "qdo/raw_reference.hpp"
#include "qdo/run.hpp"
#include "qdo/run_folder.hpp"
#include "qdo/scenes.hpp"
#include "qdo/simulator.hpp"

namespace fs = std::filesystem;

namespace qdo {
namespace {

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// A number of `s` in [lo, hi] (lo excluded when lo_open); InputError naming `argument` and the whole value.
double number_in(const std::string& s, const std::string& argument, const std::string& whole, double lo, double hi, bool lo_open,
                 const std::string& allowed) {
  char* end = nullptr;
  const double v = std::strtod(s.c_str(), &end);
  if (s.empty() || *end || !std::isfinite(v) || v > hi || (lo_open ? v <= lo : v < lo)) reject(argument, whole, allowed);
  return v;
}

std::vector<std::string> split(const std::string& s, char sep) {
  std::vector<std::string> out;
  std::stringstream ss(s);
  for (std::string x; std::getline(ss, x, sep);) out.push_back(x);
  if (!s.empty() && s.back() == sep) out.push_back("");
  return out;
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Exposure.

std::string ExposureRule::to_string() const {
  if (kind == Kind::Scale) return "scale:" + to_str(scale);
  if (kind == Kind::Percentile) return "percentile:" + to_str(percentile) + ":" + to_str(level);
  return "none";
}

ExposureRule exposure_rule_from_string(const std::string& s, const std::string& argument) {
  const std::string allowed = "none, scale:K (K in (0, 1e6]) or percentile:P:L (P in (0, 100], L in (0, 1])";
  ExposureRule r;
  if (s == "none" || s.empty()) return r;
  const auto f = split(s, ':');
  if (f.size() == 2 && f[0] == "scale") {
    r.kind = ExposureRule::Kind::Scale;
    r.scale = number_in(f[1], argument, s, 0, 1e6, true, allowed);
    return r;
  }
  if (f.size() == 3 && f[0] == "percentile") {
    r.kind = ExposureRule::Kind::Percentile;
    r.percentile = number_in(f[1], argument, s, 0, 100, true, allowed);
    r.level = number_in(f[2], argument, s, 0, 1, true, allowed);
    return r;
  }
  reject(argument, s, allowed);
}

// ---------------------------------------------------------------------------------------------
// Captures.

// Saturated, empty and clipped captures: refused when nothing can be reconstructed from them
// (no signal above the dark or black level; most values at the white level), said in f.notes
// (printed, and kept in reconstruct.json) when part of the capture is clipped.
void check_capture_levels(const SystemConfig& cfg, const CaptureOptions& o, CaptureFiles& f) {
  const std::string first = "file '" + o.captures.front() + "'" + (o.captures.size() > 1 ? " (and the other captures)" : "");
  const std::size_t n = f.mean_dn.data.size() * o.captures.size();
  const double sat_fraction = double(f.saturated) / double(std::max<std::size_t>(n, 1));
  if (sat_fraction > 0.5)
    throw InputError(first + ": " + to_str(100 * sat_fraction) + " % of the capture values are at the white level " + to_str(f.white_dn) +
                     " DN: overexposed, nothing to reconstruct; capture again with a shorter exposure or a lower gain");
  // The signal above the dark (or the black level). Empty: its 99.9th percentile within 0.1 % of
  // the range of 0 (black, zero, the darks themselves), or within 0.5 % and no further above the
  // median than noise goes (4 sigma, from the median absolute deviation): the lens cap on.
  std::vector<double> sig(f.mean_dn.data.size());
  for (std::size_t i = 0; i < sig.size(); ++i)
    sig[i] = f.mean_dn.data[i] - (f.dark_dn.data.empty() ? cfg.black_level_dn : f.dark_dn.data[i]);
  auto quantile = [](std::vector<double> v, double q) {
    const std::size_t k = std::min(v.size() - 1, std::size_t(q * double(v.size())));
    std::nth_element(v.begin(), v.begin() + long(k), v.end());
    return v[k];
  };
  const double top = quantile(sig, 0.999), med = quantile(sig, 0.5), range = f.white_dn - cfg.black_level_dn;
  std::vector<double> dev(sig.size());
  for (std::size_t i = 0; i < sig.size(); ++i) dev[i] = std::fabs(sig[i] - med);
  const double sigma = 1.4826 * quantile(dev, 0.5);
  const bool noise_only = sigma > 0 && top <= 0.005 * range && top - med <= 4 * sigma;
  if (!(top > 0.001 * range) || noise_only)
    throw InputError(first + ": no signal: its 99.9th percentile is " + to_str(top) + " DN above the " +
                     (f.dark_dn.data.empty() ? "black level " + to_str(cfg.black_level_dn) + " DN" : std::string("mean dark")) +
                     (noise_only ? ", within the noise (" + to_str(sigma) + " DN) of its median" : std::string()) + " (range " + to_str(range) +
                     " DN): an empty or black capture, the lens cap on, or darks given as the capture");
  if (f.saturated > 0)
    f.notes.push_back(to_str(f.saturated) + " capture values (" + to_str(100 * sat_fraction) + " %) are at the white level " +
                      to_str(f.white_dn) + " DN: clipped, so the cube is wrong around them; a shorter exposure avoids it");
}

CaptureFiles read_captures(const SystemConfig& cfg, const CaptureOptions& o) {
  if (o.captures.empty()) reject("--capture", "(missing)", "one or more 16-bit PNG captures of the scene");
  const std::size_t planes = raw_channels(cfg.cfa);
  CaptureFiles f;
  f.white_dn = cfg.bit_depth > 0 ? cfg.white_level_dn() : 65535.0;
  auto check = [&](const RealStack& img, const std::string& path, const RealStack* like, const std::string& like_name) {
    if (img.planes != planes)
      throw InputError("file '" + path + "': a " + (img.planes == 1 ? std::string("grayscale (raw mosaic)") : std::string("RGB")) +
                       " capture, but the configuration's cfa is \"" + to_string(cfg.cfa) + "\", which needs " +
                       (planes == 1 ? "a raw mosaic (16-bit grayscale PNG)" : "an RGB capture (16-bit RGB PNG)"));
    if (like && (img.rows != like->rows || img.cols != like->cols))
      throw InputError("file '" + path + "': " + to_str(img.rows) + " x " + to_str(img.cols) + " pixels, but '" + like_name + "' has " +
                       to_str(like->rows) + " x " + to_str(like->cols) + " (every capture and dark frame must be the same size)");
    for (std::size_t i = 0; i < img.data.size(); ++i)
      if (img.data[i] > f.white_dn) {
        const std::size_t p = i % img.plane_size();
        throw InputError("file '" + path + "': code value " + to_str(img.data[i]) + " at row " + to_str(p / img.cols) + ", column " +
                         to_str(p % img.cols) + " is above the white level " + to_str(f.white_dn) + " DN of bit_depth " +
                         to_str(cfg.bit_depth) + " (wrong bit depth, or a container shifted left)");
      }
  };
  // Every file read and checked before any is processed.
  std::vector<RealStack> caps;
  for (const std::string& path : o.captures) {
    caps.push_back(read_capture16(path));
    check(caps.back(), path, caps.size() > 1 ? &caps.front() : nullptr, o.captures.front());
  }
  if (!o.darks_dir.empty()) f.darks = capture_files(o.darks_dir, "--darks");
  std::vector<RealStack> darks;
  for (const std::string& path : f.darks) {
    darks.push_back(read_capture16(path));
    check(darks.back(), path, &caps.front(), o.captures.front());
  }
  f.mean_dn = RealStack(caps.front().planes, caps.front().rows, caps.front().cols, 0.0);
  for (const RealStack& c : caps)
    for (std::size_t i = 0; i < c.data.size(); ++i) {
      f.mean_dn.data[i] += c.data[i] / double(caps.size());
      if (c.data[i] >= f.white_dn) ++f.saturated;
    }
  if (!darks.empty()) {
    f.dark_dn = RealStack(f.mean_dn.planes, f.mean_dn.rows, f.mean_dn.cols, 0.0);
    for (const RealStack& d : darks)
      for (std::size_t i = 0; i < d.data.size(); ++i) f.dark_dn.data[i] += d.data[i] / double(darks.size());
  }
  check_capture_levels(cfg, o, f);
  return f;
}

void check_mosaic_phase(const RealStack& raw, Cfa cfa, const std::string& origin) {
  if (cfa == Cfa::None || raw.rows < 2 || raw.cols < 2) return;
  // Diagonal neighbours within each 2 x 2 cell: (0,1)-(1,0) and (0,0)-(1,1). The same spatial step,
  // so the pair that shares a filter (green) differs by the scene's gradient only, the other (red
  // against blue) by the colour as well.
  double d_anti = 0, d_diag = 0, level = 0;
  std::size_t n = 0;
  for (std::size_t y = 0; y + 1 < raw.rows; y += 2)
    for (std::size_t x = 0; x + 1 < raw.cols; x += 2) {
      const double a = raw.data[y * raw.cols + x], b = raw.data[y * raw.cols + x + 1], c = raw.data[(y + 1) * raw.cols + x],
                   d = raw.data[(y + 1) * raw.cols + x + 1];
      d_anti += std::fabs(b - c);
      d_diag += std::fabs(a - d);
      level += std::fabs(a) + std::fabs(b) + std::fabs(c) + std::fabs(d);
      ++n;
    }
  if (n == 0 || !(level > 0)) return;  // a dark capture shows nothing
  level /= 4 * double(n);
  d_anti /= double(n);
  d_diag /= double(n);
  // Green on the anti-diagonal (0,1),(1,0) for RGGB and BGGR; on the diagonal for GRBG and GBRG.
  const bool anti = cfa == Cfa::RGGB || cfa == Cfa::BGGR;
  const double d_cfg = anti ? d_anti : d_diag, d_other = anti ? d_diag : d_anti;
  if (d_cfg > 0.02 * level && d_cfg > 3 * d_other)
    throw InputError("file '" + origin + "': its 2 x 2 mosaic statistics contradict the configured cfa \"" + to_string(cfa) +
                     "\": the two green sites of that layout differ by " + to_str(100 * d_cfg / level) +
                     " % of the mean level on average, the other diagonal pair by " + to_str(100 * d_other / level) +
                     " %; the capture fits " + (anti ? "grbg or gbrg" : "rggb or bggr") + " (check the configuration's cfa, or a crop of the raw frame by one pixel)");
}

namespace {

struct Pt {
  double x, y;
};

// The convex hull (Andrew's monotone chain), counter-clockwise, without repeated points.
std::vector<Pt> convex_hull(std::vector<Pt> p) {
  std::sort(p.begin(), p.end(), [](const Pt& a, const Pt& b) { return a.x < b.x || (a.x == b.x && a.y < b.y); });
  if (p.size() < 3) return p;
  const auto cross = [](const Pt& o, const Pt& a, const Pt& b) { return (a.x - o.x) * (b.y - o.y) - (a.y - o.y) * (b.x - o.x); };
  std::vector<Pt> h(2 * p.size());
  std::size_t k = 0;
  for (std::size_t i = 0; i < p.size(); ++i) {
    while (k >= 2 && cross(h[k - 2], h[k - 1], p[i]) <= 0) --k;
    h[k++] = p[i];
  }
  for (std::size_t i = p.size() - 1, t = k + 1; i-- > 0;) {
    while (k >= t && cross(h[k - 2], h[k - 1], p[i]) <= 0) --k;
    h[k++] = p[i];
  }
  h.resize(k - 1);
  return h;
}

// How far q lies outside the convex polygon h (counter-clockwise): 0 inside, else the distance to
// the nearest edge (a point or segment hull: the distance to it).
double outside(const std::vector<Pt>& h, const Pt& q) {
  const auto seg = [](const Pt& a, const Pt& b, const Pt& p) {
    const double dx = b.x - a.x, dy = b.y - a.y, l2 = dx * dx + dy * dy;
    const double t = l2 > 0 ? std::clamp(((p.x - a.x) * dx + (p.y - a.y) * dy) / l2, 0.0, 1.0) : 0.0;
    return std::hypot(p.x - a.x - t * dx, p.y - a.y - t * dy);
  };
  if (h.size() == 1) return std::hypot(q.x - h[0].x, q.y - h[0].y);
  bool in = h.size() >= 3;
  double d = 1e300;
  for (std::size_t i = 0; i < h.size(); ++i) {
    const Pt& a = h[i];
    const Pt& b = h[(i + 1) % h.size()];
    if ((b.x - a.x) * (q.y - a.y) - (b.y - a.y) * (q.x - a.x) < 0) in = false;
    d = std::min(d, seg(a, b, q));
  }
  return in ? 0.0 : d;
}

Cfa swap_red_blue(Cfa c) {
  switch (c) {
    case Cfa::RGGB: return Cfa::BGGR;
    case Cfa::BGGR: return Cfa::RGGB;
    case Cfa::GRBG: return Cfa::GBRG;
    case Cfa::GBRG: return Cfa::GRBG;
    default: return c;
  }
}

}  // namespace

void check_mosaic_colours(const RealStack& raw, Cfa cfa, const Eigen::MatrixXd& srf, const std::string& origin) {
  if (cfa == Cfa::None || raw.rows < 2 || raw.cols < 2 || srf.rows() != 3) return;
  std::vector<Pt> cols;
  for (long b = 0; b < srf.cols(); ++b) {
    const double sum = srf(0, b) + srf(1, b) + srf(2, b);
    if (sum > 0) cols.push_back({srf(0, b) / sum, srf(2, b) / sum});
  }
  if (cols.empty()) return;
  const std::vector<Pt> hull = convex_hull(cols);
  // Per 2 x 2 cell: its (R, G, B) under a layout (G the mean of the two green sites).
  const std::size_t ch = raw.rows / 2, cw = raw.cols / 2;
  std::vector<double> sums;
  sums.reserve(ch * cw);
  auto cell = [&](Cfa c, std::size_t cy, std::size_t cx) {
    double v[3] = {0, 0, 0}, n[3] = {0, 0, 0};
    for (std::size_t dy = 0; dy < 2; ++dy)
      for (std::size_t dx = 0; dx < 2; ++dx) {
        const std::size_t y = 2 * cy + dy, x = 2 * cx + dx;
        const int k = cfa_channel(c, y, x);
        v[k] += raw.data[y * raw.cols + x];
        n[k] += 1;
      }
    return std::array<double, 3>{v[0] / n[0], v[1] / n[1], v[2] / n[2]};
  };
  for (std::size_t cy = 0; cy < ch; ++cy)
    for (std::size_t cx = 0; cx < cw; ++cx) {
      const auto c = cell(cfa, cy, cx);
      sums.push_back(c[0] + c[1] + c[2]);
    }
  if (sums.empty()) return;
  std::vector<double> sorted = sums;
  std::nth_element(sorted.begin(), sorted.begin() + long(sorted.size() / 2), sorted.end());
  const double median = sorted[sorted.size() / 2];
  auto fraction_outside = [&](Cfa c) {
    std::size_t bright = 0, out = 0;
    for (std::size_t cy = 0; cy < ch; ++cy)
      for (std::size_t cx = 0; cx < cw; ++cx) {
        const double sum = sums[cy * cw + cx];
        if (!(sum > 0) || sum < median) continue;
        const auto v = cell(c, cy, cx);
        ++bright;
        out += outside(hull, Pt{std::max(v[0], 0.0) / sum, std::max(v[2], 0.0) / sum}) > 0.02;
      }
    return bright ? double(out) / double(bright) : 0.0;
  };
  const Cfa swapped = swap_red_blue(cfa);
  const double f_cfg = fraction_outside(cfa), f_swap = fraction_outside(swapped);
  if (f_cfg > 0.2 && f_cfg > 4 * f_swap)
    throw InputError("file '" + origin + "': read as \"" + to_string(cfa) + "\", " + to_str(100 * f_cfg) +
                     " % of its bright 2 x 2 cells have colours the camera's responses cannot produce (with red and blue swapped, \"" +
                     to_string(swapped) + "\": " + to_str(100 * f_swap) +
                     " %); check the configuration's cfa, or a crop of the raw frame by one row and one column");
}

RealStack capture_signal(const SystemConfig& cfg, const CaptureFiles& f) {
  const double span = cfg.gain * (f.white_dn - cfg.black_level_dn);
  if (!(span > 0)) reject("gain", cfg.gain, "> 0 with a white level above the black level");
  RealStack v = f.mean_dn;
  for (std::size_t i = 0; i < v.data.size(); ++i)
    v.data[i] = (v.data[i] - (f.dark_dn.data.empty() ? cfg.black_level_dn : f.dark_dn.data[i])) / span;
  return v;
}

PreparedCapture prepare_capture(Runtime& rt, Precision p, const SystemConfig& cfg, const CaptureOptions& o, const CaptureFiles& f) {
  PreparedCapture r;
  const auto t0 = std::chrono::steady_clock::now();
  RealStack v = capture_signal(cfg, f);
  r.seconds_dark = seconds_since(t0);
  const auto t1 = std::chrono::steady_clock::now();
  RealStack rgb;
  if (cfg.cfa != Cfa::None) {
    check_mosaic_phase(v, cfg.cfa, o.captures.front());
    check_mosaic_colours(v, cfg.cfa, sensor_response(cfg), o.captures.front());
    if (v.rows < 3 || v.cols < 3) reject("capture size", shape(v), "at least 3 x 3 for the demosaic");
    DemosaicStage stage(rt, cfg.cfa, demosaic_method_from_string(o.demosaic, "--demosaic"), p);
    rgb = stage.run(std::vector<RealStack>{v}).front();
  } else {
    rgb = std::move(v);
  }
  r.seconds_demosaic = seconds_since(t1);
  if (o.crop) {
    if (o.crop_rows == 0 || o.crop_cols == 0 || o.crop_row + o.crop_rows > rgb.rows || o.crop_col + o.crop_cols > rgb.cols)
      reject("--crop", to_str(o.crop_row) + "," + to_str(o.crop_col) + "," + to_str(o.crop_rows) + "," + to_str(o.crop_cols),
             "ROW,COL,H,W inside the " + to_str(rgb.rows) + " x " + to_str(rgb.cols) + " frame, H, W >= 1");
    RealStack c(3, o.crop_rows, o.crop_cols);
    for (std::size_t ch = 0; ch < 3; ++ch)
      for (std::size_t y = 0; y < o.crop_rows; ++y)
        for (std::size_t x = 0; x < o.crop_cols; ++x) c(ch, y, x) = rgb(ch, o.crop_row + y, o.crop_col + x);
    rgb = std::move(c);
  }
  if (o.exposure.kind == ExposureRule::Kind::Scale) r.exposure_factor = o.exposure.scale;
  if (o.exposure.kind == ExposureRule::Kind::Percentile) {
    std::vector<double> s = rgb.data;
    const std::size_t k = std::min(s.size() - 1, std::size_t(std::ceil(o.exposure.percentile / 100 * double(s.size()))) - (o.exposure.percentile > 0 ? 1 : 0));
    std::nth_element(s.begin(), s.begin() + std::ptrdiff_t(k), s.end());
    if (!(s[k] > 0))
      reject("--exposure", o.exposure.to_string(),
             "a percentile the capture holds signal at (its " + to_str(o.exposure.percentile) + "th percentile is " + to_str(s[k]) +
                 " after the dark: a dark or empty capture)");
    r.exposure_factor = o.exposure.level / s[k];
  }
  if (r.exposure_factor != 1)
    for (double& x : rgb.data) x *= r.exposure_factor;
  r.rgb = std::move(rgb);
  return r;
}

// ---------------------------------------------------------------------------------------------
// Tiles.

std::vector<std::size_t> tile_starts(std::size_t size, std::size_t tile, std::size_t overlap) {
  if (tile == 0 || size < tile)
    reject("image size", size, "at least the decoder's tile of " + to_str(tile) + " px (the grid it was trained on) on each side");
  if (overlap >= tile) reject("--overlap", overlap, "below the tile size " + to_str(tile) + " px");
  std::vector<std::size_t> s;
  const std::size_t stride = tile - overlap;
  for (std::size_t a = 0;; a += stride) {
    if (a + tile >= size) {
      s.push_back(size - tile);
      break;
    }
    s.push_back(a);
  }
  return s;
}

std::vector<std::vector<double>> tile_weights(const std::vector<std::size_t>& starts, std::size_t tile, std::size_t size) {
  const double pi = 3.14159265358979323846;
  std::vector<std::vector<double>> w(starts.size(), std::vector<double>(tile, 1.0));
  for (std::size_t k = 0; k < starts.size(); ++k) {
    // The overlap with the previous and the next tile; a ramp sin²(π/2 (t + 1/2) / L) across it.
    const std::size_t left = k > 0 && starts[k - 1] + tile > starts[k] ? starts[k - 1] + tile - starts[k] : 0;
    const std::size_t right = k + 1 < starts.size() && starts[k] + tile > starts[k + 1] ? starts[k] + tile - starts[k + 1] : 0;
    for (std::size_t t = 0; t < tile; ++t) {
      if (left > 0 && t < left) w[k][t] *= std::pow(std::sin(pi / 2 * (double(t) + 0.5) / double(left)), 2);
      if (right > 0 && tile - 1 - t < right) w[k][t] *= std::pow(std::sin(pi / 2 * (double(tile - 1 - t) + 0.5) / double(right)), 2);
    }
  }
  std::vector<double> sum(size, 0.0);
  for (std::size_t k = 0; k < starts.size(); ++k)
    for (std::size_t t = 0; t < tile; ++t) sum[starts[k] + t] += w[k][t];
  for (std::size_t k = 0; k < starts.size(); ++k)
    for (std::size_t t = 0; t < tile; ++t) w[k][t] /= sum[starts[k] + t];
  return w;
}

TileBoundary tile_boundary_from_string(const std::string& s, const std::string& argument) {
  if (s == "circular") return TileBoundary::Circular;
  if (s == "mirror") return TileBoundary::Mirror;
  reject(argument, s, "circular or mirror");
}

std::string to_string(TileBoundary b) { return b == TileBoundary::Mirror ? "mirror" : "circular"; }

wiener::SpectralPrior regrid_prior(const wiener::SpectralPrior& p, std::size_t rows, std::size_t cols) {
  p.validate();
  wiener::SpectralPrior q = p;
  q.rows = rows;
  q.cols = cols;
  const double scale = double(rows * cols) / double(p.rows * p.cols);
  for (std::size_t i = 0; i < p.bands * p.bands; ++i) q.cov[i] *= scale;  // bin 0 = DC
  q.validate();
  return q;
}

RealStack decode_tiled(const Decoder& dec, const RealStack& y, std::size_t tile, std::size_t overlap,
                       const std::function<void(std::size_t, std::size_t)>& progress, TileBoundary boundary) {
  if (y.planes != dec.channels()) reject("sensor image planes", y.planes, "the decoder's " + to_str(dec.channels()) + " channels");
  const bool mirror = boundary == TileBoundary::Mirror;
  // A tile as the decoder takes it: itself, or its whole-sample mirror extension to 2 tile x 2 tile.
  auto input = [&](const RealStack& t) {
    if (!mirror) return t;
    const std::size_t e = 2 * tile;
    RealStack x(t.planes, e, e);
    for (std::size_t ch = 0; ch < t.planes; ++ch)
      for (std::size_t r = 0; r < e; ++r)
        for (std::size_t c = 0; c < e; ++c) x(ch, r, c) = t(ch, r < tile ? r : e - 1 - r, c < tile ? c : e - 1 - c);
    return x;
  };
  auto output = [&](const RealStack& x) {
    if (!mirror) return x;
    RealStack o(x.planes, tile, tile);
    for (std::size_t b = 0; b < x.planes; ++b)
      for (std::size_t r = 0; r < tile; ++r)
        for (std::size_t c = 0; c < tile; ++c) o(b, r, c) = x(b, r, c);
    return o;
  };
  if (y.rows == tile && y.cols == tile) {
    RealStack x = output(dec.decode(input(y)));
    if (progress) progress(1, 1);
    return x;
  }
  const auto rs = tile_starts(y.rows, tile, overlap), cs = tile_starts(y.cols, tile, overlap);
  const auto wr = tile_weights(rs, tile, y.rows), wc = tile_weights(cs, tile, y.cols);
  const std::size_t total = rs.size() * cs.size(), batch = std::max<std::size_t>(1, dec.batch());
  RealStack out(dec.bands(), y.rows, y.cols, 0.0);
  std::vector<std::pair<std::size_t, std::size_t>> pending;
  std::vector<RealStack> ys;
  std::size_t done = 0;
  auto flush = [&] {
    const std::vector<RealStack> xs = dec.decode_batch(ys);
    for (std::size_t k = 0; k < xs.size(); ++k) {
      const auto [i, j] = pending[k];
      const RealStack x = output(xs[k]);
      for (std::size_t b = 0; b < x.planes; ++b)
        for (std::size_t r = 0; r < tile; ++r)
          for (std::size_t c = 0; c < tile; ++c) out(b, rs[i] + r, cs[j] + c) += wr[i][r] * wc[j][c] * x(b, r, c);
    }
    done += xs.size();
    pending.clear();
    ys.clear();
    if (progress) progress(done, total);
  };
  for (std::size_t i = 0; i < rs.size(); ++i)
    for (std::size_t j = 0; j < cs.size(); ++j) {
      RealStack t(y.planes, tile, tile);
      for (std::size_t ch = 0; ch < y.planes; ++ch)
        for (std::size_t r = 0; r < tile; ++r)
          for (std::size_t c = 0; c < tile; ++c) t(ch, r, c) = y(ch, rs[i] + r, cs[j] + c);
      ys.push_back(input(t));
      pending.push_back({i, j});
      if (ys.size() == batch) flush();
    }
  if (!ys.empty()) flush();
  return out;
}

// ---------------------------------------------------------------------------------------------
// Spectra and renders.

std::string SpectrumRegion::label() const {
  return box ? "box " + to_str(row) + "," + to_str(col) + "," + to_str(rows) + "," + to_str(cols) : "point " + to_str(row) + "," + to_str(col);
}

std::vector<SpectrumRegion> parse_regions(const std::string& s, bool boxes, const std::string& argument) {
  std::vector<SpectrumRegion> out;
  if (s.empty()) return out;
  const std::string allowed = boxes ? "ROW,COL,H,W boxes separated by ';' (integers, H, W >= 1)" : "ROW,COL points separated by ';' (integers >= 0)";
  for (const std::string& item : split(s, ';')) {
    const auto f = split(item, ',');
    if (f.size() != (boxes ? 4u : 2u)) reject(argument, item, allowed);
    std::vector<std::size_t> v;
    for (const std::string& x : f) {
      char* end = nullptr;
      const long long n = std::strtoll(x.c_str(), &end, 10);
      if (x.empty() || *end || n < 0 || n > (1LL << 28)) reject(argument, item, allowed);
      v.push_back(std::size_t(n));
    }
    SpectrumRegion r;
    r.row = v[0];
    r.col = v[1];
    r.box = boxes;
    if (boxes) {
      r.rows = v[2];
      r.cols = v[3];
      if (r.rows == 0 || r.cols == 0) reject(argument, item, allowed);
    }
    out.push_back(r);
  }
  return out;
}

std::vector<std::vector<double>> region_spectra(const RealStack& cube, const std::vector<SpectrumRegion>& regions,
                                                const std::string& argument) {
  std::vector<std::vector<double>> out;
  for (const SpectrumRegion& r : regions) {
    if (r.row + r.rows > cube.rows || r.col + r.cols > cube.cols)
      reject(argument, r.label(), "inside the reconstructed " + to_str(cube.rows) + " x " + to_str(cube.cols) + " image (after --crop)");
    std::vector<double> s(cube.planes, 0.0);
    for (std::size_t b = 0; b < cube.planes; ++b) {
      double sum = 0;
      for (std::size_t y = r.row; y < r.row + r.rows; ++y)
        for (std::size_t x = r.col; x < r.col + r.cols; ++x) sum += cube(b, y, x);
      s[b] = sum / double(r.rows * r.cols);
    }
    out.push_back(std::move(s));
  }
  return out;
}

RealStack render_srgb(const RealStack& cube, const std::vector<double>& wl) {
  const CsvTable t = parse_csv(embedded_file("cie1931_cmf_400-700nm_10nm.csv"), "built-in CIE 1931 table");
  const auto xb = interpolate_spectrum(t.column("wavelength_nm"), t.column("xbar"), wl, "CIE 1931");
  const auto yb = interpolate_spectrum(t.column("wavelength_nm"), t.column("ybar"), wl, "CIE 1931");
  const auto zb = interpolate_spectrum(t.column("wavelength_nm"), t.column("zbar"), wl, "CIE 1931");
  double ysum = 0;
  for (double v : yb) ysum += v;
  const double m[3][3] = {{3.2406, -1.5372, -0.4986}, {-0.9689, 1.8758, 0.0415}, {0.0557, -0.2040, 1.0570}};
  RealStack out(3, cube.rows, cube.cols);
  for (std::size_t p = 0; p < cube.plane_size(); ++p) {
    double xyz[3] = {0, 0, 0};
    for (std::size_t b = 0; b < cube.planes; ++b) {
      const double v = cube.plane(b)[p] / ysum;
      xyz[0] += v * xb[b];
      xyz[1] += v * yb[b];
      xyz[2] += v * zb[b];
    }
    for (int c = 0; c < 3; ++c) out.plane(std::size_t(c))[p] = std::max(0.0, m[c][0] * xyz[0] + m[c][1] * xyz[1] + m[c][2] * xyz[2]);
  }
  return out;
}

Map2D read_design_heights_for(const SystemConfig& cfg, const std::string& path, const std::string& argument) {
  if (!fs::is_regular_file(path)) reject(argument, path, "an existing design .h5 file");
  const Design d = read_design(path);
  if (d.height_m.rows != cfg.n || d.height_m.cols != cfg.n)
    reject(argument, path, "a height map of N x N = " + to_str(cfg.n) + " x " + to_str(cfg.n) + " samples, the configuration's (the file has " +
                               to_str(d.height_m.rows) + " x " + to_str(d.height_m.cols) + ")");
  if (std::fabs(d.pitch_m - cfg.pitch_m) > 1e-6 * cfg.pitch_m)
    reject(argument, path, "pitch_m = " + to_str(cfg.pitch_m) + " as configured (the file has " + to_str(d.pitch_m) + ")");
  const double hmax = cfg.h_max_m();
  for (std::size_t i = 0; i < d.height_m.data.size(); ++i) {
    const double h = d.height_m.data[i];
    if (!std::isfinite(h) || h < 0 || h > 2 * hmax)
      reject(argument, path,
             "heights in [0, 2 h_max] = [0, " + to_str(2 * hmax) + "] m for this configuration (the file's /height_m[" +
                 to_str(i / d.height_m.cols) + "][" + to_str(i % d.height_m.cols) + "] = " + to_str(h) + " m)");
  }
  return d.height_m;
}

// ---------------------------------------------------------------------------------------------
// The command.

ReconstructResult reconstruct(Runtime& rt, const ReconstructOptions& o) {
  using clock = std::chrono::steady_clock;
  if (o.out.empty()) reject("--out", "(missing)", "an output folder");
  if (!o.psf_file.empty() && !o.design_file.empty())
    reject("--design", o.design_file, "either --psf or --design, not both (the camera as built is one of them)");
  const RunFolder folder(o.run);
  const DesignRunOptions ro = folder.config("--run");
  const SystemConfig& cfg = ro.cfg;
  const std::size_t s = cfg.sensor_size_px();
  const DecoderEntry entry = decoder_entry(ro.decoder.kind_name());
  // A network is trained for one PSF and cannot be refit: only that one is accepted.
  if (entry.trained) {
    const bool own = o.psf_file == ro.finetune_psf && o.design_file == ro.finetune_design;
    if (!own && (!o.psf_file.empty() || !o.design_file.empty()))
      reject(o.psf_file.empty() ? "--design" : "--psf", o.psf_file.empty() ? o.design_file : o.psf_file,
             "no --psf or --design with this network run (its network was trained for " +
                 (!ro.finetune_psf.empty()      ? "the PSF file " + ro.finetune_psf
                  : !ro.finetune_design.empty() ? "the fitted design " + ro.finetune_design
                                                : std::string("its own design")) +
                 " and cannot be refit in closed form): fine-tune it for the camera as built first, qdo design --mode do-finetune "
                 "--from RUN --psf FILE (or --design FILE), and reconstruct with that run");
  }
  if (entry.trained && o.boundary_set && o.boundary == TileBoundary::Mirror)
    reject("--boundary", "mirror", "circular for this network run (its network was trained on circular " + to_str(s) + " x " + to_str(s) +
                                       " patches)");
  const TileBoundary boundary = entry.trained ? TileBoundary::Circular : o.boundary_set ? o.boundary : TileBoundary::Mirror;
  std::vector<std::pair<std::string, double>> secs;
  // Every input read and checked before any work.
  auto t = clock::now();
  const std::string psf_file = !o.psf_file.empty() ? o.psf_file : o.design_file.empty() ? ro.finetune_psf : "";
  const std::string design_file = !o.design_file.empty() ? o.design_file : o.psf_file.empty() ? ro.finetune_design : "";
  const RealStack psf_from_file = psf_file.empty() ? RealStack() : read_psf_stack_for(cfg, psf_file, "--psf");
  const Map2D heights = !design_file.empty() ? read_design_heights_for(cfg, design_file, "--design") : folder.design().height_m;
  const wiener::SpectralPrior prior = folder.prior(s);
  const CaptureFiles files = read_captures(cfg, o.capture);
  if (o.capture.crop) {
    const std::size_t rows = o.capture.crop_rows, cols = o.capture.crop_cols;
    if (rows < s || cols < s)
      reject("--crop", to_str(o.capture.crop_row) + "," + to_str(o.capture.crop_col) + "," + to_str(rows) + "," + to_str(cols),
             "a crop of at least the decoder's tile, " + to_str(s) + " x " + to_str(s) + " px");
  }
  const std::size_t img_rows = o.capture.crop ? o.capture.crop_rows : files.mean_dn.rows;
  const std::size_t img_cols = o.capture.crop ? o.capture.crop_cols : files.mean_dn.cols;
  if (img_rows < s || img_cols < s)
    throw InputError("file '" + o.capture.captures.front() + "': " + to_str(files.mean_dn.rows) + " x " + to_str(files.mean_dn.cols) +
                     " pixels" + (o.capture.crop ? " (cropped to " + to_str(img_rows) + " x " + to_str(img_cols) + ")" : std::string()) +
                     ", smaller than the decoder's tile of " + to_str(s) + " x " + to_str(s) + " px (the grid it was trained on)");
  const std::size_t overlap = o.overlap_px > 0 ? o.overlap_px : s / 4;
  if (overlap >= s) reject("--overlap", overlap, "below the decoder's tile of " + to_str(s) + " px");
  std::vector<SpectrumRegion> regions = o.regions;
  if (regions.empty()) regions.push_back({img_rows / 2, img_cols / 2, 1, 1, false});
  for (const SpectrumRegion& r : regions)
    if (r.row + r.rows > img_rows || r.col + r.cols > img_cols)
      reject(r.box ? "--boxes" : "--points", r.label(),
             "inside the reconstructed " + to_str(img_rows) + " x " + to_str(img_cols) + " image (after --crop)");
  if (cfg.cfa != Cfa::None) {
    (void)demosaic_method_from_string(o.capture.demosaic, "--demosaic");
    const RealStack signal = capture_signal(cfg, files);
    check_mosaic_phase(signal, cfg.cfa, o.capture.captures.front());
    check_mosaic_colours(signal, cfg.cfa, sensor_response(cfg), o.capture.captures.front());
  }
  secs.push_back({"read", seconds_since(t)});

  make_output_dir(o.out, "--out");
  const PreparedCapture cap = prepare_capture(rt, o.precision, cfg, o.capture, files);
  secs.push_back({"dark", cap.seconds_dark});
  secs.push_back({"demosaic", cap.seconds_demosaic});

  // The PSF the decoder is built for, then the decoder (the registry's, as `qdo eval` builds it).
  t = clock::now();
  ReconstructResult res;
  RealStack psf = psf_from_file;
  if (psf_file.empty()) {
    Simulator sim(rt, cfg, o.precision);
    sim.set_keep_field(false);
    sim.set_heights(heights);
    sim.compute_psf();
    psf = sim.psf_sensor();
  }
  res.psf = !psf_file.empty()      ? "PSF file " + psf_file
            : !design_file.empty() ? "fitted design " + design_file + " (simulated)"
                                   : "the run's design " + folder.design_path() + " (simulated)";
  DecoderInputs in;
  in.spec = ro.decoder;
  in.psf = psf;
  in.srf = sensor_response(cfg);
  in.prior = boundary == TileBoundary::Mirror ? regrid_prior(prior, 2 * s, 2 * s) : prior;
  in.noise_sigma = o.noise_sigma >= 0 ? o.noise_sigma : ro.decoder_noise_sigma;
  const std::string run = o.run;
  in.run_network = [run] { return load_run_network(run); };
  const std::unique_ptr<Decoder> dec = make_decoder(in);
  res.decoder = dec->description().empty() ? "decoder " + ro.decoder.to_string() : dec->description();
  secs.push_back({"psf+decoder", seconds_since(t)});

  t = clock::now();
  const auto rs = tile_starts(cap.rgb.rows, s, overlap), cs = tile_starts(cap.rgb.cols, s, overlap);
  res.tiles = cap.rgb.rows == s && cap.rgb.cols == s ? 1 : rs.size() * cs.size();
  res.tile_px = s;
  const auto t_tiles = clock::now();
  res.cube = decode_tiled(
      *dec, cap.rgb, s, overlap,
      [&](std::size_t done, std::size_t total) {
        if (o.quiet) return;
        const double el = seconds_since(t_tiles);
        std::fprintf(stderr, "[reconstruct] tile %zu/%zu  %.2f s/tile  ETA %.1f s\n", done, total, el / double(done),
                     el / double(done) * double(total - done));
        std::fflush(stderr);
      },
      boundary);
  res.boundary = to_string(boundary);
  for (double& v : res.cube.data) v = std::clamp(v, 0.0, 1.0);
  secs.push_back({"tiles", seconds_since(t)});

  const auto wl = cfg.wavelengths_nm();
  const fs::path dir(o.out);
  std::string caps, darks;
  for (const auto& c : o.capture.captures) caps += (caps.empty() ? "" : ";") + c;
  for (const auto& d : files.darks) darks += (darks.empty() ? "" : ";") + d;
  const std::string crop = o.capture.crop ? to_str(o.capture.crop_row) + "," + to_str(o.capture.crop_col) + "," +
                                                to_str(o.capture.crop_rows) + "," + to_str(o.capture.crop_cols)
                                          : std::string("none");
  t = clock::now();
  h5_write((dir / "cube.h5").string(),
           {{"/cube", {res.cube.planes, res.cube.rows, res.cube.cols}, {}, {}, {{"units", "radiance relative to full scale, clipped to [0, 1]"}},
             false, false, &res.cube.data},
            {"/wavelengths_nm", {wl.size()}, wl, {}, {{"units", "nm"}}}},
           {{"source", "qdo reconstruct"},
            {"run", o.run},
            {"decoder", res.decoder},
            {"psf", res.psf},
            {"captures", caps},
            {"darks", darks.empty() ? std::string("none (black level ") + to_str(cfg.black_level_dn) + " DN)" : darks},
            {"exposure", o.capture.exposure.to_string()},
            {"exposure_factor", to_str(cap.exposure_factor)},
            {"crop", crop},
            {"tiles", to_str(res.tiles) + " of " + to_str(s) + " x " + to_str(s) + " px, overlap " + to_str(overlap) + " px, boundary " +
                          res.boundary}});
  secs.push_back({"write cube", seconds_since(t)});
  t = clock::now();
  write_rgb_png((dir / "srgb.png").string(), render_srgb(res.cube, wl));
  secs.push_back({"srgb", seconds_since(t)});
  t = clock::now();
  const auto spectra = region_spectra(res.cube, regions);
  std::vector<std::string> header = {"wavelength_nm"};
  for (const auto& r : regions) header.push_back(r.label());
  CsvText csv(header);
  for (std::size_t b = 0; b < wl.size(); ++b) {
    std::vector<std::string> row = {csv_number(wl[b])};
    for (const auto& sp : spectra) row.push_back(csv_number(sp[b], 9));
    csv.row(row);
  }
  write_text_atomic((dir / "spectra.csv").string(), csv.str());
  write_line_plot_png((dir / "spectra.png").string(), spectra);
  secs.push_back({"spectra", seconds_since(t)});

  res.exposure_factor = cap.exposure_factor;
  res.notes = files.notes;
  res.seconds = secs;
  nlohmann::json j;
  j["run"] = o.run;
  j["decoder"] = res.decoder;
  j["psf"] = res.psf;
  j["captures"] = o.capture.captures;
  j["darks"] = files.darks;
  j["saturated_values"] = files.saturated;
  j["notes"] = files.notes;
  j["white_level_dn"] = files.white_dn;
  j["exposure"] = o.capture.exposure.to_string();
  j["exposure_factor"] = cap.exposure_factor;
  j["crop"] = crop;
  j["demosaic"] = cfg.cfa == Cfa::None ? std::string("none (RGB captures)") : o.capture.demosaic;
  j["image_rows_cols"] = {res.cube.rows, res.cube.cols};
  j["tiles"] = res.tiles;
  j["tile_px"] = s;
  j["overlap_px"] = overlap;
  j["boundary"] = res.boundary;
  j["noise_sigma"] = in.noise_sigma;
  nlohmann::json st = nlohmann::json::object();
  for (const auto& [k, v] : secs) st[k] = v;
  j["seconds"] = st;
  std::vector<std::string> labels;
  for (const auto& r : regions) labels.push_back(r.label());
  j["regions"] = labels;
  write_text_atomic((dir / "reconstruct.json").string(), j.dump(2) + "\n");
  return res;
}

}  // namespace qdo
