// The radial PSF engine (include/qdo/radial.hpp): tables, CPU reference, OpenCL engine.
#include "qdo/radial.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <map>
#include <mutex>
#include <thread>
#include <utility>

#include "qdo/adjoint.hpp"
#include "qdo/cpu_reference.hpp"
#include "qdo/error.hpp"

namespace qdo {

// ---------------------------------------------------------------------------------------------
// Bessel functions and zeros.

double bessel_j0(double x) { return std::cyl_bessel_j(0.0, std::fabs(x)); }

double bessel_j1(double x) {
  const double v = std::cyl_bessel_j(1.0, std::fabs(x));
  return x < 0 ? -v : v;
}

std::vector<double> bessel_j0_zeros(std::size_t count) {
  std::vector<double> z(count);
  for (std::size_t s = 0; s < count; ++s) {
    // McMahon: j ~ b + 1/(8b) - 124/(3 (8b)^3) + ..., b = (s + 3/4) pi (s from 0).
    const double b = (double(s) + 0.75) * M_PI, e = 8.0 * b;
    double x = b + 1.0 / e - 124.0 / (3.0 * e * e * e);
    for (int it = 0; it < 8; ++it) {
      const double dx = bessel_j0(x) / bessel_j1(x);  // Newton: J0' = -J1
      x += dx;
      if (std::fabs(dx) < 4e-16 * x) break;
    }
    z[s] = x;
  }
  return z;
}

std::vector<double> qdht_matrix(std::size_t k) {
  if (k < 1) reject("k", k, ">= 1");
  const std::vector<double> z = bessel_j0_zeros(k + 1);
  std::vector<double> t(k * k);
  for (std::size_t m = 0; m < k; ++m)
    for (std::size_t n = 0; n < k; ++n)
      t[m * k + n] = 2.0 * bessel_j0(z[m] * z[n] / z[k]) / (z[k] * std::fabs(bessel_j1(z[m])) * std::fabs(bessel_j1(z[n])));
  return t;
}

void RadialOptions::validate() const {
  if (!(window_factor >= 0.5 && window_factor <= 4.0))
    reject("radial.window_factor", window_factor, "within [0.5, 4] (R = factor * M * pitch / 2)");
  if (!(node_oversample >= 0.5 && node_oversample <= 8.0))
    reject("radial.node_oversample", node_oversample, "within [0.5, 8] (nodes per DOE pitch)");
  if (!(render_oversample >= 1.0 && render_oversample <= 32.0))
    reject("radial.render_oversample", render_oversample, "within [1, 32] (output samples per DOE pitch)");
}

void radial_lagrange4(double r_m, double dr_m, int idx[4], double w[4]) {
  const double t = r_m / dr_m;
  const double j0 = std::floor(t), f = t - j0;
  const int j = static_cast<int>(j0);
  w[0] = -f * (f - 1) * (f - 2) / 6.0;
  w[1] = (f + 1) * (f - 1) * (f - 2) / 2.0;
  w[2] = -(f + 1) * f * (f - 2) / 2.0;
  w[3] = (f + 1) * f * (f - 1) / 6.0;
  for (int q = 0; q < 4; ++q) idx[q] = std::abs(j - 1 + q);
}

namespace {

using clock_type = std::chrono::steady_clock;

// Runs body(lo, hi) over [0, count) on up to two host threads (table construction only).
template <typename F>
void parallel_rows(std::size_t count, const F& body) {
  const std::size_t threads = std::max<std::size_t>(1, std::min<std::size_t>(std::thread::hardware_concurrency(), 8));
  if (threads == 1 || count < 64) {
    body(std::size_t(0), count);
    return;
  }
  std::vector<std::thread> pool;
  for (std::size_t t = 0; t < threads; ++t) {
    const std::size_t lo = count * t / threads, hi = count * (t + 1) / threads;
    pool.emplace_back([&body, lo, hi] { body(lo, hi); });
  }
  for (auto& th : pool) th.join();
}

void check_ring_heights(const RadialTables& t, const std::vector<double>& h, double h_max_m) {
  if (h.size() != t.rings) reject("ring_heights_m.size()", h.size(), "exactly N/2 = " + to_str(t.rings));
  for (std::size_t k = 0; k < h.size(); ++k)
    if (!std::isfinite(h[k]) || h[k] < 0 || h[k] > 2 * h_max_m)
      reject("ring_heights_m[" + to_str(k) + "]", h[k], "finite, within [0, 2 h_max] = [0, " + to_str(2 * h_max_m) + "] m");
}

}  // namespace

RadialTables RadialTables::build(const SystemConfig& cfg, const RadialOptions& opt) {
  cfg.validate();
  opt.validate();
  if (!cfg.object_points.empty()) return build(radial_config(cfg), opt);
  const PropagationGeometry g = PropagationGeometry::from_config(cfg);
  RadialTables t;
  t.n = cfg.n;
  t.rings = cfg.n / 2;
  t.bands = cfg.bands;
  t.pitch_m = cfg.pitch_m;
  t.window_m = opt.window_factor * double(g.m) * cfg.pitch_m / 2.0;
  t.k = static_cast<std::size_t>(std::ceil(opt.node_oversample * t.window_m / cfg.pitch_m));
  t.dr_m = cfg.pitch_m / opt.render_oversample;
  const double r_corner = std::sqrt(2.0) * double(cfg.n / 2) * cfg.pitch_m;
  t.j = static_cast<std::size_t>(std::floor(r_corner / t.dr_m)) + 4;
  t.s = cfg.sensor_size_px();
  const std::size_t kk = t.k, jj = t.j, bands = t.bands;

  const std::vector<double> zeros = bessel_j0_zeros(kk + 1);
  const double big_s = zeros[kk], rr = t.window_m;
  t.rho_per_m.resize(kk);
  t.inv_j1.resize(kk);
  for (std::size_t m = 0; m < kk; ++m) {
    t.rho_per_m[m] = zeros[m] / (2.0 * M_PI * rr);
    t.inv_j1[m] = 1.0 / std::fabs(bessel_j1(zeros[m]));
  }
  // Ring k spans [k pitch, (k+1) pitch) clipped to the aperture (a continuous radius: aperture_edge,
  // which decides ties of sampled radii, does not apply); the last ring (which also holds the
  // grid's corners in expand_parameters) extends to r_ap, should a custom aperture reach beyond N/2.
  const double r_ap = cfg.aperture_radius() * (1 + 1e-12);
  std::vector<double> lo(t.rings), hi(t.rings);
  for (std::size_t k = 0; k < t.rings; ++k) {
    lo[k] = double(k) * cfg.pitch_m;
    hi[k] = k + 1 == t.rings ? r_ap : std::min(double(k + 1) * cfg.pitch_m, r_ap);
    if (hi[k] < lo[k]) hi[k] = lo[k];
  }
  // Q (ring -> spectrum) and B (spectrum -> field on the output grid), split over host threads.
  t.q.assign(kk * t.rings, 0.0);
  parallel_rows(kk, [&](std::size_t first, std::size_t last) {
    for (std::size_t m = first; m < last; ++m) {
      const double rho = t.rho_per_m[m], scale = big_s / (2.0 * M_PI * rr * rr) * t.inv_j1[m];
      // 2 pi int_a^b J0(2 pi rho r) r dr = [r J1(2 pi rho r) / rho]_a^b
      auto prim = [rho](double r) { return r * bessel_j1(2.0 * M_PI * rho * r) / rho; };
      double prev = prim(lo[0]);
      for (std::size_t k = 0; k < t.rings; ++k) {
        const double next = prim(hi[k]);
        const double start = (k > 0 && lo[k] == hi[k - 1]) ? prev : prim(lo[k]);
        t.q[m * t.rings + k] = scale * (next - start);
        prev = next;
      }
    }
  });
  t.b.assign(jj * kk, 0.0);
  parallel_rows(jj, [&](std::size_t first, std::size_t last) {
    for (std::size_t j = first; j < last; ++j) {
      const double r = double(j) * t.dr_m;
      for (std::size_t m = 0; m < kk; ++m) t.b[j * kk + m] = 2.0 * bessel_j0(zeros[m] * r / rr) * t.inv_j1[m] / big_s;
    }
  });
  // Source phase per ring and the transfer function, per band, in double.
  const auto k = wavenumber_per_band(cfg);
  const auto dn = delta_n_per_band(cfg);
  const auto wl = cfg.wavelengths_nm();
  const double d = cfg.scene_distance_m, z = cfg.sensor_distance_m;
  t.kdn_per_m.resize(bands);
  t.source.assign(bands * t.rings, cdouble(0, 0));
  t.tf.assign(bands * kk, cdouble(0, 0));
  for (std::size_t b = 0; b < bands; ++b) {
    t.kdn_per_m[b] = k[b] * dn[b];
    const double lambda = wl[b] * 1e-9;
    const double f_lim = transfer_function_limit_per_m(cfg.propagator, wl[b], z, g.m, cfg.pitch_m);
    for (std::size_t r = 0; r < t.rings; ++r) {
      if (!(hi[r] > lo[r])) continue;
      const double rm = 0.5 * (lo[r] + hi[r]), r2 = rm * rm;
      const double src = cfg.scene_at_infinity ? 0.0 : r2 / (std::sqrt(r2 + d * d) + d);
      t.source[b * t.rings + r] = std::polar(1.0, k[b] * src);
    }
    for (std::size_t m = 0; m < kk; ++m) {
      const double rho = t.rho_per_m[m], f2 = rho * rho;
      if (cfg.propagator == Propagator::Fresnel) {
        t.tf[b * kk + m] = std::polar(1.0, -M_PI * lambda * z * f2);
      } else if (rho <= f_lim && f2 * lambda * lambda < 1.0) {
        const double inv_l = 1.0 / lambda;
        t.tf[b * kk + m] = std::polar(1.0, -2.0 * M_PI * z * f2 / (std::sqrt(inv_l * inv_l - f2) + inv_l));
      }
    }
  }
  // Sensor classes from the 2-D path's area weights.
  t.weights = AreaWeights::make(cfg.n, cfg.pitch_m, t.s, cfg.sensor_pitch_m);
  const AreaWeights& w = t.weights;
  using Taps = std::vector<std::pair<long, double>>;  // (|pixel offset from N/2|, weight)
  std::vector<Taps> taps_of(t.s);
  std::map<std::vector<std::pair<long, long long>>, int> key_to_class;
  std::vector<Taps> class_taps;
  t.class_of.assign(t.s, 0);
  for (std::size_t o = 0; o < t.s; ++o) {
    Taps tp;
    for (std::size_t q = 0; q < w.taps; ++q) {
      const double v = w.w[o * w.taps + q];
      const long i = long(w.start[o]) + long(q);
      if (v != 0 && i >= 0 && i < long(cfg.n)) tp.push_back({std::labs(i - long(cfg.n / 2)), v});
    }
    std::sort(tp.begin(), tp.end());
    std::vector<std::pair<long, long long>> key;
    for (const auto& [off, v] : tp) key.push_back({off, std::llround(v * 1e12)});
    const auto it = key_to_class.find(key);
    if (it == key_to_class.end()) {
      const int c = static_cast<int>(class_taps.size());
      key_to_class[key] = c;
      class_taps.push_back(tp);
      t.class_of[o] = c;
    } else {
      t.class_of[o] = it->second;
    }
  }
  t.classes = class_taps.size();
  t.class_start.assign(t.classes + 1, 0);
  for (std::size_t o = 0; o < t.s; ++o) ++t.class_start[static_cast<std::size_t>(t.class_of[o]) + 1];
  for (std::size_t c = 0; c < t.classes; ++c) t.class_start[c + 1] += t.class_start[c];
  t.class_members.assign(t.s, 0);
  {
    std::vector<int> fill(t.class_start.begin(), t.class_start.end() - 1);
    for (std::size_t o = 0; o < t.s; ++o) t.class_members[static_cast<std::size_t>(fill[static_cast<std::size_t>(t.class_of[o])]++)] = int(o);
  }
  t.unique = t.classes * (t.classes + 1) / 2;
  t.pair_y.assign(t.unique, 0);
  t.pair_x.assign(t.unique, 0);
  t.multiplicity.assign(t.unique, 0.0);
  t.a_start.assign(t.unique + 1, 0);
  std::vector<std::map<int, double>> rows(t.unique);
  for (std::size_t cx = 0; cx < t.classes; ++cx)
    for (std::size_t cy = 0; cy <= cx; ++cy) {
      const std::size_t u = cx * (cx + 1) / 2 + cy;
      t.pair_y[u] = int(cy);
      t.pair_x[u] = int(cx);
      const double ny = double(t.class_start[cy + 1] - t.class_start[cy]), nx = double(t.class_start[cx + 1] - t.class_start[cx]);
      t.multiplicity[u] = ny * nx * (cy == cx ? 1.0 : 2.0);
      for (const auto& [oy, wy] : class_taps[cy])
        for (const auto& [ox, wx] : class_taps[cx]) {
          int idx[4];
          double lw[4];
          radial_lagrange4(std::sqrt(double(oy * oy + ox * ox)) * cfg.pitch_m, t.dr_m, idx, lw);
          for (int q = 0; q < 4; ++q) rows[u][idx[q]] += wy * wx * lw[q];
        }
    }
  std::vector<std::vector<std::pair<int, double>>> cols(jj);
  for (std::size_t u = 0; u < t.unique; ++u) {
    for (const auto& [c, v] : rows[u]) {
      t.a_col.push_back(c);
      t.a_val.push_back(v);
      cols[static_cast<std::size_t>(c)].push_back({int(u), v});
    }
    t.a_start[u + 1] = int(t.a_col.size());
  }
  t.at_start.assign(jj + 1, 0);
  for (std::size_t j = 0; j < jj; ++j) {
    for (const auto& [u, v] : cols[j]) {
      t.at_col.push_back(u);
      t.at_val.push_back(v);
    }
    t.at_start[j + 1] = int(t.at_col.size());
  }
  return t;
}

std::shared_ptr<const RadialTables> RadialTables::cached(const SystemConfig& cfg, const RadialOptions& opt) {
  cfg.validate();
  opt.validate();
  static std::mutex mu;
  static std::map<std::string, std::weak_ptr<const RadialTables>> cache;
  const std::string key = config_to_json_text(cfg) + "|" + to_str(opt.window_factor) + "|" + to_str(opt.node_oversample) +
                          "|" + to_str(opt.render_oversample);
  std::lock_guard<std::mutex> lock(mu);
  if (auto hit = cache[key].lock()) return hit;
  auto built = std::make_shared<const RadialTables>(build(cfg, opt));
  cache[key] = built;
  return built;
}

std::vector<double> ring_heights_of_map(const Map2D& h) {
  if (h.rows != h.cols || h.rows < 2 || h.rows % 2)
    reject("height_m", to_str(h.rows) + " x " + to_str(h.cols), "a square N x N map with N even");
  const std::size_t half = h.rows / 2;
  std::vector<double> out(half);
  for (std::size_t k = 0; k < half; ++k) out[k] = h(half, half + k);
  return out;
}

Map2D spread_ring_gradient(const std::vector<double>& g_ring, std::size_t n) {
  if (n < 2 || n % 2) reject("n", n, "an even number >= 2");
  if (g_ring.size() != n / 2) reject("g_ring.size()", g_ring.size(), "exactly N/2 = " + to_str(n / 2));
  // Ring of each pixel exactly as expand_parameters (integer floor(sqrt), last ring takes the rest).
  const long half = long(n / 2);
  std::vector<long> ring(n * n);
  std::vector<double> count(n / 2, 0.0);
  for (std::size_t i = 0; i < n; ++i)
    for (std::size_t j = 0; j < n; ++j) {
      const long di = long(i) - half, dj = long(j) - half, r2 = di * di + dj * dj;
      long k = static_cast<long>(std::sqrt(double(r2)));
      while (k * k > r2) --k;
      while ((k + 1) * (k + 1) <= r2) ++k;
      k = std::min(k, half - 1);
      ring[i * n + j] = k;
      count[static_cast<std::size_t>(k)] += 1;
    }
  Map2D g(n, n);
  for (std::size_t p = 0; p < n * n; ++p) {
    const auto k = static_cast<std::size_t>(ring[p]);
    g.data[p] = g_ring[k] / count[k];
  }
  return g;
}

// ---------------------------------------------------------------------------------------------
// CPU reference (double).


// ---------------------------------------------------------------------------------------------
// OpenCL engine.

namespace {
constexpr int kBandChunk = 8;  // bands per work-item in radial_matmul (RADIAL_BC in kernels/radial.cl)
}

struct RadialEngine::Impl {
  cl::Buffer q, qt, bt, b, source, tf, kdn, a_start, a_col, a_val, at_start, at_col, at_val,
      class_of, class_start, class_members, pair_y, pair_x, mult;
  cl::Buffer heights, c, g, gp, u2, inten, v, sums, psf_s;
  cl::Buffer g_s, g_u, dots, g_v, g_i, g_u2, g_g, g_c, g_h;
  cl::Kernel k_field, k_matmul, k_cmul, k_intensity, k_render, k_band_dot, k_expand, k_fold, k_norm_vjp, k_intensity_vjp,
      k_phase_ring;
};

SystemConfig radial_config(const SystemConfig& cfg) {
  if (cfg.object_points.empty()) return cfg;
  if (cfg.object_points.size() == 1 && cfg.object_points[0].on_axis()) return point_config(cfg, 0);
  reject("object_points", to_str(cfg.object_points.size()) + " points" + (cfg.object_points.size() == 1 ? " (off-axis)" : ""),
         "at most one on-axis point for the radial path (it serves on-axis points at any distance: one engine per point, "
         "e.g. with point_config(cfg, p)); off-axis points and stacks of points need the 2-D path");
}

RadialEngine::RadialEngine(Runtime& rt, const SystemConfig& cfg, Precision p, const RadialOptions& opt)
    : rt_(rt), cfg_(radial_config(cfg)), prec_(p) {
  cfg_.validate();
  opt.validate();
  rt_.require(p);
  tab_ = RadialTables::cached(cfg_, opt);
  impl_ = std::make_unique<Impl>();
  const RadialTables& t = *tab_;
  Impl& d = *impl_;
  const auto& ctx = rt_.context();
  const std::size_t rs = real_size(p);
  auto up_int = [&](const std::vector<int>& v) {
    std::vector<int> h = v.empty() ? std::vector<int>{0} : v;
    return cl::Buffer(ctx, CL_MEM_READ_ONLY | CL_MEM_COPY_HOST_PTR, h.size() * sizeof(int), h.data());
  };
  auto up_real = [&](const std::vector<double>& v) {
    std::vector<double> h = v.empty() ? std::vector<double>{0.0} : v;
    if (p == Precision::F64) return cl::Buffer(ctx, CL_MEM_READ_ONLY | CL_MEM_COPY_HOST_PTR, h.size() * 8, h.data());
    std::vector<float> f(h.begin(), h.end());
    return cl::Buffer(ctx, CL_MEM_READ_ONLY | CL_MEM_COPY_HOST_PTR, f.size() * 4, f.data());
  };
  auto up_complex = [&](const std::vector<cdouble>& v) {
    std::vector<double> h(2 * v.size());
    for (std::size_t e = 0; e < v.size(); ++e) {
      h[2 * e] = v[e].real();
      h[2 * e + 1] = v[e].imag();
    }
    return up_real(h);
  };
  d.q = up_real(t.q);
  std::vector<double> qt(t.rings * t.k), bt(t.k * t.j);
  for (std::size_t m = 0; m < t.k; ++m)
    for (std::size_t r = 0; r < t.rings; ++r) qt[r * t.k + m] = t.q[m * t.rings + r];
  d.qt = up_real(qt);
  for (std::size_t j = 0; j < t.j; ++j)
    for (std::size_t m = 0; m < t.k; ++m) bt[m * t.j + j] = t.b[j * t.k + m];
  d.bt = up_real(bt);
  d.b = up_real(t.b);
  d.source = up_complex(t.source);
  d.tf = up_complex(t.tf);
  d.kdn = up_real(t.kdn_per_m);
  d.a_start = up_int(t.a_start);
  d.a_col = up_int(t.a_col);
  d.a_val = up_real(t.a_val);
  d.at_start = up_int(t.at_start);
  d.at_col = up_int(t.at_col);
  d.at_val = up_real(t.at_val);
  d.class_of = up_int(t.class_of);
  d.class_start = up_int(t.class_start);
  d.class_members = up_int(t.class_members);
  d.pair_y = up_int(t.pair_y);
  d.pair_x = up_int(t.pair_x);
  d.mult = up_real(t.multiplicity);
  const std::size_t bands = t.bands, br = bands * t.rings, bk = bands * t.k, bj = bands * t.j, bu = bands * t.unique, bss = bands * t.s * t.s;
  auto rw = [&](std::size_t count) { return cl::Buffer(ctx, CL_MEM_READ_WRITE, std::max<std::size_t>(count, 1) * rs); };
  d.heights = rw(t.rings);
  d.c = rw(2 * br);
  d.g = rw(2 * bk);
  d.gp = rw(2 * bk);
  d.u2 = rw(2 * bj);
  d.inten = rw(bj);
  d.v = rw(bu);
  d.sums = rw(bands);
  d.psf_s = rw(bss);
  d.g_s = rw(bss);
  d.g_u = rw(bu);
  d.dots = rw(bands);
  d.g_v = rw(bu);
  d.g_i = rw(bj);
  d.g_u2 = rw(2 * bj);
  d.g_g = rw(2 * bk);
  d.g_c = rw(2 * br);
  d.g_h = rw(t.rings);
  const std::string f = "radial.cl", opts = "-DRADIAL_TILE=" + std::to_string(Runtime::kLocalSize);
  d.k_field = rt_.kernel(f, "radial_field", p, opts);
  d.k_matmul = rt_.kernel(f, "radial_matmul", p, opts);
  d.k_cmul = rt_.kernel(f, "radial_cmul_table", p, opts);
  d.k_intensity = rt_.kernel(f, "radial_intensity", p, opts);
  d.k_render = rt_.kernel(f, "radial_csr_apply", p, opts);
  d.k_band_dot = rt_.kernel(f, "radial_band_dot", p, opts);
  d.k_expand = rt_.kernel(f, "radial_expand", p, opts);
  d.k_fold = rt_.kernel(f, "radial_fold", p, opts);
  d.k_norm_vjp = rt_.kernel(f, "radial_normalize_vjp", p, opts);
  d.k_intensity_vjp = rt_.kernel(f, "radial_intensity_vjp", p, opts);
  d.k_phase_ring = rt_.kernel(f, "radial_phase_ring_vjp", p, opts);
}

RadialEngine::~RadialEngine() = default;

namespace {

// y (bands x rows complex) = M x (bands x cols complex), M given column-major (mt[c * rows + r]).
void matmul(cl::CommandQueue& q, cl::Kernel& k, Precision p, const cl::Buffer& mt, const cl::Buffer& x, cl::Buffer& y,
            std::size_t rows, std::size_t cols, std::size_t bands) {
  set_args(k, p, mt, x, y, int(rows), int(cols), int(bands));
  const std::size_t chunks = (bands + kBandChunk - 1) / kBandChunk;
  q.enqueueNDRangeKernel(k, cl::NullRange, cl::NDRange(Runtime::global_for(rows), chunks), cl::NDRange(Runtime::kLocalSize, 1));
}

void band_dot(cl::CommandQueue& q, cl::Kernel& k, Precision p, const cl::Buffer& x, const cl::Buffer& y,
              int y_band_stride, cl::Buffer& out, std::size_t len, std::size_t bands) {
  set_args(k, p, x, y, y_band_stride, int(len), out, cl::Local(Runtime::kLocalSize * sizeof(double)));
  q.enqueueNDRangeKernel(k, cl::NullRange, cl::NDRange(Runtime::kLocalSize, bands), cl::NDRange(Runtime::kLocalSize, 1));
}

std::vector<double> download(cl::CommandQueue& q, const cl::Buffer& b, std::size_t count, Precision p) {
  std::vector<double> out(count);
  Runtime::read_reals(q, b, out.data(), count, p);
  return out;
}

void upload_into(cl::CommandQueue& q, cl::Buffer& b, const std::vector<double>& v, Precision p) {
  Runtime::write_reals(q, b, v.data(), v.size(), p);
}

}  // namespace

void RadialEngine::compute_psf(const std::vector<double>& ring_heights_m) {
  const RadialTables& t = *tab_;
  check_ring_heights(t, ring_heights_m, cfg_.h_max_m());
  const auto t0 = clock_type::now();
  Impl& d = *impl_;
  cl::CommandQueue& q = rt_.queue();
  const std::size_t bands = t.bands;
  upload_into(q, d.heights, ring_heights_m, prec_);
  rt_.launch_1d(d.k_field, bands * t.rings, prec_, d.source, d.kdn, d.heights, d.c, int(t.rings), int(bands));
  matmul(q, d.k_matmul, prec_, d.qt, d.c, d.g, t.k, t.rings, bands);  // Q: Q^T row-major is Q column-major
  rt_.launch_1d(d.k_cmul, bands * t.k, prec_, d.g, d.tf, d.gp, int(bands * t.k), 0);
  matmul(q, d.k_matmul, prec_, d.bt, d.gp, d.u2, t.j, t.k, bands);
  rt_.launch_1d(d.k_intensity, bands * t.j, prec_, d.u2, d.inten, int(bands * t.j));
  rt_.launch_1d(d.k_render, bands * t.unique, prec_, d.a_start, d.a_col, d.a_val, d.inten, d.v, int(t.unique), int(t.j),
                int(bands));
  band_dot(q, d.k_band_dot, prec_, d.v, d.mult, 0, d.sums, t.unique, bands);
  rt_.launch_1d(d.k_expand, bands * t.s * t.s, prec_, d.v, d.sums, d.class_of, d.psf_s, int(t.s), int(t.unique),
                int(bands));
  q.finish();
  valid_ = true;
  ++generation_;
  t_fwd_ = std::chrono::duration<double>(clock_type::now() - t0).count();
}

RealStack RadialEngine::psf_sensor() const {
  if (!valid_) throw Error("RadialEngine: compute_psf() must run before psf_sensor()");
  const RadialTables& t = *tab_;
  RealStack out(t.bands, t.s, t.s);
  out.data = download(rt_.queue(), impl_->psf_s, out.size(), prec_);
  return out;
}

std::vector<double> RadialEngine::intensity() const {
  if (!valid_) throw Error("RadialEngine: compute_psf() must run before intensity()");
  return download(rt_.queue(), impl_->inten, tab_->bands * tab_->j, prec_);
}

std::vector<double> RadialEngine::psf_sensor_vjp(const RealStack& g_psf_sensor) {
  const RadialTables& t = *tab_;
  if (g_psf_sensor.planes != t.bands || g_psf_sensor.rows != t.s || g_psf_sensor.cols != t.s)
    reject("g_psf_sensor", to_str(g_psf_sensor.planes) + " x " + to_str(g_psf_sensor.rows) + " x " + to_str(g_psf_sensor.cols),
           "bands x S x S = " + to_str(t.bands) + " x " + to_str(t.s) + " x " + to_str(t.s));
  for (double v : g_psf_sensor.data)
    if (!std::isfinite(v)) reject("g_psf_sensor", v, "finite values");
  if (!valid_) throw Error("RadialEngine: compute_psf() must run before an adjoint");
  const auto t0 = clock_type::now();
  upload_into(rt_.queue(), impl_->g_s, g_psf_sensor.data, prec_);
  return vjp_from(impl_->g_s, t0);
}

const cl::Buffer& RadialEngine::psf_sensor_buffer() const { return impl_->psf_s; }

std::string RadialEngine::describe() const {
  return "simulated (radial, N = " + to_str(cfg_.n) + ", " + to_string(prec_) + ")";
}

std::vector<double> RadialEngine::psf_sensor_vjp(const cl::Buffer& g_psf_sensor) {
  const RadialTables& t = *tab_;
  const std::size_t bytes = t.bands * t.s * t.s * (prec_ == Precision::F64 ? sizeof(double) : sizeof(float));
  if (g_psf_sensor.getInfo<CL_MEM_SIZE>() < bytes)
    reject("g_psf_sensor buffer", to_str(g_psf_sensor.getInfo<CL_MEM_SIZE>()) + " bytes",
           ">= " + to_str(bytes) + " (bands x S x S reals of the engine's precision)");
  if (!valid_) throw Error("RadialEngine: compute_psf() must run before an adjoint");
  return vjp_from(g_psf_sensor, clock_type::now());
}

// The adjoint chain from dL/dpsf_sensor on the device (g_s: bands x S x S, only read).
std::vector<double> RadialEngine::vjp_from(const cl::Buffer& g_s, std::chrono::steady_clock::time_point t0) {
  const RadialTables& t = *tab_;
  Impl& d = *impl_;
  cl::CommandQueue& q = rt_.queue();
  const std::size_t bands = t.bands;
  rt_.launch_1d(d.k_fold, bands * t.unique, prec_, g_s, d.class_start, d.class_members, d.pair_y, d.pair_x, d.g_u,
                int(t.s), int(t.unique), int(bands));
  band_dot(q, d.k_band_dot, prec_, d.g_u, d.v, int(t.unique), d.dots, t.unique, bands);
  rt_.launch_1d(d.k_norm_vjp, bands * t.unique, prec_, d.g_u, d.mult, d.dots, d.sums, d.g_v, int(t.unique), int(bands));
  rt_.launch_1d(d.k_render, bands * t.j, prec_, d.at_start, d.at_col, d.at_val, d.g_v, d.g_i, int(t.j), int(t.unique),
                int(bands));
  rt_.launch_1d(d.k_intensity_vjp, bands * t.j, prec_, d.g_i, d.u2, d.g_u2, int(bands * t.j));
  matmul(q, d.k_matmul, prec_, d.b, d.g_u2, d.g_g, t.k, t.j, bands);  // B^T: B row-major is B^T column-major
  rt_.launch_1d(d.k_cmul, bands * t.k, prec_, d.g_g, d.tf, d.g_g, int(bands * t.k), 1);
  matmul(q, d.k_matmul, prec_, d.q, d.g_g, d.g_c, t.rings, t.k, bands);  // Q^T: Q row-major is Q^T column-major
  rt_.launch_1d(d.k_phase_ring, t.rings, prec_, d.g_c, d.c, d.kdn, d.g_h, int(t.rings), int(bands));
  std::vector<double> gh = download(q, d.g_h, t.rings, prec_);
  t_adj_ = std::chrono::duration<double>(clock_type::now() - t0).count();
  return gh;
}

}  // namespace qdo
