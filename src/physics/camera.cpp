// The Camera's passes (include/qdo/physics/camera.hpp): a batch's plan under the skipping rules, images,
// their adjoint (vjp) and blur. Construction, the PSF and its caches are camera_setup.cpp.
#include "qdo/physics/camera.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <numeric>

#include "qdo/physics/cpu_reference.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/fft.hpp"
#include "qdo/physics/optics.hpp"
#include "row_launch.hpp"

namespace qdo {

namespace {

constexpr std::size_t kMaxChunkBytes = std::size_t(256) << 20;  // pair spectra of one chunk of windows
constexpr double kTileGain = 0.75;  // Auto tiles when the tiled cost model is below this fraction

// Negative / positive extent of the PSF offsets kept at crop radius r (offsets -S/2 .. S-1-S/2).
std::size_t extent_neg(std::size_t r, std::size_t s) { return std::min(r, s / 2); }
std::size_t extent_pos(std::size_t r, std::size_t s) { return std::min(r, s - 1 - s / 2); }

// Grid length for one axis: a window of `len` pixels whose output is read over [0, len) only
// (whole scene) or over its full linear support (tile), with PSF extents a, b.
std::size_t grid_length(std::size_t len, std::size_t a, std::size_t b, bool full_support) {
  const std::size_t need = full_support ? len + a + b : std::max(len + std::max(a, b), a + b + 1);
  return fast_fft_size(need);
}

// Relative cost of the transforms and per-frequency kernels of `windows` windows on a gy x gx
// grid with `pairs` pair spectra each (forward pairs + 2 inverse transforms, plus place/combine).
double cost_model(std::size_t windows, std::size_t gy, std::size_t gx, std::size_t pairs) {
  const double g = double(gy) * double(gx);
  return double(windows) * g * (std::log2(std::max(g, 2.0)) * double(pairs + 2) + 4.0 * double(pairs));
}

// Writes `planes` planes of hw doubles (plane j from plane_at(j)) into buf as reals of precision p,
// plane j at element j * hw: one mapping of the whole region, converted straight into it (no
// staging vector, one blocking command instead of one per plane). Returns whether every value was
// finite (an infinity or a NaN has every exponent bit set), found in the same pass.
template <typename T, typename PlaneAt>
bool convert_planes(T* dst, std::size_t planes, std::size_t hw, PlaneAt&& plane_at) {
  constexpr std::uint64_t kExponent = 0x7ff0000000000000ull;
  std::uint64_t nonfinite = 0;
  for (std::size_t j = 0; j < planes; ++j) {
    const double* src = plane_at(j);
    T* out = dst + j * hw;
    for (std::size_t i = 0; i < hw; ++i) {
      std::uint64_t bits;
      std::memcpy(&bits, src + i, sizeof bits);
      nonfinite |= std::uint64_t((bits & kExponent) == kExponent);
      out[i] = T(src[i]);
    }
  }
  return nonfinite == 0;
}
template <typename PlaneAt>
bool upload_planes(cl::CommandQueue& q, const cl::Buffer& buf, Precision p, std::size_t planes, std::size_t hw,
                   PlaneAt&& plane_at) {
  if (planes * hw == 0) return true;
  const std::size_t rsz = real_size(p);
  void* ptr = q.enqueueMapBuffer(buf, CL_TRUE, CL_MAP_WRITE_INVALIDATE_REGION, 0, planes * hw * rsz);
  const bool finite = p == Precision::F64 ? convert_planes(static_cast<double*>(ptr), planes, hw, plane_at)
                                          : convert_planes(static_cast<float*>(ptr), planes, hw, plane_at);
  q.enqueueUnmapMemObject(buf, ptr);
  return finite;
}

}  // namespace

// The host half of images(): the per-band (and per-tile) maxima of the batch, the three skipping
// rules and the report. No device work but the per-generation ring energies (ensure_rings).
Camera::Plan Camera::plan_images(const std::vector<RealStack>& cubes, const SkipOptions& opt) {
  const std::size_t bands = cfg_.bands, h = cubes[0].rows, w = cubes[0].cols, scenes = cubes.size();
  const bool circular = cfg_.convolution == ConvolutionMode::Circular;
  // ---- Host pass: per-band maxima over the batch, and per tile when tiling is possible ----
  const bool may_tile = !opt.exact && !circular && opt.tiles != TileMode::Off;
  const std::size_t tpx = opt.tile_px, nty = may_tile ? (h + tpx - 1) / tpx : 1, ntx = may_tile ? (w + tpx - 1) / tpx : 1;
  const std::size_t ntiles = nty * ntx;
  std::vector<double> bmax(bands, 0.0);
  std::vector<double> tmax(may_tile ? scenes * bands * ntiles : 0, 0.0);  // scenes x bands x tiles
  // Exact calls skip nothing and bound nothing: the maxima would only multiply zero dropped energy.
  for (std::size_t k = 0; k < (opt.exact ? 0 : scenes); ++k)
    for (std::size_t b = 0; b < bands; ++b) {
      const double* p = cubes[k].plane(b);
      if (!may_tile) {  // the band maxima alone: one contiguous pass
        double m = bmax[b];
        for (std::size_t i = 0; i < h * w; ++i) m = std::max(m, std::fabs(p[i]));
        bmax[b] = m;
        continue;
      }
      double* tm = tmax.data() + (k * bands + b) * ntiles;
      for (std::size_t y = 0; y < h; ++y)
        for (std::size_t x = 0; x < w; ++x) {
          const double v = std::fabs(p[y * w + x]);
          bmax[b] = std::max(bmax[b], v);
          tm[(y / tpx) * ntx + x / tpx] = std::max(tm[(y / tpx) * ntx + x / tpx], v);
        }
    }

  ensure_rings();
  const std::size_t c = s_ / 2, nr = c + 1;
  // Suffix sums: dropped_b(r) = sum_{k > r} ring_b(k); kept_b(r) = sum_{k <= r} ring_b(k).
  std::vector<double> dropped(bands * (nr + 1), 0.0), keptsum(bands * nr, 0.0), total(bands, 0.0);
  for (std::size_t b = 0; b < bands; ++b) {
    double acc = 0;
    for (std::size_t k = nr; k-- > 0;) {
      dropped[b * (nr + 1) + k] = acc;  // energy beyond ring k
      acc += rings_[b * nr + k];
    }
    total[b] = acc;
    double run = 0;
    for (std::size_t k = 0; k < nr; ++k) {
      run += rings_[b * nr + k];
      keptsum[b * nr + k] = run;
    }
  }
  auto drop_at = [&](std::size_t b, std::size_t r) { return dropped[b * (nr + 1) + std::min(r, c)]; };
  auto kept_at = [&](std::size_t b, std::size_t r) { return keptsum[b * nr + std::min(r, c)]; };

  SkipReport rep;
  rep.scenes = scenes;
  rep.height = h;
  rep.width = w;
  rep.bands = bands;
  rep.sensor_psf_px = s_;
  rep.tolerance = opt.total_tolerance();
  rep.psf_generation = current_generation();

  // ---- Rule 1: bands ----
  std::vector<double> band_c(3, 0.0);
  std::vector<bool> skip_band(bands, false);
  if (!opt.exact) {
    std::vector<std::size_t> order(bands);
    std::iota(order.begin(), order.end(), 0);
    auto score = [&](std::size_t b) {
      double s = 0;
      for (int ch = 0; ch < 3; ++ch) s = std::max(s, srf_(ch, Eigen::Index(b)) * bmax[b] * total[b]);
      return s;
    };
    std::stable_sort(order.begin(), order.end(), [&](std::size_t x, std::size_t y) { return score(x) < score(y); });
    for (std::size_t b : order) {
      double worst = 0;
      for (int ch = 0; ch < 3; ++ch)
        worst = std::max(worst, band_c[std::size_t(ch)] + srf_(ch, Eigen::Index(b)) * bmax[b] * total[b]);
      if (worst > opt.band_tolerance) break;
      skip_band[b] = true;
      for (int ch = 0; ch < 3; ++ch) band_c[std::size_t(ch)] += srf_(ch, Eigen::Index(b)) * bmax[b] * total[b];
    }
  }
  std::vector<std::size_t> kept;
  for (std::size_t b = 0; b < bands; ++b) (skip_band[b] ? rep.bands_skipped : rep.bands_kept).push_back(b);
  kept = rep.bands_kept;
  const std::size_t nk = kept.size(), pairs = (nk + 1) / 2;

  // ---- Rule 2: crop radius (smallest within budget, scene peaks taken as max(1, max|x|)) ----
  auto crop_channels = [&](std::size_t r, bool peaks) {
    std::vector<double> v(3, 0.0);
    for (std::size_t b : kept)
      for (int ch = 0; ch < 3; ++ch)
        v[std::size_t(ch)] += srf_(ch, Eigen::Index(b)) * (peaks ? std::max(1.0, bmax[b]) : bmax[b]) * drop_at(b, r);
    return v;
  };
  auto maxc = [](const std::vector<double>& v) { return *std::max_element(v.begin(), v.end()); };
  std::size_t r_min = c;
  if (!opt.exact && !circular) {
    std::size_t lo = 0, hi = c;  // dropped energy is non-increasing in r: bisect
    while (lo < hi) {
      const std::size_t mid = (lo + hi) / 2;
      if (maxc(crop_channels(mid, true)) <= opt.crop_tolerance) hi = mid;
      else lo = mid + 1;
    }
    r_min = lo;
  }
  // Grid for a window of th x tw pixels and the largest radius >= r_min that grid holds.
  using Layout = Plan;
  auto layout = [&](bool tiled) {
    Layout L;
    L.th = tiled ? std::min(tpx, h) : h;
    L.tw = tiled ? std::min(tpx, w) : w;
    L.nty = tiled ? nty : 1;
    L.ntx = tiled ? ntx : 1;
    if (circular) {
      L.r = c;
      L.gy = h;
      L.gx = w;
      return L;
    }
    auto gy_of = [&](std::size_t r) { return grid_length(L.th, extent_neg(r, s_), extent_pos(r, s_), tiled); };
    auto gx_of = [&](std::size_t r) { return grid_length(L.tw, extent_neg(r, s_), extent_pos(r, s_), tiled); };
    L.r = r_min;
    L.gy = gy_of(L.r);
    L.gx = gx_of(L.r);
    while (L.r < c && gy_of(L.r + 1) <= L.gy && gx_of(L.r + 1) <= L.gx) ++L.r;
    return L;
  };

  // ---- Rule 3: tiles (greedy, smallest first, while the bound stays within budget) ----
  auto choose_tiles = [&](const Layout& L, std::vector<std::uint8_t>& skipped, std::vector<double>& bound_c) {
    skipped.assign(scenes * ntiles, 0);
    bound_c.assign(3, 0.0);
    std::vector<double> mb(bands, 0.0);  // max over skipped tiles, per band
    std::vector<std::pair<double, std::size_t>> cand;
    cand.reserve(scenes * ntiles);
    for (std::size_t k = 0; k < scenes; ++k)
      for (std::size_t t = 0; t < ntiles; ++t) {
        double v = 0;
        for (int ch = 0; ch < 3; ++ch) {
          double s = 0;
          for (std::size_t b : kept) s += srf_(ch, Eigen::Index(b)) * kept_at(b, L.r) * tmax[(k * bands + b) * ntiles + t];
          v = std::max(v, s);
        }
        cand.emplace_back(v, k * ntiles + t);
      }
    std::stable_sort(cand.begin(), cand.end(), [](const auto& x, const auto& y) { return x.first < y.first; });
    std::size_t count = 0;
    for (const auto& [v, id] : cand) {
      if (v > opt.tile_tolerance) break;
      const std::size_t k = id / ntiles, t = id % ntiles;
      std::vector<double> trial(3, 0.0);
      for (int ch = 0; ch < 3; ++ch)
        for (std::size_t b : kept)
          trial[std::size_t(ch)] += srf_(ch, Eigen::Index(b)) * kept_at(b, L.r) * std::max(mb[b], tmax[(k * bands + b) * ntiles + t]);
      if (maxc(trial) > opt.tile_tolerance) continue;
      for (std::size_t b : kept) mb[b] = std::max(mb[b], tmax[(k * bands + b) * ntiles + t]);
      bound_c = trial;
      skipped[id] = 1;
      ++count;
    }
    return count;
  };

  Layout L = layout(false);
  std::vector<std::uint8_t> tile_skip(scenes, 0);
  std::vector<double> tile_c(3, 0.0);
  bool tiled = false;
  if (may_tile) {
    const Layout T = layout(true);
    std::vector<std::uint8_t> ts;
    std::vector<double> tc;
    const std::size_t nskip = choose_tiles(T, ts, tc);
    const std::size_t windows = scenes * ntiles - nskip;
    const double cost_tiled = cost_model(windows, T.gy, T.gx, pairs), cost_whole = cost_model(scenes, L.gy, L.gx, pairs);
    if (opt.tiles == TileMode::On || cost_tiled < kTileGain * cost_whole) {
      tiled = true;
      L = T;
      tile_skip = ts;
      tile_c = tc;
    }
  }
  const std::vector<double> crop_c = crop_channels(L.r, false);

  rep.crop_radius_px = L.r;
  rep.cropped = L.r < c;
  rep.min_kept_energy = 1.0;
  for (std::size_t b : kept) rep.min_kept_energy = std::min(rep.min_kept_energy, kept_at(b, L.r));
  rep.grid_rows = L.gy;
  rep.grid_cols = L.gx;
  rep.tiled = tiled;
  rep.tile_px = tiled ? tpx : 0;
  rep.tiles_y = L.nty;
  rep.tiles_x = L.ntx;
  rep.tiles_total = scenes * L.nty * L.ntx;
  rep.tile_skipped = tile_skip;
  rep.tiles_skipped = std::size_t(std::count(tile_skip.begin(), tile_skip.end(), std::uint8_t(1)));
  rep.band_bound = maxc(band_c);
  rep.crop_bound = maxc(crop_c);
  rep.tile_bound = maxc(tile_c);
  rep.total_bound = 0;
  for (std::size_t ch = 0; ch < 3; ++ch) rep.total_bound = std::max(rep.total_bound, band_c[ch] + crop_c[ch] + tile_c[ch]);
  report_ = rep;
  L.kept = kept;
  L.tiled = tiled;
  L.tile_skip = tile_skip;
  return L;
}

std::vector<RealStack> Camera::images(const std::vector<RealStack>& cubes, const SkipOptions& opt) {
  // ---- Validation (before any device work) ----
  opt.validate();
  // An exact call keeps every band, so the upload below reads every value: it checks them there.
  check_batch(cubes, !opt.exact);
  vjp_ready_ = spectra_ready_ = false;
  const std::size_t h = cubes[0].rows, w = cubes[0].cols, scenes = cubes.size();
  const bool circular = cfg_.convolution == ConvolutionMode::Circular;
  if (circular && !opt.exact && opt.tiles == TileMode::On)
    reject("tiles", "on", "off or auto in circular convolution mode (tiles need linear convolution)");

  const Plan L = plan_images(cubes, opt);
  const std::vector<std::size_t>& kept = L.kept;
  const std::size_t nk = kept.size(), pairs = (nk + 1) / 2;
  const std::vector<std::uint8_t>& tile_skip = L.tile_skip;
  const bool tiled = L.tiled;

  // ---- Device work ----
  const std::size_t hw = h * w, g = L.gy * L.gx;
  bool one_chunk = false;  // every scene's spectra left in spec_ (vjp reuses them)
  auto& q = rt_.queue();
  if (nk > 0) {
    // Compacted kept bands of every scene on the device: scenes x K x H x W, converted plane by
    // plane from the scenes (no host copy of the whole batch). First, so that an exact call's
    // finiteness check (in the same pass) refuses a bad value before any kernel is launched.
    grow(cube_, cube_cap_, scenes * nk * hw * rsz_, CL_MEM_READ_ONLY);
    if (!upload_planes(q, cube_, prec_, scenes * nk, hw, [&](std::size_t j) { return cubes[j / nk].plane(kept[j % nk]); }))
      check_batch(cubes, true);  // throws, naming the first value that is not finite
  }
  grow(rgb_, rgb_cap_, scenes * 3 * hw * rsz_);
  q.enqueueFillBuffer(rgb_, cl_uint(0), 0, scenes * 3 * hw * rsz_);
  if (nk > 0) {
    ensure_otf(L.r, L.gy, L.gx, kept);
    // Windows (slots) and the tile -> slot map.
    std::vector<int> tiles, slot_of(scenes * L.nty * L.ntx, -1);
    for (std::size_t k = 0; k < scenes; ++k)
      for (std::size_t ty = 0; ty < L.nty; ++ty)
        for (std::size_t tx = 0; tx < L.ntx; ++tx) {
          const std::size_t id = (k * L.nty + ty) * L.ntx + tx;
          if (tile_skip[id]) continue;
          slot_of[id] = int(tiles.size() / 3);
          tiles.insert(tiles.end(), {int(k), int(ty * L.th), int(tx * L.tw)});
        }
    const std::size_t nslots = tiles.size() / 3;
    tiles.resize(std::max<std::size_t>(tiles.size(), 3), 0);
    grow(tiles_, tiles_cap_, tiles.size() * sizeof(int), CL_MEM_READ_ONLY);
    q.enqueueWriteBuffer(tiles_, CL_FALSE, 0, tiles.size() * sizeof(int), tiles.data());
    grow(slot_of_, slot_of_cap_, slot_of.size() * sizeof(int), CL_MEM_READ_ONLY);
    q.enqueueWriteBuffer(slot_of_, CL_FALSE, 0, slot_of.size() * sizeof(int), slot_of.data());
    // Response weights of the kept bands, 3 x 2P (zero-padded).
    std::vector<double> wt(3 * 2 * pairs, 0.0);
    for (std::size_t ch = 0; ch < 3; ++ch)
      for (std::size_t i = 0; i < nk; ++i) wt[ch * 2 * pairs + i] = srf_(Eigen::Index(ch), Eigen::Index(kept[i]));
    grow(wts_, wts_cap_, wt.size() * rsz_, CL_MEM_READ_ONLY);
    rt_.write_reals(wts_, wt.data(), wt.size(), prec_);
    if (nslots > 0) {
      const std::size_t per_slot = pairs * g * 2 * rsz_;
      const std::size_t chunk = std::max<std::size_t>(1, std::min(nslots, kMaxChunkBytes / per_slot));
      one_chunk = !tiled && nslots == scenes && chunk >= nslots;
      grow(spec_, spec_cap_, chunk * per_slot);
      grow(rgbspec_, rgbspec_cap_, chunk * 2 * g * 2 * rsz_);
      FftPlan& fwd = rt_.fft(L.gy, L.gx, chunk * pairs, prec_);
      FftPlan& inv = rt_.fft(L.gy, L.gx, chunk * 2, prec_);
      const std::size_t a = circular ? 0 : extent_neg(L.r, s_), b = circular ? 0 : extent_pos(L.r, s_);
      for (std::size_t base = 0; base < nslots; base += chunk) {
        const std::size_t count = std::min(chunk, nslots - base);
        launch_rows(rt_, k_place_, L.gx, chunk * pairs * L.gy, prec_, cube_, tiles_, spec_, int(h), int(w), int(nk), int(L.gy),
                      int(L.gx), int(L.th), int(L.tw), int(base), int(count), int(chunk));
        fwd.forward(spec_);
        launch_rows(rt_, k_combine_, L.gx, chunk * L.gy, prec_, spec_, otf_, wts_, rgbspec_, int(L.gy), int(L.gx), int(nk),
                      int(chunk));
        inv.inverse(rgbspec_);
        rt_.launch_1d(k_gather_, scenes * hw, prec_, rgbspec_, slot_of_, rgb_, int(h), int(w), int(L.gy), int(L.gx),
                      int(L.th), int(L.tw), int(L.nty), int(L.ntx), int(a), int(b), int(base), int(count), int(scenes));
        report_.forward_ffts += chunk * pairs;
        report_.inverse_ffts += chunk * 2;
      }
    }
  }
  cl::Buffer* result = &rgb_;
  if (cfg_.read_noise_sigma > 0 || cfg_.full_well_photons > 0) {
    grow(noisy_, noisy_cap_, scenes * 3 * hw * rsz_);
    rt_.launch_1d(k_noise_, scenes * 3 * hw, prec_, rgb_, eye_, noisy_, int(hw), 3, Real{cfg_.read_noise_sigma},
                  Real{cfg_.full_well_photons}, cl_uint(cfg_.noise_seed & 0xffffffffull),
                  cl_uint(cfg_.noise_seed >> 32), int(scenes));
    result = &noisy_;
  }
  // The single read-back of the call.
  std::vector<RealStack> out(scenes, RealStack(3, h, w));
  for (std::size_t k = 0; k < scenes; ++k) rt_.read_reals(*result, out[k].data.data(), 3 * hw, prec_, k * 3 * hw);
  vjp_ready_ = !tiled;
  spectra_ready_ = vjp_ready_ && one_chunk;
  return out;
}

namespace {
std::size_t chunk_slots(std::size_t nslots, std::size_t per_slot_bytes) {
  return std::max<std::size_t>(1, std::min(nslots, kMaxChunkBytes / std::max<std::size_t>(per_slot_bytes, 1)));
}
}  // namespace

Camera::Gradient Camera::vjp(const std::vector<RealStack>& g_rgb, bool want_scenes) {
  const SkipReport& rep = report_;
  if (rep.tiled) reject("vjp", "after a tiled images() call", "the adjoint of an untiled call (tiles off or exact)");
  if (!vjp_ready_) reject("vjp", "without a preceding images() call", "images() on this camera first (blur() in between discards its batch)");
  if (current_generation() != rep.psf_generation)
    throw Error("Camera::vjp: the PSF changed since the images() call it would differentiate");
  const std::size_t scenes = rep.scenes, h = rep.height, w = rep.width, hw = h * w, bands = rep.bands;
  if (g_rgb.size() != scenes) reject("g_rgb.size()", g_rgb.size(), "one gradient per scene of the last images() call (" + to_str(scenes) + ")");
  for (std::size_t k = 0; k < scenes; ++k) {
    if (g_rgb[k].planes != 3 || g_rgb[k].rows != h || g_rgb[k].cols != w)
      reject("g_rgb[" + to_str(k) + "]", shape(g_rgb[k]), "3 x H x W = " + shape(3, h, w));
    for (std::size_t i = 0; i < g_rgb[k].size(); ++i)
      if (!std::isfinite(g_rgb[k].data[i])) reject("g_rgb[" + to_str(k) + "][" + to_str(i) + "]", g_rgb[k].data[i], "finite values");
  }
  Gradient out;
  out.psf = RealStack(bands, s_, s_);
  if (want_scenes) out.scenes.assign(scenes, RealStack(bands, h, w));
  const std::vector<std::size_t>& kept = rep.bands_kept;
  const std::size_t nk = kept.size(), pairs = (nk + 1) / 2, gy = rep.grid_rows, gx = rep.grid_cols, g = gy * gx;
  if (nk == 0) return out;
  const bool reused = rep.otf_reused;
  ensure_otf(rep.crop_radius_px, gy, gx, kept);  // reused unless blur() changed it since
  report_.otf_reused = reused;                   // the report stays the images() call's

  auto& q = rt_.queue();
  grow(grgb_, grgb_cap_, scenes * 3 * hw * rsz_, CL_MEM_READ_ONLY);
  for (std::size_t k = 0; k < scenes; ++k) rt_.write_reals(grgb_, g_rgb[k].data.data(), 3 * hw, prec_, k * 3 * hw);
  const std::size_t chunk = chunk_slots(scenes, pairs * g * 2 * rsz_);
  // The scene spectra of the images() call, when it left them all in spec_ (same chunk layout).
  const bool reuse_spectra = spectra_ready_ && chunk >= scenes;
  grow(spec_, spec_cap_, chunk * pairs * g * 2 * rsz_);
  grow(rgbspec_, rgbspec_cap_, chunk * 2 * g * 2 * rsz_);
  if (want_scenes) {
    grow(gscene_, gscene_cap_, chunk * pairs * g * 2 * rsz_);
    grow(gout_, gout_cap_, scenes * nk * hw * rsz_);
  }
  grow(gpsf_, gpsf_cap_, pairs * g * 2 * rsz_);
  q.enqueueFillBuffer(gpsf_, cl_uint(0), 0, pairs * g * 2 * rsz_);
  FftPlan& fwd_pairs = rt_.fft(gy, gx, chunk * pairs, prec_);
  FftPlan& fwd_rgb = rt_.fft(gy, gx, chunk * 2, prec_);
  // Unused when !want_scenes (never written then, so passing spec_ twice keeps the kernel's restrict
  // promise: restrict only forbids a second path to an object that is modified).
  const cl::Buffer& scene_out = want_scenes ? gscene_ : spec_;
  for (std::size_t base = 0; base < scenes; base += chunk) {
    const std::size_t count = std::min(chunk, scenes - base);
    // Image gradients as two pair spectra per scene (R + iG, B), then the scene spectra again.
    launch_rows(rt_, k_place_, gx, chunk * 2 * gy, prec_, grgb_, tiles_, rgbspec_, int(h), int(w), 3, int(gy), int(gx), int(h),
                  int(w), int(base), int(count), int(chunk));
    fwd_rgb.forward(rgbspec_);
    if (!reuse_spectra) {
      launch_rows(rt_, k_place_, gx, chunk * pairs * gy, prec_, cube_, tiles_, spec_, int(h), int(w), int(nk), int(gy), int(gx),
                    int(h), int(w), int(base), int(count), int(chunk));
      fwd_pairs.forward(spec_);
    }
    launch_rows(rt_, k_vjp_spectra_, gx, pairs * gy, prec_, rgbspec_, spec_, otf_, wts_, scene_out, gpsf_, int(gy), int(gx),
                  int(nk), int(count), int(want_scenes ? 1 : 0));
    if (want_scenes) {
      fwd_pairs.inverse(gscene_);
      rt_.launch_1d(k_gather_pairs_, count * nk * hw, prec_, gscene_, gout_, int(h), int(w), int(nk), int(gy), int(gx),
                    int(base), int(count));
    }
  }
  rt_.fft(gy, gx, pairs, prec_).inverse(gpsf_);
  grow(gpsf_out_, gpsf_out_cap_, bands * s_ * s_ * rsz_);
  q.enqueueFillBuffer(gpsf_out_, cl_uint(0), 0, bands * s_ * s_ * rsz_);
  launch_rows(rt_, k_gather_psf_, s_, nk * s_, prec_, gpsf_, band_of_, gpsf_out_, int(s_), int(gy), int(gx),
                int(rep.crop_radius_px), int(nk));
  rt_.read_reals(gpsf_out_, out.psf.data.data(), out.psf.size(), prec_);
  if (want_scenes)
    for (std::size_t k = 0; k < scenes; ++k)
      for (std::size_t i = 0; i < nk; ++i) rt_.read_reals(gout_, out.scenes[k].plane(kept[i]), hw, prec_, (k * nk + i) * hw);
  return out;
}

std::vector<RealStack> Camera::blur(const std::vector<RealStack>& cubes) {
  check_batch(cubes);
  vjp_ready_ = spectra_ready_ = false;
  const std::size_t bands = cfg_.bands, h = cubes[0].rows, w = cubes[0].cols, scenes = cubes.size(), hw = h * w;
  const bool circular = cfg_.convolution == ConvolutionMode::Circular;
  const std::size_t c = s_ / 2;
  const std::size_t gy = circular ? h : grid_length(h, extent_neg(c, s_), extent_pos(c, s_), false);
  const std::size_t gx = circular ? w : grid_length(w, extent_neg(c, s_), extent_pos(c, s_), false);
  const std::size_t g = gy * gx, pairs = (bands + 1) / 2;
  std::vector<std::size_t> all(bands);
  std::iota(all.begin(), all.end(), 0);
  ensure_otf(c, gy, gx, all);
  std::vector<int> tiles;
  for (std::size_t k = 0; k < scenes; ++k) tiles.insert(tiles.end(), {int(k), 0, 0});
  grow(tiles_, tiles_cap_, tiles.size() * sizeof(int), CL_MEM_READ_ONLY);
  rt_.queue().enqueueWriteBuffer(tiles_, CL_TRUE, 0, tiles.size() * sizeof(int), tiles.data());
  grow(cube_, cube_cap_, scenes * bands * hw * rsz_, CL_MEM_READ_ONLY);
  for (std::size_t k = 0; k < scenes; ++k) rt_.write_reals(cube_, cubes[k].data.data(), bands * hw, prec_, k * bands * hw);
  const std::size_t chunk = chunk_slots(scenes, pairs * g * 2 * rsz_);
  grow(spec_, spec_cap_, chunk * pairs * g * 2 * rsz_);
  grow(gscene_, gscene_cap_, chunk * pairs * g * 2 * rsz_);
  grow(gout_, gout_cap_, scenes * bands * hw * rsz_);
  FftPlan& plan = rt_.fft(gy, gx, chunk * pairs, prec_);
  for (std::size_t base = 0; base < scenes; base += chunk) {
    const std::size_t count = std::min(chunk, scenes - base);
    launch_rows(rt_, k_place_, gx, chunk * pairs * gy, prec_, cube_, tiles_, spec_, int(h), int(w), int(bands), int(gy), int(gx),
                  int(h), int(w), int(base), int(count), int(chunk));
    plan.forward(spec_);
    rt_.launch_1d(k_multiply_, chunk * pairs * g, prec_, spec_, otf_, gscene_, int(gy), int(gx), int(pairs), int(chunk));
    plan.inverse(gscene_);
    rt_.launch_1d(k_gather_pairs_, count * bands * hw, prec_, gscene_, gout_, int(h), int(w), int(bands), int(gy),
                  int(gx), int(base), int(count));
  }
  std::vector<RealStack> out(scenes, RealStack(bands, h, w));
  for (std::size_t k = 0; k < scenes; ++k) rt_.read_reals(gout_, out[k].data.data(), bands * hw, prec_, k * bands * hw);
  return out;
}

}  // namespace qdo
