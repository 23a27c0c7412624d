// Training scenes: the synthetic scene generator (shapes of measured reflectances under a
// measured illuminant, from the embedded tables; see include/qdo/data/datasets.hpp).
#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <utility>

#include "data/datasets_internal.hpp"
#include "qdo/data/datasets.hpp"
#include "qdo/runtime/embedded.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"
#include "qdo/data/scenes.hpp"

namespace qdo {
using namespace datasets_detail;

// =========================================================================================
// Synthetic scenes
// =========================================================================================

namespace {

// A spectral table as tabulated: rows = spectra, values on `wl_nm`.
struct SpectralTable {
  std::string file;
  std::vector<double> wl_nm;
  std::vector<std::string> names;
  std::vector<std::vector<double>> rows;
};

SpectralTable load_table(const std::string& file, bool clip01) {
  const CsvTable t = parse_csv(embedded_file(file), "embedded table " + file);
  if (t.header.size() < 2 || t.header[0] != "name")
    throw Error("embedded table " + file + ": expected a 'name' column followed by wavelength columns");
  SpectralTable s;
  s.file = file;
  for (std::size_t c = 1; c < t.header.size(); ++c) {
    char* end = nullptr;
    const double w = std::strtod(t.header[c].c_str(), &end);
    if (end == t.header[c].c_str() || (!s.wl_nm.empty() && !(w > s.wl_nm.back())))
      throw Error("embedded table " + file + ": column '" + t.header[c] + "' is not an ascending wavelength in nm");
    s.wl_nm.push_back(w);
  }
  const std::size_t n = t.raw[0].size();
  for (std::size_t r = 0; r < n; ++r) {
    std::vector<double> v;
    for (std::size_t c = 1; c < t.header.size(); ++c) {
      const double x = t.columns[c][r];
      if (!std::isfinite(x)) throw Error("embedded table " + file + ": row " + t.raw[0][r] + " has a non-number");
      v.push_back(clip01 ? std::clamp(x, 0.0, 1.0) : std::max(x, 0.0));
    }
    s.names.push_back(t.raw[0][r]);
    s.rows.push_back(std::move(v));
  }
  if (s.rows.empty()) throw Error("embedded table " + file + ": no rows");
  return s;
}

struct SyntheticTables {
  std::vector<SpectralTable> reflectance;
  SpectralTable illuminant;
};
const SyntheticTables& synthetic_tables() {
  static const SyntheticTables t = [] {
    SyntheticTables s;
    for (const std::string& f : synthetic_reflectance_files()) s.reflectance.push_back(load_table(f, true));
    s.illuminant = load_table(synthetic_illuminant_file(), false);
    return s;
  }();
  return t;
}

// Smooth value noise in [0, 1]: hashed lattice values, smoothstep-interpolated, 3 octaves.
double lattice(std::uint64_t seed, std::int64_t ix, std::int64_t iy) {
  const std::uint64_t h = splitmix64(seed ^ splitmix64(static_cast<std::uint64_t>(ix) * 0x9E3779B97F4A7C15ull +
                                                       static_cast<std::uint64_t>(iy) * 0xC2B2AE3D27D4EB4Full));
  return static_cast<double>(h >> 11) * (1.0 / 9007199254740992.0);
}
double value_noise(std::uint64_t seed, double x, double y) {
  const double fx0 = std::floor(x), fy0 = std::floor(y);
  const auto ix = static_cast<std::int64_t>(fx0), iy = static_cast<std::int64_t>(fy0);
  const double fx = x - fx0, fy = y - fy0;
  const double sx = fx * fx * (3 - 2 * fx), sy = fy * fy * (3 - 2 * fy);
  const double a = lattice(seed, ix, iy), b = lattice(seed, ix + 1, iy);
  const double c = lattice(seed, ix, iy + 1), d = lattice(seed, ix + 1, iy + 1);
  return (a + (b - a) * sx) * (1 - sy) + (c + (d - c) * sx) * sy;
}
double fractal_noise(std::uint64_t seed, double x, double y, double cell) {
  double sum = 0, norm = 0, amp = 1, f = 1 / cell;
  for (std::uint64_t o = 0; o < 3; ++o) {
    sum += amp * value_noise(seed + o, x * f, y * f);
    norm += amp;
    amp *= 0.5;
    f *= 2;
  }
  return sum / norm;
}

// One occluding shape, centre (cx, cy) and size r in pixels.
struct Shape {
  int type = 0;                   // 0 ellipse, 1 rotated rectangle, 2 star-shaped polygon
  double cx = 0, cy = 0, r = 1, aspect = 1, angle = 0;
  std::vector<double> px, py;     // polygon vertices (type 2)

  double bound() const { return r * std::sqrt(1 + aspect * aspect); }
  bool inside(double x, double y) const {
    const double dx = x - cx, dy = y - cy;
    if (type == 2) {  // crossing number
      bool in = false;
      for (std::size_t i = 0, j = px.size() - 1; i < px.size(); j = i++)
        if ((py[i] > y) != (py[j] > y) && x < (px[j] - px[i]) * (y - py[i]) / (py[j] - py[i]) + px[i]) in = !in;
      return in;
    }
    const double c = std::cos(angle), s = std::sin(angle);
    const double u = (dx * c + dy * s) / r, v = (-dx * s + dy * c) / (r * aspect);
    return type == 0 ? u * u + v * v <= 1 : (std::abs(u) <= 1 && std::abs(v) <= 1);
  }
};

// Per-material appearance: texture and shading parameters.
struct Look {
  double tex_amp = 0, tex_cell = 16, shade = 0, shade_angle = 0, cx = 0, cy = 0, r = 1;
  std::uint64_t tex_seed = 0;
};

}  // namespace

const std::vector<std::string>& synthetic_reflectance_files() {
  static const std::vector<std::string> f = {"munsell_matt_uef1269_400-700nm_10nm.csv",
                                             "rawtoaces_190patches_400-700nm_10nm.csv",
                                             "cie2017_cfi_ces99_400-700nm_10nm.csv"};
  return f;
}
const std::string& synthetic_illuminant_file() {
  static const std::string f = "cie_illuminants_400-700nm_10nm.csv";
  return f;
}

SyntheticScene synthetic_scene_detail(const SystemConfig& cfg, std::size_t size_px, std::uint64_t seed) {
  if (size_px == 0 || size_px > 16384) reject("size_px", size_px, "1 .. 16384 pixels");
  const std::vector<double> wl = cfg.wavelengths_nm();
  if (wl.empty()) reject("bands", wl.size(), "at least 1 band");
  const SyntheticTables& tables = synthetic_tables();
  std::mt19937_64 rng(mix_seed(seed, 0x5CE7Eu));
  const std::size_t S = size_px;
  const double Sd = static_cast<double>(S);

  SyntheticScene out;
  // Illuminant, scaled to max 1 on the band grid.
  {
    const SpectralTable& t = tables.illuminant;
    const std::size_t r = uniform_below(rng, t.rows.size());
    out.illuminant = t.file + ":" + t.names[r];
    out.illuminant_spd = interpolate_spectrum(t.wl_nm, t.rows[r], wl, "illuminant " + out.illuminant);
    const double mx = *std::max_element(out.illuminant_spd.begin(), out.illuminant_spd.end());
    if (!(mx > 0)) throw Error("illuminant " + out.illuminant + " is zero on the band grid");
    for (double& v : out.illuminant_spd) v /= mx;
  }
  auto draw_material = [&] {
    const SpectralTable& t = tables.reflectance[uniform_below(rng, tables.reflectance.size())];
    const std::size_t r = uniform_below(rng, t.rows.size());
    out.material.push_back(t.file + ":" + t.names[r]);
    out.reflectance.push_back(interpolate_spectrum(t.wl_nm, t.rows[r], wl, "reflectance " + out.material.back()));
  };
  auto draw_look = [&](double cx, double cy, double r) {
    Look l;
    l.tex_amp = uniform01(rng) < 0.3 ? 0.0 : uniform(rng, 0.05, 0.6);
    l.tex_cell = std::max(2.0, Sd * std::exp(uniform(rng, std::log(1.0 / 64), std::log(1.0 / 4))));
    l.tex_seed = rng();
    l.shade = uniform(rng, 0.0, 0.4);
    l.shade_angle = uniform(rng, 0.0, 2 * M_PI);
    l.cx = cx;
    l.cy = cy;
    l.r = std::max(r, 1.0);
    return l;
  };

  // Background (label 0), then K shapes in painter's order.
  std::vector<Look> looks;
  draw_material();
  looks.push_back(draw_look(Sd / 2, Sd / 2, Sd));
  out.label.assign(S * S, 0);
  const std::size_t K = 12 + uniform_below(rng, 29);  // 12 .. 40 shapes
  for (std::size_t k = 1; k <= K; ++k) {
    Shape sh;
    sh.type = static_cast<int>(uniform_below(rng, 3));
    sh.cx = uniform(rng, -0.1, 1.1) * Sd;
    sh.cy = uniform(rng, -0.1, 1.1) * Sd;
    sh.r = std::max(1.5, Sd * std::exp(uniform(rng, std::log(0.03), std::log(0.3))));  // log-uniform size
    sh.aspect = uniform(rng, 0.3, 1.0);
    sh.angle = uniform(rng, 0.0, M_PI);
    if (sh.type == 2) {
      const std::size_t nv = 3 + uniform_below(rng, 6);
      std::vector<double> ang(nv);
      for (double& a : ang) a = uniform(rng, 0.0, 2 * M_PI);
      std::sort(ang.begin(), ang.end());
      for (double a : ang) {
        const double rr = sh.r * uniform(rng, 0.5, 1.0);
        sh.px.push_back(sh.cx + rr * std::cos(a));
        sh.py.push_back(sh.cy + rr * std::sin(a));
      }
    }
    draw_material();
    looks.push_back(draw_look(sh.cx, sh.cy, sh.r));
    const double b = sh.bound();
    const auto lo = [&](double c) { return static_cast<std::size_t>(std::clamp(std::floor(c - b), 0.0, Sd)); };
    const auto hi = [&](double c) { return static_cast<std::size_t>(std::clamp(std::ceil(c + b) + 1, 0.0, Sd)); };
    for (std::size_t y = lo(sh.cy); y < hi(sh.cy); ++y)
      for (std::size_t x = lo(sh.cx); x < hi(sh.cx); ++x)
        if (sh.inside(static_cast<double>(x) + 0.5, static_cast<double>(y) + 0.5))
          out.label[y * S + x] = static_cast<std::uint32_t>(k);
  }

  // Albedo: exposure x global shading x per-shape shading x per-shape texture, in (0, 1].
  const double exposure = uniform(rng, 0.75, 1.0);
  const double g_shade = uniform(rng, 0.0, 0.4), g_angle = uniform(rng, 0.0, 2 * M_PI);
  const double gc = std::cos(g_angle), gs = std::sin(g_angle);
  out.albedo = Map2D(S, S);
  for (std::size_t y = 0; y < S; ++y)
    for (std::size_t x = 0; x < S; ++x) {
      const double fx = static_cast<double>(x) + 0.5, fy = static_cast<double>(y) + 0.5;
      const double ramp = std::clamp(((fx / Sd - 0.5) * gc + (fy / Sd - 0.5) * gs) * M_SQRT2, -1.0, 1.0);
      const Look& l = looks[out.label[y * S + x]];
      const double proj = std::clamp(((fx - l.cx) * std::cos(l.shade_angle) + (fy - l.cy) * std::sin(l.shade_angle)) / l.r,
                                     -1.0, 1.0);
      const double tex = l.tex_amp > 0 ? 1 - l.tex_amp * fractal_noise(l.tex_seed, fx, fy, l.tex_cell) : 1.0;
      out.albedo(y, x) = exposure * (1 - g_shade * (0.5 + 0.5 * ramp)) * (1 - l.shade * (0.5 + 0.5 * proj)) * tex;
    }

  // cube(b, y, x) = albedo(y, x) * reflectance[label][b] * illuminant[b].
  out.cube = RealStack(wl.size(), S, S);
  for (std::size_t b = 0; b < wl.size(); ++b) {
    double* plane = out.cube.plane(b);
    for (std::size_t i = 0; i < S * S; ++i)
      plane[i] = out.albedo.data[i] * out.reflectance[out.label[i]][b] * out.illuminant_spd[b];
  }
  return out;
}

RealStack synthetic_scene(const SystemConfig& cfg, std::size_t size_px, std::uint64_t seed) {
  return synthetic_scene_detail(cfg, size_px, seed).cube;
}


}  // namespace qdo
