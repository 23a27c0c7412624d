// The radial PSF engine's tables (include/qdo/physics/radial.hpp): Bessel functions and zeros, the QDHT,
// RadialTables (build, cache) and the ring <-> grid maps. The OpenCL engine is in radial.cpp.
#include "qdo/physics/radial.hpp"

#include <algorithm>
#include <cmath>
#include <map>
#include <mutex>
#include <thread>
#include <utility>

#include "qdo/runtime/error.hpp"

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

}  // namespace qdo
