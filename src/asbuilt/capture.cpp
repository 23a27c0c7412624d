// qdo reconstruct's capture stages (reconstruct.hpp, steps 1 to 4): the exposure rule, the
// captures and darks read and checked (sizes, white level, saturated and empty captures), the
// mosaic's phase and colours checked against the configuration, the signal above the dark, the
// development of the capture pipeline (CapturePipeline::develop: the demosaic), the crop and the
// exposure.
#include <algorithm>
#include <array>
#include <chrono>
#include <filesystem>
#include <cmath>
#include <string>
#include <vector>

#include "asbuilt/reconstruct_internal.hpp"
#include "qdo/physics/capture_pipeline.hpp"
#include "qdo/physics/demosaic.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/physics/flat_field.hpp"
#include "qdo/data/io.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/raw_reference.hpp"
#include "qdo/asbuilt/reconstruct.hpp"

namespace qdo {
using namespace reconstruct_detail;

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
  const auto f = split_fields(s, ':');
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

namespace {

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

// The flat field from the white frames (CaptureOptions::white_dir): their mean signal over the
// darks (or the black level), through flat_field (flat_field.hpp). Refused, naming the folder: a
// white with saturated pixels (the field would be clipped), and flat_field's refusals.
void read_flat_field(const SystemConfig& cfg, const std::vector<RealStack>& whites, CaptureFiles& f) {
  const RealStack& first = whites.front();
  RealStack w(first.planes, first.rows, first.cols, 0.0);
  std::size_t saturated = 0;
  for (const RealStack& x : whites)
    for (std::size_t i = 0; i < x.data.size(); ++i) {
      w.data[i] += x.data[i] / double(whites.size());
      if (x.data[i] >= f.white_dn) ++saturated;
    }
  const std::string where = "--white '" + std::filesystem::path(f.whites.front()).parent_path().string() + "'";
  if (saturated > 0)
    throw InputError(where + ": " + to_str(saturated) + " white-frame values at the white level " + to_str(f.white_dn) +
                     " DN: the flat field would be clipped; take the white frames with a shorter exposure");
  for (std::size_t i = 0; i < w.data.size(); ++i) w.data[i] -= f.dark_dn.data.empty() ? cfg.black_level_dn : f.dark_dn.data[i];
  FlatField ff = flat_field(w, cfg.cfa, where);
  f.channel_gains.assign(ff.channel_gains.begin(), ff.channel_gains.end());
  f.flat = std::move(ff.gain);
  f.notes.push_back("flat field from " + to_str(whites.size()) + " white frame(s): channel gains R " + to_str(f.channel_gains[0]) + ", G " +
                    to_str(f.channel_gains[1]) + ", B " + to_str(f.channel_gains[2]) + " of the white's mean, divided out with each pixel's response");
}

}  // namespace

CaptureFiles read_captures(const SystemConfig& cfg, const CaptureOptions& o) {
  if (o.captures.empty()) reject("--capture", "(missing)", "one or more captures of the scene (16-bit PNG or TIFF, or camera raw)");
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
  // A camera raw file's metadata is checked against the configuration; its white level (where the
  // sensor saturates) counts as the white level when it lies below the configuration's.
  auto read = [&](const std::string& path) {
    CaptureMeta meta;
    RealStack img = read_capture16(path, &meta);
    check_camera_raw(meta, to_string(cfg.cfa), cfg.black_level_dn, f.white_dn, path);
    if (meta.camera_raw) f.white_dn = std::min(f.white_dn, meta.raw.white_level_dn);
    return img;
  };
  std::vector<RealStack> caps;
  for (const std::string& path : o.captures) {
    caps.push_back(read(path));
    check(caps.back(), path, caps.size() > 1 ? &caps.front() : nullptr, o.captures.front());
  }
  if (!o.darks_dir.empty()) f.darks = capture_files(o.darks_dir, "--darks");
  std::vector<RealStack> darks;
  for (const std::string& path : f.darks) {
    darks.push_back(read(path));
    check(darks.back(), path, &caps.front(), o.captures.front());
  }
  if (!o.white_dir.empty()) f.whites = capture_files(o.white_dir, "--white");
  std::vector<RealStack> whites;
  for (const std::string& path : f.whites) {
    whites.push_back(read(path));
    check(whites.back(), path, &caps.front(), o.captures.front());
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
  if (!whites.empty()) read_flat_field(cfg, whites, f);
  // The mosaic's phase and colours, once, on the signal, before any work (prepare_capture and
  // reconstruct rely on it).
  if (cfg.cfa != Cfa::None) {
    const RealStack signal = capture_signal(cfg, f);
    check_mosaic_phase(signal, cfg.cfa, o.captures.front());
    check_mosaic_colours(signal, cfg.cfa, sensor_response(cfg), o.captures.front());
  }
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
    v.data[i] = (v.data[i] - (f.dark_dn.data.empty() ? cfg.black_level_dn : f.dark_dn.data[i])) / span /
                (f.flat.data.empty() ? 1.0 : f.flat.data[i]);
  return v;
}

double estimate_demosaic_sigma(Runtime& rt, Precision p, const SystemConfig& cfg, DemosaicMethod method, const RealStack& rgb) {
  if (cfg.cfa == Cfa::None) reject("cfa", to_string(cfg.cfa), "a mosaic (rggb, grbg, gbrg or bggr)");
  if (rgb.planes != 3 || rgb.rows < 5 || rgb.cols < 5)
    reject("demosaiced image", shape(rgb), "3 x H x W with H, W >= 5");
  // The mosaic one column over: every site of the capture's mosaic holds another colour there.
  SystemConfig shifted = cfg;
  shifted.cfa = cfg.cfa == Cfa::RGGB ? Cfa::GRBG : cfg.cfa == Cfa::GRBG ? Cfa::RGGB : cfg.cfa == Cfa::GBRG ? Cfa::BGGR : Cfa::GBRG;
  RealStack mosaic(1, rgb.rows, rgb.cols);
  for (std::size_t y = 0; y < rgb.rows; ++y)
    for (std::size_t x = 0; x < rgb.cols; ++x) mosaic(0, y, x) = rgb(std::size_t(cfa_channel(shifted.cfa, y, x)), y, x);
  PipelineOptions po;
  po.noise = false;
  po.raw = true;
  po.demosaic = method;
  CapturePipeline pipeline(rt, shifted, p, po);
  const RealStack again = pipeline.develop(mosaic).demosaiced;
  // At the sites where the capture measured colour c, rgb holds the measurement and the shifted
  // mosaic interpolates it: the error there is an interpolation error of this demosaic on this
  // image. The first demosaic is exact at its own sites and interpolates the rest (3/4 of the
  // pixels for red and blue, 1/2 for green): sigma^2 = the mean over colours of that share times
  // the colour's mean squared error at its sites (2 px from the edge left out).
  double total = 0;
  for (std::size_t c = 0; c < 3; ++c) {
    double sum = 0;
    std::size_t n = 0, sites = 0, all = 0;
    for (std::size_t y = 2; y + 2 < rgb.rows; ++y)
      for (std::size_t x = 2; x + 2 < rgb.cols; ++x) {
        ++all;
        if (std::size_t(cfa_channel(cfg.cfa, y, x)) != c) continue;
        ++sites;
        const double e = again(c, y, x) - rgb(c, y, x);
        sum += e * e;
        ++n;
      }
    if (n > 0) total += (1 - double(sites) / double(all)) * sum / double(n) / 3;
  }
  return std::sqrt(total);
}

PreparedCapture prepare_capture(Runtime& rt, Precision p, const SystemConfig& cfg, const CaptureOptions& o, const CaptureFiles& f) {
  PreparedCapture r;
  const auto t0 = std::chrono::steady_clock::now();
  RealStack v = capture_signal(cfg, f);
  r.seconds_dark = seconds_since(t0);
  const auto t1 = std::chrono::steady_clock::now();
  RealStack rgb;
  if (cfg.cfa != Cfa::None) {
    if (v.rows < 3 || v.cols < 3) reject("capture size", shape(v), "at least 3 x 3 for the demosaic");
    // Developed as the capture pipeline develops its own raw frames (capture_pipeline.hpp), so
    // the simulated and the measured frame go through the same stages after the sensor.
    PipelineOptions po;
    po.noise = false;
    po.raw = true;
    po.demosaic = demosaic_method_from_string(o.demosaic, "--demosaic");
    CapturePipeline pipeline(rt, cfg, p, po);
    rgb = std::move(pipeline.develop(v).demosaiced);
    r.demosaic_sigma = estimate_demosaic_sigma(rt, p, cfg, po.demosaic, rgb);
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


}  // namespace qdo
