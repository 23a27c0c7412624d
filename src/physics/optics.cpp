#include "qdo/physics/optics.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "qdo/runtime/embedded.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"
#include "qdo/data/materials.hpp"

namespace qdo {

std::size_t fast_fft_size(std::size_t min_len) {
  if (min_len < 1) min_len = 1;
  for (std::size_t m = min_len;; ++m) {
    std::size_t r = m;
    for (std::size_t p : {2, 3, 5, 7})
      while (r % p == 0) r /= p;
    if (r == 1) return m;
  }
}

PropagationGeometry PropagationGeometry::from_config(const SystemConfig& c) {
  PropagationGeometry g;
  g.n = c.n;
  g.m = fast_fft_size(c.n + 2 * c.padding_px);
  // Keep M - N even so the axis stays on a sample in both grids.
  while ((g.m - g.n) % 2) g.m = fast_fft_size(g.m + 1);
  g.offset = (g.m - g.n) / 2;
  g.pitch_m = c.pitch_m;
  return g;
}

double transfer_function_limit_per_m(Propagator p, double wavelength_nm, double z_m, std::size_t m, double pitch_m) {
  const double lambda = wavelength_nm * 1e-9;
  const double window = double(m) * pitch_m;
  const double az = std::fabs(z_m);
  if (p == Propagator::Fresnel) return az > 0 ? window / (2.0 * lambda * az) : INFINITY;
  const double q = 2.0 * az / window;
  return 1.0 / (lambda * std::sqrt(q * q + 1.0));
}

SampledPadding sampled_padding_px(const SystemConfig& cfg, double z_m) {
  const std::vector<double> wl = cfg.wavelengths_nm();
  const double nyquist = 0.5 / cfg.pitch_m;
  SystemConfig c = cfg;
  for (std::size_t p = 0; p <= 4 * cfg.n; ++p) {
    c.padding_px = p;
    const std::size_t m = PropagationGeometry::from_config(c).m;
    bool ok = true;
    for (double w : wl) ok = ok && transfer_function_limit_per_m(cfg.propagator, w, z_m, m, cfg.pitch_m) >= nyquist;
    if (ok) return {p, true};
  }
  return {4 * cfg.n, false};
}

void check_source_sampling(const SystemConfig& cfg, std::vector<BandSampling>& bands) {
  const double r = cfg.aperture_radius(), d = cfg.scene_distance_m;
  if (cfg.object_points.empty()) {
    for (auto& b : bands) {
      b.source_frequency_per_m =
          cfg.scene_at_infinity ? 0.0 : r / (b.wavelength_nm * 1e-9 * std::sqrt(r * r + d * d));
      b.source_undersampled = b.source_frequency_per_m > 0.5 / cfg.pitch_m;
    }
    return;
  }
  // Object points: planes are (designs x) points x bands; plane i is point (i / bands) % points.
  const std::vector<ObjectPoint> pts = cfg.points();
  for (std::size_t i = 0; i < bands.size(); ++i) {
    BandSampling& b = bands[i];
    const std::size_t p = (i / cfg.bands) % pts.size();
    b.point = static_cast<int>(p);
    b.point_distance_m = pts[p].distance_m;
    b.field_x_deg = pts[p].field_x_deg;
    b.field_y_deg = pts[p].field_y_deg;
    const auto img = chief_ray_image_m(cfg, pts[p]);
    b.chief_ray_x_m = img.first;
    b.chief_ray_y_m = img.second;
    const ObjectPoint& pt = pts[p];
    b.source_frequency_per_m = pt.on_axis() && pt.at_infinity() ? 0.0
                               : pt.on_axis() ? r / (b.wavelength_nm * 1e-9 * std::sqrt(r * r + pt.distance_m * pt.distance_m))
                                              : object_point_frequency_per_m(cfg, pt, b.wavelength_nm);
    b.source_undersampled = b.source_frequency_per_m > 0.5 / cfg.pitch_m;
  }
}

bool SamplingReport::any_inaccurate() const {
  for (const auto& b : bands)
    if ((b.undersampled && b.aliased_energy_fraction > kAliasTolerance) || b.source_undersampled) return true;
  return false;
}

double SamplingReport::worst_aliased_fraction() const {
  double w = 0;
  for (const auto& b : bands) w = std::max(w, b.aliased_energy_fraction);
  return w;
}

double SamplingReport::worst_energy_outside() const {
  double w = 0;
  for (const auto& b : bands) w = std::max(w, b.energy_outside_window);
  return w;
}

std::string SamplingReport::summary() const {
  std::ostringstream os;
  os.precision(3);
  std::size_t under = 0;
  for (const auto& b : bands) under += b.undersampled;
  os << "sampling: transfer function under-sampled in " << under << " of " << bands.size() << " bands";
  if (under) {
    const auto& b = bands.back();
    os << " (at " << b.wavelength_nm << " nm it is reliable only up to |f| = " << b.f_limit_per_m
       << " 1/m of the grid's " << b.f_nyquist_per_m << " 1/m)";
  }
  os << "; worst field energy beyond the limit " << worst_aliased_fraction()
     << "; worst energy outside the N x N window " << worst_energy_outside() << ".";
  std::size_t src = 0;
  for (const auto& b : bands) src += b.source_undersampled;
  if (src) os << " The point source's spherical wave is under-sampled on the DOE grid in " << src
              << " bands (increase scene_distance_m or use a finer pitch_m).";
  if (any_inaccurate()) os << " INACCURATE: increase padding_px, reduce sensor_distance_m or pitch_m.";
  // Object points: one line per point (its planes follow each other, bands of one point).
  for (std::size_t i = 0; i < bands.size(); ++i) {
    const auto& b = bands[i];
    if (b.point < 0 || (i > 0 && bands[i - 1].point == b.point)) continue;
    double worst_f = 0, worst_out = 0, worst_beyond = 0, nyq = b.f_nyquist_per_m;
    bool aliases = false;
    for (std::size_t j = i; j < bands.size() && bands[j].point == b.point; ++j) {
      worst_f = std::max(worst_f, bands[j].source_frequency_per_m);
      worst_beyond = std::max(worst_beyond, bands[j].aliased_energy_fraction);
      worst_out = std::max(worst_out, bands[j].energy_outside_window);
      aliases = aliases || bands[j].source_undersampled;
    }
    os << "\n  object point " << b.point << " (d = " << b.point_distance_m << " m, field (" << b.field_x_deg << ", "
       << b.field_y_deg << ") deg): chief ray at (" << b.chief_ray_x_m * 1e3 << ", " << b.chief_ray_y_m * 1e3
       << ") mm on the sensor; source local frequency up to " << worst_f << " 1/m of the grid's Nyquist " << nyq
       << " 1/m" << (aliases ? " (ALIASES)" : "") << "; field energy beyond the transfer function's limit up to "
       << worst_beyond << "; energy outside the N x N window up to " << worst_out << ".";
  }
  return os.str();
}

void SamplingReport::enforce() const {
  for (const auto& b : bands) {
    if (b.source_undersampled) {
      std::ostringstream os;
      os << "strict_sampling: at " << b.wavelength_nm << " nm the point source's spherical wave reaches a local frequency of "
         << b.source_frequency_per_m << " 1/m at the aperture rim, above the DOE grid's Nyquist " << b.f_nyquist_per_m
         << " 1/m; the field after the DOE aliases. Increase scene_distance_m or use a finer pitch_m";
      throw AccuracyError(os.str());
    }
    if (b.undersampled && b.aliased_energy_fraction > kAliasTolerance) {
      std::ostringstream os;
      os << "strict_sampling: at " << b.wavelength_nm << " nm the transfer function is under-sampled beyond |f| = "
         << b.f_limit_per_m << " 1/m (grid Nyquist " << b.f_nyquist_per_m << " 1/m) and "
         << b.aliased_energy_fraction << " of the field energy lies there (allowed " << kAliasTolerance
         << "); increase padding_px or reduce sensor_distance_m";
      throw AccuracyError(os.str());
    }
  }
}

AreaWeights AreaWeights::make(std::size_t n, double pitch_in_m, std::size_t s, double pitch_out_m, double shift_out_px) {
  if (!(pitch_out_m > 0) || !(pitch_in_m > 0)) reject("sensor_pitch_m", pitch_out_m, "> 0");
  if (!std::isfinite(shift_out_px)) reject("shift_out_px", shift_out_px, "a finite number of output pixels");
  AreaWeights a;
  a.n = n;
  a.s = s;
  a.taps = static_cast<std::size_t>(std::ceil(pitch_out_m / pitch_in_m)) + 1;
  a.start.assign(s, 0);
  a.w.assign(s * a.taps, 0.0);
  for (std::size_t o = 0; o < s; ++o) {
    // Output pixel edges in units of input cells, measured from input cell 0's left edge.
    const double lo = ((double(o) - shift_out_px - double(s / 2) - 0.5) * pitch_out_m) / pitch_in_m + double(n / 2) + 0.5;
    const double hi = lo + pitch_out_m / pitch_in_m;
    const long first = static_cast<long>(std::floor(lo));
    a.start[o] = static_cast<int>(first);
    for (std::size_t t = 0; t < a.taps; ++t) {
      const long i = first + static_cast<long>(t);
      if (i < 0 || i >= static_cast<long>(n)) continue;
      const double ov = std::min(hi, double(i + 1)) - std::max(lo, double(i));
      if (ov > 0) a.w[o * a.taps + t] = ov;
    }
  }
  return a;
}

AreaWeights AreaWeights::make_xy(std::size_t n, double pitch_in_m, std::size_t s, double pitch_out_m, double shift_x_px,
                                 double shift_y_px) {
  AreaWeights a = make(n, pitch_in_m, s, pitch_out_m, shift_y_px);
  if (shift_x_px == shift_y_px) return a;
  const AreaWeights c = make(n, pitch_in_m, s, pitch_out_m, shift_x_px);  // the same taps: they depend on the pitches only
  a.col_offset = s;
  a.start.insert(a.start.end(), c.start.begin(), c.start.end());
  a.w.insert(a.w.end(), c.w.begin(), c.w.end());
  return a;
}

AreaWeights sensor_weights(const SystemConfig& cfg, double extra_x_px, double extra_y_px) {
  return AreaWeights::make_xy(cfg.n, cfg.pitch_m, cfg.sensor_size_px(), cfg.sensor_pitch_m,
                              extra_x_px - cfg.aperture_offset_x_m / cfg.sensor_pitch_m,
                              extra_y_px - cfg.aperture_offset_y_m / cfg.sensor_pitch_m);
}

namespace {

// The transpose of one axis's table: entries [first, first + s) of a.
AreaWeights transpose_axis(const AreaWeights& a, std::size_t first) {
  AreaWeights one;
  one.n = a.n;
  one.s = a.s;
  one.taps = a.taps;
  one.start.assign(a.start.begin() + std::ptrdiff_t(first), a.start.begin() + std::ptrdiff_t(first + a.s));
  one.w.assign(a.w.begin() + std::ptrdiff_t(first * a.taps), a.w.begin() + std::ptrdiff_t((first + a.s) * a.taps));
  return one.transposed();
}

}  // namespace

AreaWeights AreaWeights::transposed() const {
  if (col_offset != 0) {
    AreaWeights r = transpose_axis(*this, 0), c = transpose_axis(*this, col_offset);
    const std::size_t taps_ = std::max(r.taps, c.taps);
    AreaWeights t;
    t.n = s;
    t.s = n;
    t.taps = taps_;
    t.col_offset = n;
    t.start = r.start;
    t.start.insert(t.start.end(), c.start.begin(), c.start.end());
    t.w.assign(2 * n * taps_, 0.0);
    for (std::size_t i = 0; i < n; ++i) {
      for (std::size_t k = 0; k < r.taps; ++k) t.w[i * taps_ + k] = r.w[i * r.taps + k];
      for (std::size_t k = 0; k < c.taps; ++k) t.w[(n + i) * taps_ + k] = c.w[i * c.taps + k];
    }
    return t;
  }
  AreaWeights t;
  t.n = s;
  t.s = n;
  std::vector<std::vector<std::pair<int, double>>> cols(n);
  for (std::size_t o = 0; o < s; ++o)
    for (std::size_t k = 0; k < taps; ++k) {
      const double v = w[o * taps + k];
      const long i = start[o] + static_cast<long>(k);
      if (v != 0 && i >= 0 && i < static_cast<long>(n)) cols[static_cast<std::size_t>(i)].push_back({int(o), v});
    }
  t.taps = 1;
  for (const auto& c : cols)
    if (!c.empty()) t.taps = std::max<std::size_t>(t.taps, static_cast<std::size_t>(c.back().first - c.front().first + 1));
  t.start.assign(n, 0);
  t.w.assign(n * t.taps, 0.0);
  for (std::size_t i = 0; i < n; ++i) {
    if (cols[i].empty()) continue;
    t.start[i] = cols[i].front().first;
    for (const auto& ov : cols[i]) t.w[i * t.taps + static_cast<std::size_t>(ov.first - t.start[i])] = ov.second;
  }
  return t;
}

double circle_rectangle_area(double r, double x0, double x1, double y0, double y1) {
  x0 = std::max(x0, -r);
  x1 = std::min(x1, r);
  if (!(x1 > x0) || !(y1 > y0) || !(r > 0)) return 0.0;
  // Area = integral over x of |[y0, y1] ∩ [-c(x), c(x)]|, c = sqrt(r² - x²). Between the breakpoints
  // (where c crosses |y0| or |y1|) each bound is one of y0, y1, ±c, with the integral of c in closed
  // form: C(x) = (x c(x) + r² asin(x / r)) / 2.
  const auto chord = [r](double x) { return std::sqrt(std::max(0.0, r * r - x * x)); };
  const auto prim = [r, &chord](double x) { return 0.5 * (x * chord(x) + r * r * std::asin(std::clamp(x / r, -1.0, 1.0))); };
  std::vector<double> xs = {x0, x1};
  for (double y : {y0, y1})
    if (std::fabs(y) < r) {
      const double b = std::sqrt(r * r - y * y);
      for (double x : {-b, b})
        if (x > x0 && x < x1) xs.push_back(x);
    }
  std::sort(xs.begin(), xs.end());
  double area = 0;
  for (std::size_t k = 0; k + 1 < xs.size(); ++k) {
    const double a = xs[k], b = xs[k + 1];
    if (!(b > a)) continue;
    const double c = chord(0.5 * (a + b));
    // Which bound is the circle's at the middle (a tie there is a tangent: the circle's bound holds
    // on the whole piece).
    const bool top_c = c <= y1, bottom_c = -c >= y0;
    const double top = top_c ? c : y1, bottom = bottom_c ? -c : y0;
    if (!(top > bottom)) continue;
    const double ic = prim(b) - prim(a);  // integral of c over [a, b]
    area += (top_c ? ic : y1 * (b - a)) - (bottom_c ? -ic : y0 * (b - a));
  }
  return area;
}

std::vector<double> aperture_transmission(const SystemConfig& cfg) {
  const std::size_t n = cfg.n;
  std::vector<double> t(n * n, 0.0);
  const double half = double(n / 2);
  if (cfg.aperture_edge != ApertureEdge::Area) {
    const double r2 = cfg.aperture_inside_px2();
    for (std::size_t i = 0; i < n; ++i)
      for (std::size_t j = 0; j < n; ++j) {
        const double di = double(i) - half, dj = double(j) - half;
        t[i * n + j] = di * di + dj * dj <= r2 ? 1.0 : 0.0;
      }
    return t;
  }
  // In pixel units about the circle's centre.
  const double r = cfg.aperture_radius() / cfg.pitch_m, cx = cfg.aperture_offset_x_m / cfg.pitch_m,
               cy = cfg.aperture_offset_y_m / cfg.pitch_m;
  for (std::size_t i = 0; i < n; ++i) {
    const double y = double(i) - half - cy;
    if (y - 0.5 >= r || y + 0.5 <= -r) continue;
    for (std::size_t j = 0; j < n; ++j) {
      const double x = double(j) - half - cx;
      if (x - 0.5 >= r || x + 0.5 <= -r) continue;
      // Whole cells inside (every corner within r) are exactly 1.
      const double fx = std::fabs(x) + 0.5, fy = std::fabs(y) + 0.5;
      t[i * n + j] = fx * fx + fy * fy <= r * r ? 1.0 : circle_rectangle_area(r, x - 0.5, x + 0.5, y - 0.5, y + 0.5);
    }
  }
  return t;
}

namespace {

// The whole pixels of a relief move and the axis offset that carries the rest (move_relief).
struct ReliefSplit {
  long kx = 0, ky = 0;
  double axis_x_m = 0, axis_y_m = 0;
  ReliefSplit(const SystemConfig& cfg, double dx_m, double dy_m) {
    const double tx = (dx_m - cfg.aperture_offset_x_m) / cfg.pitch_m, ty = (dy_m - cfg.aperture_offset_y_m) / cfg.pitch_m;
    kx = long(std::lround(tx));
    ky = long(std::lround(ty));
    axis_x_m = -(tx - double(kx)) * cfg.pitch_m;
    axis_y_m = -(ty - double(ky)) * cfg.pitch_m;
  }
};

// out(i, j) = in(i - ky, j - kx), zero from outside; sign -1 gives the transpose.
Map2D roll_zero(const Map2D& in, long kx, long ky) {
  Map2D out(in.rows, in.cols);
  const long r = long(in.rows), c = long(in.cols);
  for (long i = 0; i < r; ++i) {
    const long si = i - ky;
    if (si < 0 || si >= r) continue;
    for (long j = 0; j < c; ++j) {
      const long sj = j - kx;
      if (sj >= 0 && sj < c) out(std::size_t(i), std::size_t(j)) = in(std::size_t(si), std::size_t(sj));
    }
  }
  return out;
}

}  // namespace

SystemConfig move_relief(const SystemConfig& cfg, Map2D& height_m, double dx_m, double dy_m, bool area_edge) {
  if (height_m.rows != cfg.n || height_m.cols != cfg.n)
    reject("height_m", to_str(height_m.rows) + " x " + to_str(height_m.cols), "an N x N map with N = " + to_str(cfg.n));
  SystemConfig c = moved_relief_config(cfg, dx_m, dy_m, area_edge);
  const ReliefSplit sp(cfg, dx_m, dy_m);
  if (sp.kx != 0 || sp.ky != 0) height_m = roll_zero(height_m, sp.kx, sp.ky);
  return c;
}

SystemConfig moved_relief_config(const SystemConfig& cfg, double dx_m, double dy_m, bool area_edge) {
  for (const auto& [key, v] : {std::pair<const char*, double>{"dx_m", dx_m}, {"dy_m", dy_m}})
    if (!std::isfinite(v) || std::fabs(v) > double(cfg.n) * cfg.pitch_m)
      reject(key, v, "a finite move of at most the DOE grid's width (metres)");
  const ReliefSplit sp(cfg, dx_m, dy_m);
  SystemConfig c = cfg;
  c.aperture_offset_x_m = sp.axis_x_m;
  c.aperture_offset_y_m = sp.axis_y_m;
  if (area_edge || c.aperture_offset()) c.aperture_edge = ApertureEdge::Area;
  c.validate();
  return c;
}

Map2D move_relief_adjoint(const SystemConfig& cfg, const Map2D& g_moved, double dx_m, double dy_m) {
  const ReliefSplit sp(cfg, dx_m, dy_m);
  return roll_zero(g_moved, -sp.kx, -sp.ky);
}

std::vector<std::string> builtin_cameras() { return {"FLIR_GS3-U3-41S4C"}; }

Eigen::MatrixXd sensor_response(const SystemConfig& cfg) {
  CsvTable t;
  std::string origin = cfg.camera;
  if (cfg.camera == "FLIR_GS3-U3-41S4C") {
    t = parse_csv(embedded_file("srf_FLIR_GS3-U3-41S4C.csv"), "built-in camera FLIR_GS3-U3-41S4C");
  } else if (cfg.camera.find('/') != std::string::npos || cfg.camera.find(".csv") != std::string::npos) {
    t = read_csv(cfg.camera);
  } else {
    std::string names;
    for (const auto& c : builtin_cameras()) names += c + " ";
    reject("camera", cfg.camera, "a built-in camera (" + names + ") or the path of a CSV file with columns wavelength_nm,R,G,B");
  }
  const auto& wl = t.column("wavelength_nm");
  for (std::size_t r = 0; r < wl.size(); ++r)
    if (!std::isfinite(wl[r]) || (r > 0 && !(wl[r] > wl[r - 1])))
      reject("camera", origin, "a wavelength_nm column that is strictly increasing (row " + to_str(r + 1) + " holds " +
                                   to_str(wl[r]) + " nm)");
  const std::vector<const std::vector<double>*> ch = {&t.column("R"), &t.column("G"), &t.column("B")};
  const auto bands = cfg.wavelengths_nm();
  Eigen::MatrixXd s(3, static_cast<Eigen::Index>(bands.size()));
  for (std::size_t b = 0; b < bands.size(); ++b) {
    const double w = bands[b];
    std::size_t exact = wl.size();
    for (std::size_t r = 0; r < wl.size(); ++r)
      if (std::fabs(wl[r] - w) < 1e-6) exact = r;
    for (int c = 0; c < 3; ++c) {
      double v = 0;
      if (exact < wl.size()) {
        v = (*ch[c])[exact];
      } else if (cfg.srf_interpolate) {
        std::size_t r = 1;
        while (r < wl.size() && wl[r] < w) ++r;
        if (wl.empty() || w < wl.front() || w > wl.back() || r >= wl.size())
          reject("camera", origin, "a response covering " + to_str(w) + " nm (the table spans " +
                                       to_str(wl.empty() ? 0 : wl.front()) + " to " + to_str(wl.empty() ? 0 : wl.back()) + " nm)");
        const double f = (w - wl[r - 1]) / (wl[r] - wl[r - 1]);
        v = (1 - f) * (*ch[c])[r - 1] + f * (*ch[c])[r];
      } else {
        reject("camera", origin, "a response sampled at every band of the configuration; it has no sample at " +
                                     to_str(w) + " nm (set srf_interpolate to allow linear interpolation)");
      }
      if (!std::isfinite(v) || v < 0) reject("camera", origin, "finite non-negative responses (at " + to_str(w) + " nm)");
      s(c, static_cast<Eigen::Index>(b)) = v;
    }
  }
  for (int c = 0; c < 3; ++c) {
    const double sum = s.row(c).sum();
    if (!(sum > 0)) reject("camera", origin, "a response with a positive sum in every channel over the bands");
    s.row(c) /= sum;
  }
  return s;
}

std::vector<double> delta_n_per_band(const SystemConfig& cfg) {
  const Material& m = material_by_name(cfg.material);
  std::vector<double> out;
  for (double w : cfg.wavelengths_nm()) out.push_back(m.index(w, "wavelengths") - 1.0);
  return out;
}

std::vector<double> wavenumber_per_band(const SystemConfig& cfg) {
  std::vector<double> out;
  for (double w : cfg.wavelengths_nm()) out.push_back(2.0 * M_PI / (w * 1e-9));
  return out;
}

}  // namespace qdo
