// Mask planning: the design's levels -> binary, nested or greyscale mask sets, with the
// fabrication-constraint checks (the height map's reconstruction is in fab_reconstruct.cpp). API
// and conventions: include/qdo/fab/fab.hpp.
#include "qdo/fab/fab.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "fab/fab_internal.hpp"
#include "qdo/runtime/error.hpp"

namespace qdo::fab {


namespace {

std::int64_t pitch_in_nm(double pitch_m) {
  const double p = pitch_m * 1e9, r = std::round(p);
  if (std::fabs(p - r) > 1e-6 || r < 2 || std::fmod(r, 2.0) != 0.0)
    reject("pitch_m", pitch_m,
           "an even whole number of nanometres (pixel edges at centre +- pitch/2 must lie on the 1 nm GDSII grid)");
  return static_cast<std::int64_t>(r);
}

// Pixels that belong to features (value 1) narrower than m pixels in x or y: those not covered
// by any m x m square lying entirely in the set (morphological opening). Outside the grid the
// map is `pad`. Returns a map of flagged pixels.
std::vector<std::uint8_t> narrow_pixels(const std::vector<std::uint8_t>& a, std::size_t n, std::size_t m, std::uint8_t pad) {
  const std::size_t P = n + 2 * m;
  std::vector<std::uint8_t> g(P * P, pad);
  for (std::size_t y = 0; y < n; ++y)
    for (std::size_t x = 0; x < n; ++x) g[(y + m) * P + x + m] = a[y * n + x] ? 1 : 0;
  // run[x] = consecutive ones to the right; e(y, x) = 1 when the m x m square at (y, x) is full.
  std::vector<std::uint32_t> right(P * P, 0), down(P * P, 0);
  for (std::size_t y = 0; y < P; ++y)
    for (std::size_t x = P; x-- > 0;)
      right[y * P + x] = g[y * P + x] ? 1 + (x + 1 < P ? right[y * P + x + 1] : 0) : 0;
  std::vector<std::uint8_t> e(P * P, 0);
  for (std::size_t x = 0; x < P; ++x)
    for (std::size_t y = P; y-- > 0;) {
      const bool row_ok = right[y * P + x] >= m;
      down[y * P + x] = row_ok ? 1 + (y + 1 < P ? down[(y + 1) * P + x] : 0) : 0;
      e[y * P + x] = down[y * P + x] >= m ? 1 : 0;
    }
  // Dilation: covered(y, x) when some e(y', x') with y - m < y' <= y, x - m < x' <= x (prefix sums).
  std::vector<std::uint32_t> s((P + 1) * (P + 1), 0);
  for (std::size_t y = 0; y < P; ++y)
    for (std::size_t x = 0; x < P; ++x)
      s[(y + 1) * (P + 1) + x + 1] = e[y * P + x] + s[y * (P + 1) + x + 1] + s[(y + 1) * (P + 1) + x] - s[y * (P + 1) + x];
  std::vector<std::uint8_t> out(n * n, 0);
  for (std::size_t y = 0; y < n; ++y)
    for (std::size_t x = 0; x < n; ++x) {
      if (!a[y * n + x]) continue;
      const std::size_t Y = y + m, X = x + m;  // padded coordinates
      const std::size_t y0 = Y + 1 - m, x0 = X + 1 - m;
      const std::uint32_t c = s[(Y + 1) * (P + 1) + X + 1] - s[y0 * (P + 1) + X + 1] - s[(Y + 1) * (P + 1) + x0] + s[y0 * (P + 1) + x0];
      if (c == 0) out[y * n + x] = 1;
    }
  return out;
}

void check_min_feature(const Mask& mk, std::size_t n, double pitch_m, double min_feature_um) {
  if (!(min_feature_um > 0)) return;
  const double px = min_feature_um * 1e-6 / pitch_m;
  const std::size_t m = static_cast<std::size_t>(std::ceil(px - 1e-9));
  if (m <= 1) return;  // every feature is at least one pixel wide
  for (int pass = 0; pass < 2; ++pass) {
    std::vector<std::uint8_t> a = mk.drawn;
    if (pass == 1)
      for (auto& v : a) v = v ? 0 : 1;  // gaps: the closed (unetched) region, the outside counts as closed
    const auto bad = narrow_pixels(a, n, m, pass == 1 ? 1 : 0);
    std::size_t count = 0, first = 0, r0 = n, r1 = 0, c0 = n, c1 = 0;
    for (std::size_t i = 0; i < bad.size(); ++i)
      if (bad[i]) {
        if (!count) first = i;
        ++count;
        r0 = std::min(r0, i / n);
        r1 = std::max(r1, i / n);
        c0 = std::min(c0, i % n);
        c1 = std::max(c1, i % n);
      }
    if (count)
      throw InputError(mk.name + " (layer " + std::to_string(mk.layer) + "): " + std::to_string(count) + " pixel(s) " +
                       (pass == 0 ? "of drawn (etched) features" : "of gaps between drawn features") +
                       " narrower than the minimum feature size " + to_str(min_feature_um) + " um (" + std::to_string(m) +
                       " pixels at " + to_str(pitch_m * 1e6) + " um pitch; --min-feature-um), first at " + pixel_name(first, n) +
                       ", region rows " + std::to_string(r0) + ".." + std::to_string(r1) + ", cols " + std::to_string(c0) + ".." +
                       std::to_string(c1));
  }
}

double interpolate_dose(const std::vector<std::pair<double, double>>& curve, double depth_nm, int level) {
  if (curve.size() < 2) reject("dose curve", curve.size(), "at least two (depth_nm, dose) points");
  for (std::size_t k = 1; k < curve.size(); ++k)
    if (!(curve[k].first > curve[k - 1].first)) reject("dose curve depth_nm", curve[k].first, "strictly increasing depths");
  if (depth_nm < curve.front().first - 1e-9 || depth_nm > curve.back().first + 1e-9)
    reject("level " + std::to_string(level) + " etch depth (nm)", depth_nm,
           "within the dose curve's calibrated range [" + to_str(curve.front().first) + ", " + to_str(curve.back().first) + "] nm");
  for (std::size_t k = 1; k < curve.size(); ++k)
    if (depth_nm <= curve[k].first) {
      const double t = (depth_nm - curve[k - 1].first) / (curve[k].first - curve[k - 1].first);
      return curve[k - 1].second + std::clamp(t, 0.0, 1.0) * (curve[k].second - curve[k - 1].second);
    }
  return curve.back().second;
}

}  // namespace

Scheme scheme_from_string(const std::string& s) {
  if (s == "binary") return Scheme::Binary;
  if (s == "nested") return Scheme::Nested;
  if (s == "greyscale" || s == "grayscale") return Scheme::Greyscale;
  reject("scheme", s, "binary, nested or greyscale");
}

std::string to_string(Scheme s) {
  switch (s) {
    case Scheme::Binary: return "binary";
    case Scheme::Nested: return "nested";
    case Scheme::Greyscale: return "greyscale";
  }
  return "?";
}

// ------------------------------------------------------------------------------------------------
// Planning

MaskPlan plan_masks(const Design& d, const SystemConfig& cfg, Scheme scheme, const Constraints& c,
                    const std::vector<std::pair<double, double>>& dose_curve) {
  const Map2D& h = d.height_m;
  const std::size_t n = h.rows;
  if (n == 0 || h.cols != n || h.data.size() != n * n) reject("design", to_str(h.rows) + " x " + to_str(h.cols), "a square N x N map");
  if (n != cfg.n) reject("design", to_str(n) + " x " + to_str(n), "the configuration's N x N = " + to_str(cfg.n) + " x " + to_str(cfg.n));
  if (!(c.level_tolerance_nm > 0)) reject("level_tolerance_nm", c.level_tolerance_nm, "> 0");
  if (c.min_feature_um < 0 || !std::isfinite(c.min_feature_um)) reject("min_feature_um", c.min_feature_um, ">= 0");
  if (c.max_levels < 0) reject("max_levels", c.max_levels, ">= 0 (0: the scheme's limit)");
  if (c.max_height_nm < 0 || !std::isfinite(c.max_height_nm)) reject("max_height_nm", c.max_height_nm, ">= 0 (0: h_max)");
  const double tol = c.level_tolerance_nm * 1e-9;
  MaskPlan plan;
  plan.scheme = scheme;
  plan.method = scheme == Scheme::Nested ? "L - 1 nested masks, free steps" : scheme == Scheme::Greyscale ? "one layer per level" : "";
  plan.n = n;
  plan.pitch_m = cfg.pitch_m;
  plan.pitch_nm = pitch_in_nm(cfg.pitch_m);
  plan.h_max_m = cfg.h_max_m();
  const double max_h = c.max_height_nm > 0 ? c.max_height_nm * 1e-9 : plan.h_max_m;

  // 1. The level table and every pixel's level.
  std::vector<double> table = d.levels_m;
  if (table.empty()) {
    std::vector<double> v = h.data;
    std::sort(v.begin(), v.end());
    for (double x : v)
      if (table.empty() || x - table.back() > tol) table.push_back(x);
    if (table.size() > 65536)
      reject("design", to_str(table.size()) + " distinct heights", "a quantized design (at most 65536 levels; qdo quantize)");
  }
  for (std::size_t l = 0; l < table.size(); ++l)
    if (!std::isfinite(table[l])) reject("level " + std::to_string(l) + " height", table[l], "finite");
  std::vector<std::pair<double, int>> sorted;
  for (std::size_t l = 0; l < table.size(); ++l) sorted.push_back({table[l], int(l)});
  std::sort(sorted.begin(), sorted.end());
  plan.levels.resize(table.size());
  std::vector<std::size_t> first_pixel(table.size(), 0);
  for (std::size_t l = 0; l < table.size(); ++l) {
    plan.levels[l].index = int(l);
    plan.levels[l].height_m = table[l];
  }
  plan.level_of_pixel.assign(n * n, -1);
  for (std::size_t i = 0; i < n * n; ++i) {
    const double v = h.data[i];
    if (!std::isfinite(v)) throw InputError(pixel_name(i, n) + " has a non-finite height");
    auto it = std::lower_bound(sorted.begin(), sorted.end(), std::pair<double, int>{v - tol, -1});
    int best = -1;  // levels within the tolerance are one height: take the lowest table index
    for (; it != sorted.end() && it->first <= v + tol; ++it)
      if (best < 0 || it->second < best) best = it->second;
    if (best < 0) {
      auto nb = std::lower_bound(sorted.begin(), sorted.end(), std::pair<double, int>{v, -1});
      if (nb == sorted.end()) --nb;
      throw InputError(pixel_name(i, n) + " has height " + nm(v) + " nm, none of the design's " + std::to_string(table.size()) +
                       " level heights (nearest: level " + std::to_string(nb->second) + " at " + nm(nb->first) +
                       " nm): export quantized designs only (qdo quantize, or a run's design.h5)");
    }
    auto& L = plan.levels[std::size_t(best)];
    if (L.pixels++ == 0) first_pixel[std::size_t(best)] = i;
    plan.level_of_pixel[i] = best;
  }

  // 2. Etchable range and level count.
  std::vector<int> used;
  for (const auto& L : plan.levels)
    if (L.pixels) used.push_back(L.index);
  for (int l : used) {
    const double v = table[std::size_t(l)];
    if (v < -tol || v > max_h + tol)
      throw InputError("level " + std::to_string(l) + " (height " + nm(v) + " nm, " + std::to_string(plan.levels[std::size_t(l)].pixels) +
                       " pixels, first at " + pixel_name(first_pixel[std::size_t(l)], n) + ") lies outside the etchable range [0, " +
                       nm(max_h) + "] nm of the relief above the base plate (--max-height-nm; default h_max)");
  }
  // Distinct used heights, descending (groups of levels equal within the tolerance).
  std::vector<double> groups;
  {
    std::vector<double> hs;
    for (int l : used) hs.push_back(table[std::size_t(l)]);
    std::sort(hs.begin(), hs.end(), std::greater<double>());
    for (double v : hs)
      if (groups.empty() || groups.back() - v > tol) groups.push_back(v);
  }
  const int max_levels = c.max_levels > 0 ? c.max_levels : scheme_max_levels(scheme);
  if (int(groups.size()) > max_levels || int(groups.size()) > kMaxMaskLayers + 1)
    throw InputError("the design uses " + std::to_string(groups.size()) + " distinct level heights; the " + to_string(scheme) +
                     " scheme allows at most " + std::to_string(std::min(max_levels, kMaxMaskLayers + 1)) +
                     " (--max-levels; REFERENCE §6: mature multi-level lithography makes <= 16)");
  if (groups.size() < 2) throw InputError("the design uses a single level height (" + nm(groups.front()) + " nm): there is nothing to etch");
  auto group_of = [&](double v) {
    for (std::size_t g = 0; g < groups.size(); ++g)
      if (std::fabs(groups[g] - v) <= tol) return int(g);
    return -1;
  };

  // 3. The masks of the scheme.
  if (scheme == Scheme::Binary) {
    const std::size_t L = table.size();
    std::size_t k = 0;
    while ((std::size_t(1) << k) < L) ++k;
    std::string fail_a, fail_b;
    std::vector<double> depth;
    std::vector<std::uint64_t> code(L, 0);
    bool ok = false;
    // (a) index-coded: level l etched by the masks j with bit j of l clear.
    if ((std::size_t(1) << k) == L && k >= 1) {
      const double top = table[L - 1];
      depth.assign(k, 0.0);
      ok = top <= max_h + tol;
      if (!ok) fail_a = "level " + std::to_string(L - 1) + " (the top of the index code) lies above the etchable range";
      for (std::size_t j = 0; j < k && ok; ++j) {
        depth[j] = top - table[L - 1 - (std::size_t(1) << j)];
        if (depth[j] < -tol) {
          ok = false;
          fail_a = "level " + std::to_string(L - 1 - (std::size_t(1) << j)) + " lies above the top level " + std::to_string(L - 1);
        }
        depth[j] = std::max(depth[j], 0.0);
      }
      for (std::size_t l = 0; l < L && ok; ++l) {
        const std::uint64_t cl = (~std::uint64_t(l)) & (L - 1);
        double e = 0;
        for (std::size_t j = 0; j < k; ++j)
          if (cl & (std::uint64_t(1) << j)) e += depth[j];
        code[l] = cl;
        if (std::fabs((top - table[l]) - e) > tol) {
          ok = false;
          fail_a = "level " + std::to_string(l) + " (" + nm(table[l]) + " nm, etch " + nm(top - table[l]) +
                   " nm below the top level) is not the sum of the depths of its binary index code (" + nm(e) + " nm)";
        }
      }
      if (ok) {
        plan.method = "index-coded";
        plan.top_m = top;
      }
    }
    // (b) multiples of the smallest step d.
    if (!ok) {
      const double top = groups.front();
      double dstep = std::numeric_limits<double>::infinity();
      for (double g : groups)
        if (top - g > tol) dstep = std::min(dstep, top - g);
      std::uint64_t maxm = 0;
      bool okb = true;
      std::vector<std::uint64_t> codeb(L, 0);
      for (std::size_t l = 0; l < L && okb; ++l) {
        const double e = top - table[l];
        const double m = std::round(e / dstep);
        const bool fits = m >= 0 && m < 1e6 && std::fabs(e - m * dstep) <= tol;
        if (!fits) {
          if (plan.levels[l].pixels == 0) continue;  // unused levels need no code
          okb = false;
          fail_b = "level " + std::to_string(l) + " (" + nm(table[l]) + " nm, etch " + nm(e) + " nm below the top level " + nm(top) +
                   " nm) is not a whole multiple of the smallest step d = " + nm(dstep) + " nm";
          break;
        }
        codeb[l] = static_cast<std::uint64_t>(m);
        if (plan.levels[l].pixels) maxm = std::max(maxm, codeb[l]);
      }
      if (okb) {
        std::size_t kb = 0;
        while ((std::uint64_t(1) << kb) <= maxm) ++kb;
        int allowed = 0;
        while ((1 << (allowed + 1)) <= max_levels) ++allowed;
        if (int(kb) > allowed)
          throw InputError("the design's levels need " + std::to_string(kb) + " binary masks (etch depths up to " +
                           std::to_string(maxm) + " x d = " + nm(double(maxm) * dstep) + " nm); the binary scheme allows at most " +
                           std::to_string(allowed) + " (" + std::to_string(max_levels) + " levels; --max-levels)");
        k = kb;
        depth.assign(k, 0.0);
        for (std::size_t j = 0; j < k; ++j) depth[j] = double(std::uint64_t(1) << j) * dstep;
        code = codeb;
        plan.method = "multiples of d";
        plan.top_m = top;
        ok = true;
      }
    }
    if (!ok)
      throw InputError("binary-coded masks cannot make this design: " + (fail_a.empty() ? fail_b : fail_a) +
                       (fail_a.empty() || fail_b.empty() ? "" : "; nor as multiples of a step: " + fail_b) +
                       ". Binary masks only make levels that are subset sums of k etch depths: use --scheme nested "
                       "(L - 1 masks, free step heights) or greyscale, or train with --mode qdo+m");
    {
      int allowed = 0;
      while ((1 << (allowed + 1)) <= max_levels) ++allowed;
      if (int(k) > allowed)
        throw InputError("the design needs " + std::to_string(k) + " binary masks (" + std::to_string(L) +
                         " table levels); the binary scheme allows at most " + std::to_string(allowed) + " (--max-levels " +
                         std::to_string(max_levels) + ")");
    }
    for (std::size_t j = 0; j < k; ++j) {
      Mask mk;
      mk.layer = int(j) + 1;
      mk.name = "mask " + std::to_string(j + 1);
      mk.etch_depth_m = depth[j];
      mk.drawn.assign(n * n, 0);
      plan.masks.push_back(std::move(mk));
    }
    for (std::size_t l = 0; l < L; ++l)
      for (std::size_t j = 0; j < k; ++j)
        if (code[l] & (std::uint64_t(1) << j)) plan.levels[l].masks.push_back(int(j));
  } else {
    plan.top_m = groups.front();
    const std::size_t G = groups.size();
    double emax = plan.top_m - groups.back();
    if (scheme == Scheme::Nested) {
      for (std::size_t m = 1; m < G; ++m) {
        Mask mk;
        mk.layer = int(m);
        mk.name = "mask " + std::to_string(m);
        mk.etch_depth_m = groups[m - 1] - groups[m];
        mk.drawn.assign(n * n, 0);
        plan.masks.push_back(std::move(mk));
      }
    } else {
      for (std::size_t g = 0; g < G; ++g) {
        Mask mk;
        mk.layer = int(g) + 1;
        mk.name = "grey level " + std::to_string(g + 1);
        mk.etch_depth_m = plan.top_m - groups[g];
        mk.relative_dose = dose_curve.empty() ? (emax > 0 ? mk.etch_depth_m / emax : 0.0)
                                              : interpolate_dose(dose_curve, mk.etch_depth_m * 1e9, int(g));
        mk.drawn.assign(n * n, 0);
        plan.masks.push_back(std::move(mk));
      }
    }
    for (auto& L : plan.levels) {
      const int g = group_of(L.height_m);
      if (g < 0) continue;  // an unused level at a height no used level has: not fabricated
      if (scheme == Scheme::Nested)
        for (int m = 0; m < g; ++m) L.masks.push_back(m);
      else
        L.masks.push_back(g);
    }
  }
  for (auto& L : plan.levels) {
    double e = 0;
    for (int m : L.masks) e += plan.masks[std::size_t(m)].etch_depth_m;
    L.etch_depth_m = scheme == Scheme::Greyscale && !L.masks.empty() ? plan.masks[std::size_t(L.masks[0])].etch_depth_m : e;
  }
  for (std::size_t i = 0; i < n * n; ++i)
    for (int m : plan.levels[std::size_t(plan.level_of_pixel[i])].masks) plan.masks[std::size_t(m)].drawn[i] = 1;
  for (auto& mk : plan.masks) mk.pixels = std::size_t(std::count(mk.drawn.begin(), mk.drawn.end(), std::uint8_t(1)));
  if (plan.top_m - groups.back() > max_h + tol)
    throw InputError("the deepest etch, " + nm(plan.top_m - groups.back()) + " nm, exceeds the etchable range " + nm(max_h) + " nm");
  if (plan.masks.size() > std::size_t(kMaxMaskLayers))
    throw InputError("the scheme needs " + std::to_string(plan.masks.size()) + " mask layers; GDS layers 1.." +
                     std::to_string(kMaxMaskLayers) + " are available");

  // 4. Minimum feature size per mask.
  for (const auto& mk : plan.masks) check_min_feature(mk, n, plan.pitch_m, c.min_feature_um);
  return plan;
}

}  // namespace qdo::fab
