#include "qdo/fab.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <memory>
#include <numeric>
#include <sstream>

#include "qdo/cpu_reference.hpp"
#include "qdo/datasets.hpp"
#include "qdo/design_run.hpp"
#include "qdo/error.hpp"
#include "qdo/io.hpp"
#include "json_strict.hpp"
#include "qdo/optics.hpp"
#include "qdo/simulator.hpp"
#include "qdo/testset.hpp"
#include "qdo/wiener.hpp"

namespace fs = std::filesystem;
using nlohmann::json;

namespace qdo::fab {
namespace {

std::string nm(double metres, int digits = 3) {
  char b[64];
  std::snprintf(b, sizeof b, "%.*f", digits, metres * 1e9);
  return b;
}

std::string pixel_name(std::size_t idx, std::size_t n) {
  return "pixel (row " + std::to_string(idx / n) + ", col " + std::to_string(idx % n) + ")";
}

std::int64_t pitch_in_nm(double pitch_m) {
  const double p = pitch_m * 1e9, r = std::round(p);
  if (std::fabs(p - r) > 1e-6 || r < 2 || std::fmod(r, 2.0) != 0.0)
    reject("pitch_m", pitch_m,
           "an even whole number of nanometres (pixel edges at centre +- pitch/2 must lie on the 1 nm GDSII grid)");
  return static_cast<std::int64_t>(r);
}

// Corner of pixel (0, 0) in nm: the optical axis (sample (N/2, N/2)) at the origin.
std::int64_t origin_nm(std::size_t n, std::int64_t pitch_nm) {
  return -(std::int64_t(n / 2) * pitch_nm) - pitch_nm / 2;
}

int scheme_max_levels(Scheme s) { return s == Scheme::Greyscale ? kMaxMaskLayers : 16; }

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

// ------------------------------------------------------------------------------------------------
// Reconstruction

namespace {

struct PlanInfo {  // what reconstruction needs, from a plan or a manifest
  Scheme scheme = Scheme::Binary;
  std::size_t n = 0;
  double top_m = 0;
  std::vector<double> depth_m;                       // per mask
  std::vector<std::pair<std::vector<int>, int>> codes;  // (sorted mask set, level index) of used levels
  std::vector<double> level_height_m;
};

Reconstruction reconstruct_info(const PlanInfo& p, const std::vector<std::vector<std::uint8_t>>& drawn) {
  const std::size_t n = p.n, K = p.depth_m.size();
  if (drawn.size() != K) reject("masks", drawn.size(), "one bitmap per mask (" + std::to_string(K) + ")");
  for (const auto& d : drawn)
    if (d.size() != n * n) reject("mask bitmap size", d.size(), "N x N = " + std::to_string(n * n));
  std::map<std::string, int> lookup;
  for (const auto& [set, l] : p.codes) {
    std::string key(K, '0');
    for (int m : set) key[std::size_t(m)] = '1';
    lookup.emplace(key, l);
  }
  Reconstruction r;
  r.height_m = Map2D(n, n);
  r.level_of_pixel.assign(n * n, -1);
  std::string key(K, '0');
  for (std::size_t i = 0; i < n * n; ++i) {
    double e = 0;
    for (std::size_t m = 0; m < K; ++m) {
      key[m] = drawn[m][i] ? '1' : '0';
      if (drawn[m][i]) e += p.depth_m[m];
    }
    r.height_m.data[i] = p.top_m - e;
    const auto it = lookup.find(key);
    if (it != lookup.end()) r.level_of_pixel[i] = it->second;
  }
  return r;
}

PlanInfo info_of(const MaskPlan& plan) {
  PlanInfo p;
  p.scheme = plan.scheme;
  p.n = plan.n;
  p.top_m = plan.top_m;
  for (const auto& m : plan.masks) p.depth_m.push_back(m.etch_depth_m);
  for (const auto& L : plan.levels) {
    p.level_height_m.push_back(L.height_m);
    if (L.pixels) {
      std::vector<int> s = L.masks;
      std::sort(s.begin(), s.end());
      p.codes.push_back({s, L.index});
    }
  }
  return p;
}

}  // namespace

Reconstruction reconstruct(const MaskPlan& plan, const std::vector<std::vector<std::uint8_t>>& drawn) {
  return reconstruct_info(info_of(plan), drawn);
}

Reconstruction reconstruct_export(const std::string& dir) {
  const fs::path mpath = fs::path(dir) / "manifest.json";
  std::ifstream f(readable_output(mpath.string()));  // its temporary name while the command's outputs are staged
  if (!f) throw InputError("file '" + mpath.string() + "': cannot open (not an export folder?)");
  json j;
  try {
    j = parse_json_strict(std::string(std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>()),
                          "file '" + mpath.string() + "'");
  } catch (const json::exception& e) {
    throw InputError("file '" + mpath.string() + "': " + e.what());
  }
  PlanInfo p;
  std::int64_t pitch = 0, org = 0;
  std::map<int, std::size_t> layer_to_mask;
  std::string gds_name;
  try {
    p.scheme = scheme_from_string(j.at("scheme").get<std::string>());
    p.n = j.at("grid").at("n").get<std::size_t>();
    pitch = j.at("grid").at("pitch_nm").get<std::int64_t>();
    org = j.at("grid").at("pixel_00_corner_nm").at(0).get<std::int64_t>();
    p.top_m = j.at("blank_top_nm").get<double>() * 1e-9;
    gds_name = j.at("gds").at("file").get<std::string>();
    for (const auto& m : j.at("masks")) {
      layer_to_mask[m.at("layer").get<int>()] = p.depth_m.size();
      p.depth_m.push_back(m.at("etch_depth_nm").get<double>() * 1e-9);
    }
    for (const auto& L : j.at("levels")) {
      p.level_height_m.push_back(L.at("height_nm").get<double>() * 1e-9);
      if (L.at("pixels").get<std::size_t>() == 0) continue;
      std::vector<int> set;
      for (const auto& lay : L.at("mask_layers")) set.push_back(int(layer_to_mask.at(lay.get<int>())));
      std::sort(set.begin(), set.end());
      p.codes.push_back({set, L.at("index").get<int>()});
    }
  } catch (const json::exception& e) {
    throw InputError("file '" + mpath.string() + "': " + e.what());
  } catch (const std::out_of_range&) {
    throw InputError("file '" + mpath.string() + "': a level names a mask layer that is not in \"masks\"");
  }
  if (pitch <= 0 || p.n == 0) throw InputError("file '" + mpath.string() + "': grid n and pitch_nm must be positive");
  if (gds_name.empty() || gds_name.find('/') != std::string::npos || gds_name == "." || gds_name == "..")
    throw InputError("file '" + mpath.string() + "': gds.file = '" + gds_name + "' must name a file in the export folder");
  const gds::Library lib = gds::read(readable_output((fs::path(dir) / gds_name).string()));
  if (std::fabs(lib.db_in_metres - 1e-9) > 1e-15)
    throw InputError("GDSII '" + gds_name + "': database unit " + to_str(lib.db_in_metres) + " m, expected 1e-9 (1 nm)");
  std::vector<std::vector<gds::Polygon>> polys(p.depth_m.size());
  for (const auto& b : lib.boundaries) {
    const auto it = layer_to_mask.find(b.layer);
    if (it == layer_to_mask.end()) continue;  // marks, aperture
    gds::Polygon g;
    for (const auto& q : b.points) {
      const std::int64_t dx = q.x - org, dy = q.y - org;
      if (dx % pitch || dy % pitch)
        throw InputError("GDSII '" + gds_name + "' layer " + std::to_string(b.layer) + ": vertex (" + std::to_string(q.x) + ", " +
                         std::to_string(q.y) + ") nm is not on the pixel grid");
      g.push_back({dx / pitch, dy / pitch});
    }
    polys[it->second].push_back(std::move(g));
  }
  std::vector<std::vector<std::uint8_t>> drawn;
  for (const auto& pl : polys) drawn.push_back(gds::rasterize(pl, p.n, p.n));
  return reconstruct_info(p, drawn);
}

// ------------------------------------------------------------------------------------------------
// Export

namespace {

gds::Polygon cross_polygon(std::int64_t cx, std::int64_t cy, std::int64_t arm, std::int64_t half_w) {
  const std::int64_t a = arm, w = half_w;
  const std::int64_t pts[12][2] = {{-w, -a}, {w, -a}, {w, -w}, {a, -w}, {a, w},  {w, w},
                                   {w, a},   {-w, a}, {-w, w}, {-a, w}, {-a, -w}, {-w, -w}};
  gds::Polygon p;
  for (const auto& q : pts) p.push_back({cx + q[0], cy + q[1]});
  p.push_back(p.front());
  return p;
}

gds::Polygon disk_polygon(double radius_nm, std::size_t vertices) {
  gds::Polygon p;
  for (std::size_t k = 0; k < vertices; ++k) {
    const double t = 2.0 * M_PI * double(k) / double(vertices);
    const gds::Point q{std::llround(radius_nm * std::cos(t)), std::llround(radius_nm * std::sin(t))};
    if (p.empty() || q != p.back()) p.push_back(q);
  }
  if (p.back() == p.front()) p.pop_back();
  p.push_back(p.front());
  return p;
}

std::string md_escape(const std::string& s) {
  std::string o;
  for (char ch : s) o += ch == '|' ? std::string("\\|") : std::string(1, ch);
  return o;
}

}  // namespace

ExportResult export_design(const Design& d, const SystemConfig& cfg, const ExportOptions& o) {
  if (o.out.empty()) reject("out", "(missing)", "an output folder");
  std::vector<std::pair<double, double>> curve;
  if (!o.dose_curve_csv.empty()) {
    if (o.scheme != Scheme::Greyscale) reject("dose_curve", o.dose_curve_csv, "only with the greyscale scheme");
    const CsvTable t = read_csv(o.dose_curve_csv);
    const auto& dep = t.column("depth_nm");
    const auto& dose = t.column("dose");
    for (std::size_t i = 0; i < dep.size(); ++i) {
      if (!std::isfinite(dep[i]) || !std::isfinite(dose[i])) reject("dose curve row " + std::to_string(i + 1), o.dose_curve_csv, "numbers");
      curve.push_back({dep[i], dose[i]});
    }
  }
  ExportResult res;
  res.plan = plan_masks(d, cfg, o.scheme, o.constraints, curve);  // every check before any writing
  const MaskPlan& plan = res.plan;
  const std::size_t n = plan.n;
  const std::int64_t p = plan.pitch_nm, org = origin_nm(n, p);
  if (!(o.mark_arm_um > o.mark_width_um && o.mark_width_um > 0 && o.mark_margin_um > o.mark_arm_um))
    reject("alignment mark", to_str(o.mark_arm_um) + "/" + to_str(o.mark_width_um) + "/" + to_str(o.mark_margin_um),
           "margin > arm > width > 0 (um)");
  if (o.aperture_vertices < 16 || o.aperture_vertices > 8000) reject("aperture_vertices", o.aperture_vertices, "in [16, 8000]");

  // GDSII library: mask layers, marks, aperture.
  gds::Library lib;
  lib.name = "QDO_" + to_string(plan.scheme);
  std::vector<std::size_t> mask_polys(plan.masks.size(), 0), mask_verts(plan.masks.size(), 0);
  for (std::size_t m = 0; m < plan.masks.size(); ++m) {
    const Mask& mk = plan.masks[m];
    for (auto& poly : gds::merge_pixels(mk.drawn, n, n)) {
      gds::Boundary b;
      b.layer = mk.layer;
      for (auto& q : poly) b.points.push_back({org + q.x * p, org + q.y * p});
      mask_verts[m] += b.points.size() - 1;
      ++mask_polys[m];
      lib.boundaries.push_back(std::move(b));
    }
    res.polygons += mask_polys[m];
    res.vertices += mask_verts[m];
  }
  const std::int64_t half_field = std::int64_t(n / 2) * p + p / 2;
  const std::int64_t mc = half_field + std::llround(o.mark_margin_um * 1e3);
  const std::int64_t arm = std::llround(o.mark_arm_um * 1e3), hw = std::llround(o.mark_width_um * 1e3 / 2);
  for (int sx : {-1, 1})
    for (int sy : {-1, 1}) lib.boundaries.push_back({kMarkLayer, 0, cross_polygon(sx * mc, sy * mc, arm, hw)});
  lib.boundaries.push_back({kApertureLayer, 0, disk_polygon(cfg.aperture_radius() * 1e9, o.aperture_vertices)});

  make_output_dir(o.out, "out");
  const fs::path dir(o.out);
  gds::write((dir / "masks.gds").string(), lib);
  res.files.push_back("masks.gds");

  // Manifest.
  json j;
  j["format"] = "qdo fab export 1";
  j["scheme"] = to_string(plan.scheme);
  j["method"] = plan.method;
  j["scheme_note"] = plan.scheme == Scheme::Binary
                         ? "k binary-coded masks; a level's etch is the sum of the depths of the masks open over it"
                     : plan.scheme == Scheme::Nested
                         ? "L - 1 nested masks in order; mask m opens every pixel at or below the m-th highest level and etches one free step"
                         : "one layer per level written in a single greyscale exposure; dose per layer from the dose table";
  j["gds"] = {{"file", "masks.gds"},
              {"library", lib.name},
              {"structure", lib.structure},
              {"database_unit_m", 1e-9},
              {"user_unit_m", 1e-6},
              {"datatype", 0},
              {"alignment_mark_layer", kMarkLayer},
              {"aperture_layer", kApertureLayer}};
  j["material"] = cfg.material;
  j["base_wavelength_nm"] = cfg.base_wavelength_nm;
  j["h_max_nm"] = plan.h_max_m * 1e9;
  j["base_plate_m"] = cfg.base_plate_m;
  j["aperture_radius_m"] = cfg.aperture_radius();
  j["pitch_m"] = cfg.pitch_m;
  j["grid"] = {{"n", n},
               {"pitch_nm", p},
               {"pixel_00_corner_nm", {org, org}},
               {"mapping", "pixel (row i, col j) covers x in [c + j p, c + (j+1) p], y in [c + i p, c + (i+1) p] nm, c = pixel_00_corner_nm; "
                           "the optical axis (sample (N/2, N/2)) at the origin; y grows with the row (a GDS viewer shows the PNGs flipped vertically)"}};
  j["blank_top_nm"] = plan.top_m * 1e9;
  j["etch_convention"] =
      "H is the glass relief above the base plate. The blank's unetched surface is the highest level (blank_top_nm); each pixel is etched "
      "by etch_depth_nm = blank_top - H. REFERENCE's etch depth h_max - H (etch_depth_from_h_max_nm) differs by the constant h_max - "
      "blank_top (a uniformly thinner relief layer: only a constant phase).";
  j["tone"] = "drawn polygons = open (etched) regions: dark-field masks for a positive resist (invert for a negative resist)";
  std::map<int, int> layer_of;
  for (std::size_t m = 0; m < plan.masks.size(); ++m) layer_of[int(m)] = plan.masks[m].layer;
  j["levels"] = json::array();
  for (const auto& L : plan.levels) {
    json lj;
    lj["index"] = L.index;
    lj["height_nm"] = L.height_m * 1e9;
    lj["etch_depth_nm"] = (plan.top_m - L.height_m) * 1e9;
    lj["etch_depth_from_h_max_nm"] = (plan.h_max_m - L.height_m) * 1e9;
    lj["pixels"] = L.pixels;
    json layers = json::array();
    for (int m : L.masks) layers.push_back(layer_of[m]);
    lj["mask_layers"] = layers;
    if (!L.pixels) lj["note"] = "unused: not fabricated";
    j["levels"].push_back(lj);
  }
  j["masks"] = json::array();
  for (std::size_t m = 0; m < plan.masks.size(); ++m) {
    const Mask& mk = plan.masks[m];
    json mj;
    mj["layer"] = mk.layer;
    mj["name"] = mk.name;
    mj["etch_depth_nm"] = mk.etch_depth_m * 1e9;
    mj["tone"] = "dark-field (drawn = open = etched)";
    mj["polygons"] = mask_polys[m];
    mj["vertices"] = mask_verts[m];
    mj["open_pixels"] = mk.pixels;
    mj["open_area_um2"] = double(mk.pixels) * double(p) * double(p) * 1e-6;
    if (plan.scheme == Scheme::Greyscale) mj["relative_dose"] = mk.relative_dose;
    mj["preview"] = "mask_L" + std::to_string(mk.layer) + ".png";
    j["masks"].push_back(mj);
  }
  if (plan.scheme == Scheme::Greyscale) {
    j["dose_table"] = json::array();
    for (const auto& mk : plan.masks)
      j["dose_table"].push_back({{"layer", mk.layer}, {"etch_depth_nm", mk.etch_depth_m * 1e9}, {"relative_dose", mk.relative_dose}});
    j["dose_calibration"] = o.dose_curve_csv.empty() ? "linear placeholder: dose = etch / deepest etch; replace with the fab's curve (--dose-curve)"
                                                     : "interpolated from " + o.dose_curve_csv;
  }
  j["process"] = plan.scheme == Scheme::Greyscale
                     ? "one greyscale write; the alignment crosses (layer 254) are written with it"
                     : "mask 1 prints the alignment crosses (copy layer 254 onto every mask plate); every later mask is aligned to them; "
                       "each mask: expose, develop, etch its depth, strip";
  j["alignment_marks"] = {{"layer", kMarkLayer},
                          {"shape", "crosses"},
                          {"centres_nm", {{-mc, -mc}, {mc, -mc}, {-mc, mc}, {mc, mc}}},
                          {"arm_half_length_um", o.mark_arm_um},
                          {"arm_width_um", o.mark_width_um}};
  j["aperture"] = {{"layer", kApertureLayer}, {"radius_um", cfg.aperture_radius() * 1e6}, {"vertices", o.aperture_vertices},
                   {"note", "reference outline of the circular aperture (a filled polygon), not an etch layer"}};
  j["constraints"] = {{"min_feature_um", o.constraints.min_feature_um},
                      {"max_levels", o.constraints.max_levels > 0 ? o.constraints.max_levels : scheme_max_levels(plan.scheme)},
                      {"max_height_nm", o.constraints.max_height_nm > 0 ? o.constraints.max_height_nm : plan.h_max_m * 1e9},
                      {"level_tolerance_nm", o.constraints.level_tolerance_nm}};
  j["provenance"] = o.provenance;
  j["polygons"] = res.polygons;
  j["vertices"] = res.vertices;
  write_text_atomic((dir / "manifest.json").string(), j.dump(2) + "\n");
  res.files.push_back("manifest.json");

  // Read everything back with the project's reader and check it against the design.
  const Reconstruction rec = reconstruct_export(o.out);
  for (std::size_t i = 0; i < n * n; ++i) {
    if (rec.level_of_pixel[i] != plan.level_of_pixel[i])
      throw Error("export check failed: " + pixel_name(i, n) + " reads back as level " + std::to_string(rec.level_of_pixel[i]) +
                  ", the design has level " + std::to_string(plan.level_of_pixel[i]));
    res.max_height_error_nm = std::max(res.max_height_error_nm, std::fabs(rec.height_m.data[i] - d.height_m.data[i]) * 1e9);
  }
  if (res.max_height_error_nm > o.constraints.level_tolerance_nm)
    throw Error("export check failed: heights rebuilt from the masks differ from the design by " + to_str(res.max_height_error_nm) + " nm");
  j["check"] = {{"reader", "qdo::gds::read + rasterize at pixel centres"},
                {"level_map_identical", true},
                {"max_height_error_nm", res.max_height_error_nm}};
  write_text_atomic((dir / "manifest.json").string(), j.dump(2) + "\n");

  // Previews from the read-back polygons.
  const gds::Library back = gds::read(readable_output((dir / "masks.gds").string()));
  for (const Mask& mk : plan.masks) {
    std::vector<gds::Polygon> polys;
    for (const auto& b : back.boundaries)
      if (b.layer == mk.layer) {
        gds::Polygon g;
        for (const auto& q : b.points) g.push_back({(q.x - org) / p, (q.y - org) / p});
        polys.push_back(std::move(g));
      }
    const auto bits = gds::rasterize(polys, n, n);
    std::vector<unsigned char> px(bits.size());
    for (std::size_t i = 0; i < bits.size(); ++i) px[i] = bits[i] ? 255 : 0;
    const std::string name = "mask_L" + std::to_string(mk.layer) + ".png";
    write_png((dir / name).string(), n, n, 1, px);
    res.files.push_back(name);
  }
  write_map_png((dir / "heights_from_masks.png").string(), rec.height_m);
  res.files.push_back("heights_from_masks.png");

  // Markdown sheet.
  std::ostringstream md;
  md << "# Mask set: " << to_string(plan.scheme) << " scheme\n\n";
  md << "| item | value |\n|---|---|\n";
  for (const auto& [k, v] : o.provenance) md << "| " << md_escape(k) << " | " << md_escape(v) << " |\n";
  md << "| scheme | " << to_string(plan.scheme) << " (" << plan.method << ") |\n";
  md << "| material | " << cfg.material << " |\n";
  md << "| h_max (2pi at " << cfg.base_wavelength_nm << " nm) | " << nm(plan.h_max_m, 2) << " nm |\n";
  md << "| base plate | " << cfg.base_plate_m * 1e3 << " mm |\n";
  md << "| grid | " << n << " x " << n << " pixels at " << p << " nm (" << double(n * std::size_t(p)) * 1e-3 << " um field) |\n";
  md << "| aperture | radius " << cfg.aperture_radius() * 1e6 << " um (layer " << kApertureLayer << ") |\n";
  md << "| blank top (unetched surface) | " << nm(plan.top_m, 2) << " nm above the base plate |\n";
  md << "| GDSII | masks.gds, 1 nm database unit, 1 um user unit, structure DOE; alignment crosses on layer " << kMarkLayer << " |\n";
  md << "| mask polygons | " << res.polygons << " (" << res.vertices << " vertices) |\n";
  md << "| read-back check | level map identical; max height error " << res.max_height_error_nm << " nm |\n\n";
  md << "Etch depths are measured from the blank's unetched surface (the highest level): etch = blank top - H. "
        "REFERENCE's h_max - H differs by a constant (a thinner relief layer; only a constant phase). "
        "Drawn polygons are the open (etched) regions: dark-field masks for a positive resist.\n\n";
  md << "## Levels\n\n| level | height (nm) | etch depth (nm) | h_max - H (nm) | pixels | mask layers |\n|---:|---:|---:|---:|---:|---|\n";
  for (const auto& L : plan.levels) {
    md << "| " << L.index << " | " << nm(L.height_m) << " | " << nm(plan.top_m - L.height_m) << " | " << nm(plan.h_max_m - L.height_m)
       << " | " << L.pixels << " | ";
    for (std::size_t k = 0; k < L.masks.size(); ++k) md << (k ? ", " : "") << layer_of[L.masks[k]];
    md << (L.pixels ? "" : " (unused)") << " |\n";
  }
  md << "\n## Masks\n\n| layer | name | etch depth (nm) | tone | polygons | vertices | open area (mm^2) |"
     << (plan.scheme == Scheme::Greyscale ? " relative dose |" : "") << " preview |\n|---:|---|---:|---|---:|---:|---:|"
     << (plan.scheme == Scheme::Greyscale ? "---:|" : "") << "---|\n";
  for (std::size_t m = 0; m < plan.masks.size(); ++m) {
    const Mask& mk = plan.masks[m];
    md << "| " << mk.layer << " | " << mk.name << " | " << nm(mk.etch_depth_m) << " | dark-field | " << mask_polys[m] << " | "
       << mask_verts[m] << " | " << double(mk.pixels) * double(p) * double(p) * 1e-12 << " |";
    if (plan.scheme == Scheme::Greyscale) md << " " << mk.relative_dose << " |";
    md << " mask_L" << mk.layer << ".png |\n";
  }
  md << "\nProcess: " << j["process"].get<std::string>() << ".\n";
  if (plan.scheme == Scheme::Greyscale) md << "\nDose calibration: " << j["dose_calibration"].get<std::string>() << ".\n";
  md << "\nFiles: masks.gds, manifest.json, this sheet, mask_L*.png (white = open), heights_from_masks.png (the height map rebuilt from "
        "the GDSII polygons and these depths).\n";
  write_text_atomic((dir / "manifest.md").string(), md.str());
  res.files.push_back("manifest.md");
  return res;
}

// ------------------------------------------------------------------------------------------------
// Tolerance analysis

namespace {

std::uint64_t splitmix64(std::uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}
// Uniform in [-1, 1) from (seed, stream, index): portable across standard libraries.
double sym_uniform(std::uint64_t seed, std::uint64_t stream, std::uint64_t index) {
  const std::uint64_t r = splitmix64(splitmix64(seed ^ splitmix64(stream)) + index);
  return double(r >> 11) * (2.0 / 9007199254740992.0) - 1.0;
}

// 1-D box-cell shift of rows (axis 1) or columns (axis 0) of a size x size map by s cells
// (continuous): out(x) = (1 - f) in(x - q) + f in(x - q - 1), q = floor(s), f = s - q; zero outside.
std::vector<double> shift_axis(const std::vector<double>& in, std::size_t size, double s, int axis) {
  if (s == 0.0) return in;
  const double qf = std::floor(s), f = s - qf;
  const long q = long(qf);
  std::vector<double> out(in.size(), 0.0);
  for (std::size_t a = 0; a < size; ++a)
    for (std::size_t b = 0; b < size; ++b) {
      const long src0 = long(b) - q, src1 = src0 - 1;
      double v = 0;
      auto at = [&](long k) {
        if (k < 0 || k >= long(size)) return 0.0;
        return axis == 1 ? in[a * size + std::size_t(k)] : in[std::size_t(k) * size + a];
      };
      v = (1.0 - f) * at(src0) + f * at(src1);
      if (axis == 1) out[a * size + b] = v;
      else out[b * size + a] = v;
    }
  return out;
}

std::vector<double> gaussian_blur(const std::vector<double>& in, std::size_t size, double sigma_cells) {
  if (!(sigma_cells > 0)) return in;
  const long r = long(std::ceil(3.0 * sigma_cells));
  std::vector<double> k(std::size_t(2 * r + 1));
  double sum = 0;
  for (long t = -r; t <= r; ++t) sum += k[std::size_t(t + r)] = std::exp(-0.5 * double(t * t) / (sigma_cells * sigma_cells));
  for (double& v : k) v /= sum;
  std::vector<double> tmp(in.size(), 0.0), out(in.size(), 0.0);
  const long S = long(size);
  for (long y = 0; y < S; ++y)
    for (long x = 0; x < S; ++x) {
      double v = 0;
      for (long t = -r; t <= r; ++t)
        if (x - t >= 0 && x - t < S) v += k[std::size_t(t + r)] * in[std::size_t(y * S + x - t)];
      tmp[std::size_t(y * S + x)] = v;
    }
  for (long y = 0; y < S; ++y)
    for (long x = 0; x < S; ++x) {
      double v = 0;
      for (long t = -r; t <= r; ++t)
        if (y - t >= 0 && y - t < S) v += k[std::size_t(t + r)] * tmp[std::size_t((y - t) * S + x)];
      out[std::size_t(y * S + x)] = v;
    }
  return out;
}

}  // namespace

Map2D perturbed_heights(const MaskPlan& plan, const Map2D& design_height_m, const Perturbation& pt, std::size_t oversample) {
  const std::size_t n = plan.n, K = plan.masks.size();
  if (design_height_m.rows != n || design_height_m.cols != n) reject("design heights", design_height_m.rows, "the plan's N = " + to_str(n));
  if (oversample < 1 || oversample > 16) reject("oversample", oversample, "in [1, 16]");
  for (const auto* v : {&pt.depth_error_m, &pt.shift_x_m, &pt.shift_y_m})
    if (!v->empty() && v->size() != K) reject("perturbation size", v->size(), "one value per mask (" + to_str(K) + ") or none");
  if (pt.edge_blur_m < 0 || pt.height_noise_m < 0) reject("edge blur / height noise", "< 0", ">= 0");
  auto get = [](const std::vector<double>& v, std::size_t m) { return v.empty() ? 0.0 : v[m]; };
  Map2D h = design_height_m;
  const std::size_t F = oversample, M = n * F;
  const double fine_pitch = plan.pitch_m / double(F);
  std::vector<double> de(n * n, 0.0);  // change of the etch depth, area-averaged per DOE pixel
  bool changed = false;
  for (std::size_t m = 0; m < K; ++m) {
    const Mask& mk = plan.masks[m];
    const double eps = get(pt.depth_error_m, m), sx = get(pt.shift_x_m, m), sy = get(pt.shift_y_m, m);
    const bool geometric = sx != 0.0 || sy != 0.0 || pt.edge_blur_m > 0;
    if (!geometric && eps == 0.0) continue;
    changed = true;
    if (!geometric) {  // depth error alone: the open region gets eps more etch
      for (std::size_t i = 0; i < n * n; ++i)
        if (mk.drawn[i]) de[i] += eps;
      continue;
    }
    // The open region on the fine grid, shifted and blurred (area fractions), then area-averaged.
    std::vector<double> fine(M * M, 0.0);
    for (std::size_t y = 0; y < M; ++y)
      for (std::size_t x = 0; x < M; ++x) fine[y * M + x] = mk.drawn[(y / F) * n + x / F] ? 1.0 : 0.0;
    fine = shift_axis(fine, M, sx / fine_pitch, 1);
    fine = shift_axis(fine, M, sy / fine_pitch, 0);
    fine = gaussian_blur(fine, M, pt.edge_blur_m / fine_pitch);
    const double inv = 1.0 / double(F * F), depth = mk.etch_depth_m + eps;
    for (std::size_t i = 0; i < n; ++i)
      for (std::size_t j = 0; j < n; ++j) {
        double a = 0;
        for (std::size_t u = 0; u < F; ++u)
          for (std::size_t v = 0; v < F; ++v) a += fine[(i * F + u) * M + j * F + v];
        a *= inv;
        de[i * n + j] += depth * a - mk.etch_depth_m * (mk.drawn[i * n + j] ? 1.0 : 0.0);
      }
  }
  if (changed)
    for (std::size_t i = 0; i < n * n; ++i) h.data[i] -= de[i];
  if (pt.height_noise_m > 0)
    for (std::size_t i = 0; i < n * n; ++i) h.data[i] += pt.height_noise_m * sym_uniform(pt.noise_seed, 7, i);
  const double lo = *std::min_element(h.data.begin(), h.data.end());
  if (lo < 0)
    for (double& v : h.data) v -= lo;  // a constant height: a constant phase, the PSF is unchanged
  const double cap = 2.0 * plan.h_max_m;
  for (double& v : h.data) v = std::min(v, cap);
  return h;
}

namespace {

// The reconstruction pipeline of qdo eval (src/eval.cpp), step for step, so the metrics agree
// exactly: the same test patches, noise draws, Wiener decoder and averaging order.
class Evaluator {
 public:
  Evaluator(Runtime& rt, const DesignRunOptions& o, const ToleranceOptions& t, const std::string& run)
      : o_(o), sim_(rt, o.cfg, t.precision) {
    const SystemConfig& cfg = o.cfg;
    s_ = cfg.sensor_size_px();
    prior_ = load_prior((fs::path(run) / "prior.h5").string());
    if (prior_.rows != s_ || prior_.cols != s_) reject("prior", run + "/prior.h5", "a prior on the S x S sensor grid");
    sigma_ = t.noise_sigma >= 0 ? t.noise_sigma : o.decoder_noise_sigma;
    srf_ = sensor_response(cfg);
    patches_ = testset::patches(cfg, s_, t.data, t.data_format, t.synthetic_scenes, o.design.seed);
  }
  RealStack psf(const Map2D& h) {
    sim_.set_heights(h);
    sim_.compute_psf();
    return sim_.psf_sensor();
  }
  std::unique_ptr<WienerDecoder> decoder(const RealStack& psf) const {
    return std::make_unique<WienerDecoder>(wiener::psf_to_otf(psf, s_, s_), srf_, prior_, sigma_);
  }
  Metrics metrics(const RealStack& psf_actual, const WienerDecoder& dec) const {
    const ComplexStack otf = wiener::psf_to_otf(psf_actual, s_, s_);
    std::vector<std::pair<std::string, testset::Scores>> per_patch;
    for (std::size_t k = 0; k < patches_.size(); ++k) {
      const RealStack& x = patches_[k].cube;
      per_patch.push_back({patches_[k].scene, testset::score(testset::reconstruct(x, otf, srf_, dec, sigma_, o_.design.seed, k), x)});
    }
    std::vector<testset::Scores> rows;
    for (const auto& scene : testset::per_scene_means(per_patch)) rows.push_back(scene.second);
    return testset::mean_of(rows);
  }
  std::size_t patches() const { return patches_.size(); }
  double sigma() const { return sigma_; }

 private:
  const DesignRunOptions& o_;
  Simulator sim_;
  std::size_t s_ = 0;
  wiener::SpectralPrior prior_;
  double sigma_ = 0;
  Eigen::MatrixXd srf_;
  std::vector<testset::Patch> patches_;
};

const char* kMetricNames[6] = {"psnr_db", "psnr_h_db", "ssim", "rmse", "ergas", "sam_rad"};
double metric(const Metrics& m, int k) {
  switch (k) {
    case 0: return m.psnr;
    case 1: return m.psnr_hyper;
    case 2: return m.ssim;
    case 3: return m.rmse;
    case 4: return m.ergas;
    default: return m.sam_rad;
  }
}
bool higher_is_better(int k) { return k <= 2; }

Stat stat_of(const std::vector<double>& v) {
  Stat s;
  if (v.empty()) return s;
  s.min = *std::min_element(v.begin(), v.end());
  s.max = *std::max_element(v.begin(), v.end());
  for (double x : v) s.mean += x / double(v.size());
  if (v.size() > 1) {
    double q = 0;
    for (double x : v) q += (x - s.mean) * (x - s.mean);
    s.std = std::sqrt(q / double(v.size() - 1));
  }
  return s;
}

// --- A small raster canvas with a 3 x 5 pixel font, for the strip chart ---
struct Canvas {
  std::size_t w, h;
  std::vector<unsigned char> px;
  Canvas(std::size_t w_, std::size_t h_) : w(w_), h(h_), px(w_ * h_ * 3, 255) {}
  void dot(long x, long y, const unsigned char* c) {
    if (x < 0 || y < 0 || x >= long(w) || y >= long(h)) return;
    std::copy(c, c + 3, px.begin() + long((std::size_t(y) * w + std::size_t(x)) * 3));
  }
  void rect(long x0, long y0, long x1, long y1, const unsigned char* c) {
    for (long y = std::min(y0, y1); y <= std::max(y0, y1); ++y)
      for (long x = std::min(x0, x1); x <= std::max(x0, x1); ++x) dot(x, y, c);
  }
  void text(long x, long y, const std::string& s, const unsigned char* c, int scale = 2) {
    static const std::map<char, const char*> font = {
        {'0', "111101101101111"}, {'1', "010110010010111"}, {'2', "111001111100111"}, {'3', "111001111001111"},
        {'4', "101101111001001"}, {'5', "111100111001111"}, {'6', "111100111101111"}, {'7', "111001001001001"},
        {'8', "111101111101111"}, {'9', "111101111001111"}, {'.', "000000000000010"}, {'-', "000000111000000"},
        {'A', "010101111101101"}, {'B', "110101110101110"}, {'D', "110101101101110"}, {'E', "111100110100111"},
        {'H', "101101111101101"}, {'I', "111010010010111"}, {'L', "100100100100111"}, {'N', "111101101101101"},
        {'O', "010101101101010"}, {'P', "110101110100100"}, {'R', "110101110101101"}, {'S', "011100010001110"},
        {'T', "111010010010010"}, {'U', "101101101101111"}, {'V', "101101101101010"}, {'Y', "101101010010010"},
        {'C', "111100100100111"}, {'G', "111100101101111"}, {' ', "000000000000000"}};
    long cx = x;
    for (char ch : s) {
      const auto it = font.find(ch);
      const char* g = it == font.end() ? "111111111111111" : it->second;
      for (int r = 0; r < 5; ++r)
        for (int q = 0; q < 3; ++q)
          if (g[r * 3 + q] == '1') rect(cx + q * scale, y + r * scale, cx + q * scale + scale - 1, y + r * scale + scale - 1, c);
      cx += 4 * scale;
    }
  }
};

std::string upper_label(const std::string& s) {
  std::string o;
  for (char ch : s) o += char(std::toupper(static_cast<unsigned char>(ch)));
  return o;
}

std::string fixed(double v, int digits) {
  char b[64];
  std::snprintf(b, sizeof b, "%.*f", digits, v);
  return b;
}

// PSNR per trial for every scenario: dots (blue: calibrated decoder, red: nominal decoder), a
// black bar at each mean, a grey line at the nominal design's PSNR; y ticks every 1 or more dB.
void write_strip_chart(const std::string& path, const ToleranceResult& r) {
  const std::size_t W = 720, H = 400;
  Canvas cv(W, H);
  const unsigned char black[3] = {0, 0, 0}, grey[3] = {150, 150, 150}, blue[3] = {31, 119, 180}, red[3] = {214, 39, 40};
  double lo = r.nominal.psnr, hi = r.nominal.psnr;
  for (const auto& t : r.trials)
    for (double v : {t.calibrated.psnr, t.nominal_decoder.psnr})
      if (std::isfinite(v)) {
        lo = std::min(lo, v);
        hi = std::max(hi, v);
      }
  double step = 1;
  while ((hi - lo) / step > 8) step *= 2;
  lo = std::floor(lo / step) * step - step * 0.5;
  hi = std::ceil(hi / step) * step + step * 0.25;
  const long left = 70, right = long(W) - 10, top = 30, bottom = long(H) - 40;
  auto Y = [&](double v) { return long(double(bottom) - (v - lo) / (hi - lo) * double(bottom - top)); };
  cv.rect(left, top, left, bottom, black);
  cv.rect(left, bottom, right, bottom, black);
  for (double v = std::ceil(lo / step) * step; v <= hi; v += step) {
    cv.rect(left - 5, Y(v), left, Y(v), black);
    cv.text(8, Y(v) - 5, fixed(v, step < 1 ? 1 : 0), black);
  }
  cv.text(8, 8, "PSNR DB", black);
  for (long x = left; x <= right; x += 6) cv.rect(x, Y(r.nominal.psnr), x + 2, Y(r.nominal.psnr), grey);
  const std::size_t S = r.summary.size();
  const double colw = double(right - left) / double(std::max<std::size_t>(S, 1));
  for (std::size_t s = 0; s < S; ++s) {
    const long cx = left + long(colw * (double(s) + 0.5));
    cv.text(cx - long(upper_label(r.summary[s].scenario).size()) * 4, bottom + 12, upper_label(r.summary[s].scenario), black);
    std::size_t k = 0;
    for (const auto& t : r.trials) {
      if (t.scenario != r.summary[s].scenario) continue;
      const long jitter = long(k++ % 7) * 3 - 9;
      cv.rect(cx - 14 + jitter, Y(t.calibrated.psnr) - 1, cx - 12 + jitter, Y(t.calibrated.psnr) + 1, blue);
      cv.rect(cx + 12 + jitter, Y(t.nominal_decoder.psnr) - 1, cx + 14 + jitter, Y(t.nominal_decoder.psnr) + 1, red);
    }
    const auto& c = r.summary[s].calibrated.at("psnr_db");
    const auto& nd = r.summary[s].nominal_decoder.at("psnr_db");
    cv.rect(cx - 26, Y(c.mean), cx - 2, Y(c.mean) + 1, black);
    cv.rect(cx + 2, Y(nd.mean), cx + 26, Y(nd.mean) + 1, black);
  }
  write_png(path, W, H, 3, cv.px);
}

}  // namespace

ToleranceResult tolerance_analysis(Runtime& rt, const ToleranceOptions& t) {
  const fs::path run(t.run);
  if (!fs::is_regular_file(run / "config.json")) reject("run", t.run, "a run folder written by qdo design (config.json missing)");
  for (const auto& [name, v] : {std::pair<const char*, double>{"etch_depth_error", t.etch_depth_error_m}, {"overlay", t.overlay_m},
                                {"edge_blur", t.edge_blur_m}, {"height_noise", t.height_noise_m}})
    if (!(v >= 0) || !std::isfinite(v)) reject(name, v, "finite and >= 0");
  if (t.trials < 1 || t.trials > 100000) reject("trials", t.trials, "in [1, 100000]");
  if (t.oversample < 1 || t.oversample > 16) reject("oversample", t.oversample, "in [1, 16]");
  const DesignRunOptions o = read_run_config(t.run);
  const Design fab = read_design((run / "design.h5").string());
  if (fab.height_m.rows != o.cfg.n) reject("run", t.run, "design.h5 on the configuration's N x N grid");
  Constraints c;
  c.min_feature_um = 0;                       // analyse whatever the design is,
  c.max_height_nm = 2 * o.cfg.h_max_m() * 1e9;  // up to the simulator's height range
  ToleranceResult res;
  std::string scheme_note;
  if (t.scheme == "auto") {
    try {
      res.plan = plan_masks(fab, o.cfg, Scheme::Binary, c);
      scheme_note = "auto: binary-coded masks";
    } catch (const InputError& e) {
      res.plan = plan_masks(fab, o.cfg, Scheme::Nested, c);
      scheme_note = std::string("auto: nested masks (binary not possible: ") + e.what() + ")";
    }
  } else {
    res.plan = plan_masks(fab, o.cfg, scheme_from_string(t.scheme), c);
    scheme_note = t.scheme;
  }
  const MaskPlan& plan = res.plan;
  const std::size_t K = plan.masks.size();
  const bool single_write = plan.scheme == Scheme::Greyscale;  // one exposure: no overlay between layers

  Evaluator ev(rt, o, t, t.run);
  const RealStack psf0 = ev.psf(fab.height_m);
  const auto dec0 = ev.decoder(psf0);
  res.nominal = ev.metrics(psf0, *dec0);
  double psf0_norm = 0;
  for (double v : psf0.data) psf0_norm += v * v;
  psf0_norm = std::sqrt(psf0_norm);

  struct Scenario {
    std::string name;
    bool depth, overlay, blur, noise;
  };
  std::vector<Scenario> scenarios = {{"all", true, true, true, true}};
  const bool active[4] = {t.etch_depth_error_m > 0, t.overlay_m > 0 && !single_write && K > 1, t.edge_blur_m > 0, t.height_noise_m > 0};
  const int n_active = int(active[0]) + int(active[1]) + int(active[2]) + int(active[3]);
  if (t.per_source && n_active > 1) {
    if (active[0]) scenarios.push_back({"etch depth", true, false, false, false});
    if (active[1]) scenarios.push_back({"overlay", false, true, false, false});
    if (active[2]) scenarios.push_back({"edge blur", false, false, true, false});
    if (active[3]) scenarios.push_back({"height noise", false, false, false, true});
  }
  Map2D worst_dh;
  RealStack worst_psf;
  std::vector<H5Dataset> psf_sets;
  if (t.save_psfs && !t.out.empty())
    psf_sets.push_back({"/psf_nominal", {psf0.planes, psf0.rows, psf0.cols}, psf0.data, {{"pitch_m", o.cfg.sensor_pitch_m}}, {}});
  double worst_psnr = std::numeric_limits<double>::infinity();
  const std::size_t total = scenarios.size() * t.trials;
  std::size_t done = 0;
  for (std::size_t k = 0; k < t.trials; ++k) {
    // Draws of trial k (independent of the scenario).
    std::vector<double> dep(K), sx(K), sy(K);
    for (std::size_t m = 0; m < K; ++m) {
      dep[m] = t.etch_depth_error_m * sym_uniform(t.seed, 1, k * K + m);
      const bool moves = m > 0 && !single_write;  // mask 1 defines the frame (the alignment marks)
      sx[m] = moves ? t.overlay_m * sym_uniform(t.seed, 2, k * K + m) : 0.0;
      sy[m] = moves ? t.overlay_m * sym_uniform(t.seed, 3, k * K + m) : 0.0;
    }
    const std::uint64_t noise_seed = splitmix64(t.seed ^ splitmix64(k + 0x51ED));
    for (const auto& sc : scenarios) {
      Perturbation pt;
      pt.depth_error_m = sc.depth ? dep : std::vector<double>(K, 0.0);
      pt.shift_x_m = sc.overlay ? sx : std::vector<double>(K, 0.0);
      pt.shift_y_m = sc.overlay ? sy : std::vector<double>(K, 0.0);
      pt.edge_blur_m = sc.blur ? t.edge_blur_m : 0.0;
      pt.height_noise_m = sc.noise ? t.height_noise_m : 0.0;
      pt.noise_seed = noise_seed;
      const Map2D h = perturbed_heights(plan, fab.height_m, pt, t.oversample);
      Trial tr;
      tr.scenario = sc.name;
      tr.index = k;
      tr.depth_error_m = pt.depth_error_m;
      tr.shift_x_m = pt.shift_x_m;
      tr.shift_y_m = pt.shift_y_m;
      // RMS of the height change, after removing the constant offset (a constant only adds a phase).
      double mean_d = 0;
      for (std::size_t i = 0; i < h.data.size(); ++i) mean_d += (h.data[i] - fab.height_m.data[i]) / double(h.data.size());
      double q = 0;
      for (std::size_t i = 0; i < h.data.size(); ++i) {
        const double dd = h.data[i] - fab.height_m.data[i] - mean_d;
        q += dd * dd / double(h.data.size());
      }
      tr.height_rms_change_m = std::sqrt(q);
      const RealStack psf = ev.psf(h);
      double dn = 0;
      for (std::size_t i = 0; i < psf.data.size(); ++i) dn += (psf.data[i] - psf0.data[i]) * (psf.data[i] - psf0.data[i]);
      tr.psf_rel_change = std::sqrt(dn) / psf0_norm;
      tr.calibrated = ev.metrics(psf, *ev.decoder(psf));
      tr.nominal_decoder = ev.metrics(psf, *dec0);
      if (sc.name == "all" && tr.calibrated.psnr < worst_psnr) {
        worst_psnr = tr.calibrated.psnr;
        worst_dh = Map2D(h.rows, h.cols);
        for (std::size_t i = 0; i < h.data.size(); ++i) worst_dh.data[i] = (h.data[i] - fab.height_m.data[i] - mean_d) * 1e9;
        worst_psf = psf;
      }
      if (t.save_psfs && !t.out.empty()) {
        std::string tag = sc.name;
        for (char& ch : tag)
          if (ch == ' ') ch = '_';
        psf_sets.push_back({"/psf_" + tag + "_" + std::to_string(k), {psf.planes, psf.rows, psf.cols}, psf.data, {}, {}});
      }
      res.trials.push_back(tr);
      ++done;
      if (!t.quiet)
        std::fprintf(stderr, "[tolerance] %zu/%zu  %-12s trial %zu  PSNR %.2f dB (nominal decoder %.2f dB)\n", done, total,
                     sc.name.c_str(), k, tr.calibrated.psnr, tr.nominal_decoder.psnr);
    }
  }
  for (const auto& sc : scenarios) {
    ScenarioSummary s;
    s.scenario = sc.name;
    for (int mi = 0; mi < 6; ++mi) {
      std::vector<double> a, b;
      for (const auto& tr : res.trials)
        if (tr.scenario == sc.name) {
          a.push_back(metric(tr.calibrated, mi));
          b.push_back(metric(tr.nominal_decoder, mi));
        }
      s.trials = a.size();
      s.calibrated[kMetricNames[mi]] = stat_of(a);
      s.nominal_decoder[kMetricNames[mi]] = stat_of(b);
    }
    res.summary.push_back(s);
  }
  if (t.out.empty()) return res;

  // Files.
  const fs::path dir(t.out);
  make_output_dir(t.out, "out");
  auto list = [](const std::vector<double>& v, double scale) {
    std::ostringstream s;
    s.precision(6);
    for (std::size_t i = 0; i < v.size(); ++i) s << (i ? ";" : "") << v[i] * scale;
    return s.str();
  };
  std::ostringstream csv;
  csv.precision(8);
  csv << "scenario,trial,psnr_db,psnr_h_db,ssim,rmse,ergas,sam_rad,nomdec_psnr_db,nomdec_psnr_h_db,nomdec_ssim,nomdec_rmse,"
         "nomdec_ergas,nomdec_sam_rad,height_rms_change_nm,psf_rel_change,depth_errors_nm,overlay_x_um,overlay_y_um\n";
  for (const auto& tr : res.trials) {
    csv << tr.scenario << "," << tr.index;
    for (int mi = 0; mi < 6; ++mi) csv << "," << metric(tr.calibrated, mi);
    for (int mi = 0; mi < 6; ++mi) csv << "," << metric(tr.nominal_decoder, mi);
    csv << "," << tr.height_rms_change_m * 1e9 << "," << tr.psf_rel_change << "," << list(tr.depth_error_m, 1e9) << ","
        << list(tr.shift_x_m, 1e6) << "," << list(tr.shift_y_m, 1e6) << "\n";
  }
  write_text_atomic((dir / "tolerance.csv").string(), csv.str());
  json j;
  j["run"] = t.run;
  j["scheme"] = to_string(plan.scheme);
  j["scheme_note"] = scheme_note;
  j["masks"] = json::array();
  for (const auto& mk : plan.masks) j["masks"].push_back({{"layer", mk.layer}, {"etch_depth_nm", mk.etch_depth_m * 1e9}});
  j["options"] = {{"etch_depth_error_nm", t.etch_depth_error_m * 1e9}, {"overlay_um", t.overlay_m * 1e6},
                  {"edge_blur_um", t.edge_blur_m * 1e6},          {"height_noise_nm", t.height_noise_m * 1e9},
                  {"trials", t.trials},                          {"seed", t.seed},
                  {"oversample", t.oversample},                  {"test_patches", ev.patches()},
                  {"noise_sigma", ev.sigma()},                   {"precision", to_string(t.precision)}};
  j["model"] = {
      {"etch_depth", "per mask, uniform in [-S, S], added to the mask's etch depth"},
      {"overlay", single_write ? "none: one greyscale write" : "per mask after the first (which defines the alignment marks), per axis, uniform in [-S, S]"},
      {"edge_blur", "Gaussian of sigma S on each mask's open region (sloped / rounded edges), deterministic"},
      {"height_noise", "per DOE pixel, uniform in [-S, S]"},
      {"grid", "masks rendered oversample x finer (area fractions), etch composed there and area-averaged back to the DOE pitch"},
      {"decoders", "calibrated: Wiener decoder rebuilt for the fabricated PSF; nominal_decoder: the nominal design's decoder"},
      {"metrics", "as qdo eval (metrics.json conventions), mean over test scenes"}};
  auto metrics_json = [](const Metrics& m) {
    return json{{"psnr_db", m.psnr}, {"psnr_h_db", m.psnr_hyper}, {"ssim", m.ssim}, {"rmse", m.rmse}, {"ergas", m.ergas}, {"sam_rad", m.sam_rad}};
  };
  j["nominal"] = metrics_json(res.nominal);
  j["scenarios"] = json::array();
  for (const auto& s : res.summary) {
    json sj;
    sj["scenario"] = s.scenario;
    sj["trials"] = s.trials;
    for (const auto* which : {&s.calibrated, &s.nominal_decoder}) {
      json mj;
      for (int mi = 0; mi < 6; ++mi) {
        const Stat& st = which->at(kMetricNames[mi]);
        mj[kMetricNames[mi]] = {{"mean", st.mean}, {"std", st.std}, {"min", st.min}, {"max", st.max},
                                {"worst", higher_is_better(mi) ? st.min : st.max},
                                {"mean_change", st.mean - metric(res.nominal, mi)}};
      }
      sj[which == &s.calibrated ? "calibrated" : "nominal_decoder"] = mj;
    }
    j["scenarios"].push_back(sj);
  }
  write_text_atomic((dir / "tolerance.json").string(), j.dump(2) + "\n");
  write_strip_chart((dir / "psnr_by_scenario.png").string(), res);
  if (!psf_sets.empty()) {
    const auto wl = o.cfg.wavelengths_nm();
    psf_sets.push_back({"/wavelengths_nm", {wl.size()}, wl, {}, {{"units", "nm"}}});
    h5_write((dir / "psfs.h5").string(), psf_sets, {{"run", t.run}, {"content", "sensor PSF stacks (bands x S x S) per trial"}});
  }
  if (!worst_dh.data.empty()) {
    write_map_png((dir / "worst_height_error.png").string(), worst_dh);
    write_montage_png((dir / "worst_psf.png").string(), worst_psf, o.cfg.wavelengths_nm(), 0.5,
                      std::min<std::size_t>(worst_psf.rows, 96));
  }
  std::ostringstream md;
  md << "# Tolerance analysis\n\nRun `" << t.run << "`, scheme " << to_string(plan.scheme) << " (" << scheme_note << "), " << K
     << " mask layer(s); " << t.trials << " trials per scenario, seed " << t.seed << ", oversampling " << t.oversample << "x, "
     << ev.patches() << " test patches.\n\n";
  md << "Errors: etch depth ±" << t.etch_depth_error_m * 1e9 << " nm per mask (uniform), overlay ±" << t.overlay_m * 1e6
     << " um per mask and axis (uniform; mask 1 is the reference" << (single_write ? "; none for a single greyscale write" : "")
     << "), edge blur sigma " << t.edge_blur_m * 1e6 << " um, height noise ±" << t.height_noise_m * 1e9 << " nm per pixel.\n\n";
  md << "Nominal design: PSNR " << fixed(res.nominal.psnr, 3) << " dB, SSIM " << fixed(res.nominal.ssim, 4) << ", RMSE "
     << fixed(res.nominal.rmse, 5) << ", ERGAS " << fixed(res.nominal.ergas, 3) << ", SAM " << fixed(res.nominal.sam_rad, 4) << " rad.\n\n";
  md << "| scenario | trials | PSNR mean (dB) | std | worst | change of mean | SSIM mean | worst | PSNR mean, nominal decoder | worst |\n"
     << "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n";
  for (const auto& s : res.summary) {
    const Stat& p = s.calibrated.at("psnr_db");
    const Stat& q = s.calibrated.at("ssim");
    const Stat& pn = s.nominal_decoder.at("psnr_db");
    md << "| " << s.scenario << " | " << s.trials << " | " << fixed(p.mean, 3) << " | " << fixed(p.std, 3) << " | " << fixed(p.min, 3)
       << " | " << fixed(p.mean - res.nominal.psnr, 3) << " | " << fixed(q.mean, 4) << " | " << fixed(q.min, 4) << " | "
       << fixed(pn.mean, 3) << " | " << fixed(pn.min, 3) << " |\n";
  }
  md << "\n\"Calibrated\": the Wiener decoder is rebuilt for the fabricated DOE's PSF (as after a PSF calibration); \"nominal decoder\": "
        "the decoder of the nominal design is used unchanged. Files: tolerance.csv (one row per trial), tolerance.json (summaries), "
        "psnr_by_scenario.png (per scenario: blue dots calibrated, red dots nominal decoder, black bars the means, dashed grey "
        "line the nominal design), worst_height_error.png (height change of the worst combined trial, nm), worst_psf.png.\n";
  write_text_atomic((dir / "tolerance.md").string(), md.str());
  return res;
}

}  // namespace qdo::fab
