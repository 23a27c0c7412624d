// References that do not share the host code they check.
//
// The CPU reference and the OpenCL path both call delta_n_per_band, wavenumber_per_band,
// AreaWeights::make and sensor_response (src/physics/optics.cpp), so a bug there is invisible to the
// kernel-vs-reference tests. Every expected value here is computed in this file from first
// principles or from data typed in / read here with its own parser:
//   * n - 1 from the Sellmeier / Cauchy formulas with the published coefficients typed below;
//   * k = 2π/λ;
//   * the camera response from ../shared/data/spectral (a copy the simulator never reads),
//     parsed here, normalised here, interpolated here;
//   * the sensor area-resampling weights as overlap lengths of pixel intervals.
// The values are then pushed through the real paths (Simulator kernels, Camera, CPU
// reference) and compared.
#include <cmath>
#include <fstream>
#include <sstream>

#include "common.hpp"
#include "qdo/physics/cpu_reference.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/physics/camera.hpp"
#include "qdo/data/materials.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/simulator.hpp"
#include "stage_probes.hpp"

using namespace qdo;
using namespace qdo::test;

namespace {

// ---- Dispersion, written out independently of src/data/materials.cpp --------------------------
// Sellmeier n² = 1 + Σ B_i λ² / (λ² - C_i), λ in µm, C_i in µm². Coefficients as published:
//  OHARA S-K1300: wang-lizhi/QuantizationAwareDeepOptics constants.py
//    (refractive_index_glass_ohara_sk1300), as listed in shared/data/spectral/sellmeier_coefficients.csv;
//  SCHOTT N-BK7: Schott catalogue;
//  fused silica: Malitson, JOSA 55, 1205 (1965): B = 0.6961663, 0.4079426, 0.8974794 and
//    sqrt(C) = 0.0684043, 0.1162414, 9.896161 µm (so C is squared here, not copied).
double sellmeier_n_minus_1(const double b[3], const double c_um2[3], double wavelength_nm) {
  const double l2 = (wavelength_nm / 1000.0) * (wavelength_nm / 1000.0);
  double n2 = 1.0;
  for (int i = 0; i < 3; ++i) n2 += b[i] * l2 / (l2 - c_um2[i]);
  return std::sqrt(n2) - 1.0;
}

double independent_n_minus_1(const std::string& material, double wavelength_nm) {
  if (material == "OHARA_SK1300") {
    const double b[3] = {0.744386780, 0.360198890, 0.918623119};
    const double c[3] = {0.00495119834, 0.0141130274, 100.428510};
    return sellmeier_n_minus_1(b, c, wavelength_nm);
  }
  if (material == "SCHOTT_N-BK7") {
    const double b[3] = {1.03961212, 0.231792344, 1.01046945};
    const double c[3] = {0.00600069867, 0.0200179144, 103.560653};
    return sellmeier_n_minus_1(b, c, wavelength_nm);
  }
  if (material == "fused_silica_Malitson1965") {
    const double b[3] = {0.6961663, 0.4079426, 0.8974794};
    const double c[3] = {0.0684043 * 0.0684043, 0.1162414 * 0.1162414, 9.896161 * 9.896161};
    return sellmeier_n_minus_1(b, c, wavelength_nm);
  }
  // NOA61, Cauchy A + B/λ² + C/λ⁴ (λ in µm), Norland via refractiveindex.info.
  const double l2 = (wavelength_nm / 1000.0) * (wavelength_nm / 1000.0);
  return 1.5375 + 0.00829045 / l2 - 0.000211046 / (l2 * l2) - 1.0;
}

// ---- Camera response, read here from the shared copy of the table ---------------------------
struct SrfTable {
  std::vector<double> wl, r, g, b;
  const std::vector<double>& channel(int c) const { return c == 0 ? r : (c == 1 ? g : b); }
};

// Tiny CSV reader: skips '#' lines and the header, expects wavelength_nm,R,G,B rows.
bool read_srf_csv(const std::string& path, SrfTable& t) {
  std::ifstream in(path);
  if (!in) return false;
  std::string line;
  bool header = false;
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') continue;
    if (!header) {
      header = true;
      REQUIRE(line.rfind("wavelength_nm,R,G,B", 0) == 0);
      continue;
    }
    std::stringstream ss(line);
    std::string f[4];
    for (auto& s : f) std::getline(ss, s, ',');
    t.wl.push_back(std::stod(f[0]));
    t.r.push_back(std::stod(f[1]));
    t.g.push_back(std::stod(f[2]));
    t.b.push_back(std::stod(f[3]));
  }
  return true;
}

const char* kSharedSrf = "/data/spectral/qdo_srf_FLIR_GS3-U3-41S4C_400-700nm.csv";

// The 3 x B response on bands start + k step: linear interpolation between the bracketing
// table rows (exact rows taken as they are), then each channel divided by its sum over the bands.
std::vector<std::vector<double>> expected_srf(const SrfTable& t, double start, double step, std::size_t bands) {
  std::vector<std::vector<double>> s(3, std::vector<double>(bands, 0.0));
  for (std::size_t k = 0; k < bands; ++k) {
    const double w = start + step * double(k);
    std::size_t r = 0;
    while (r + 1 < t.wl.size() && t.wl[r + 1] <= w) ++r;  // t.wl[r] <= w < t.wl[r + 1]
    const double frac = (w - t.wl[r]) / (r + 1 < t.wl.size() ? t.wl[r + 1] - t.wl[r] : 1.0);
    for (int c = 0; c < 3; ++c) {
      const auto& v = t.channel(c);
      // w lies frac of the way from row r to row r + 1: weight (1 - frac) on row r.
      s[c][k] = frac == 0 ? v[r] : (1.0 - frac) * v[r] + frac * v[r + 1];
    }
  }
  for (auto& row : s) {
    double sum = 0;
    for (double v : row) sum += v;
    for (double& v : row) v /= sum;
  }
  return s;
}

// A bands x 1 x bands cube whose pixel x holds only band x, at value 1: the sensor image's
// pixel x is then column x of the camera response.
RealStack band_impulses(std::size_t bands) {
  RealStack cube(bands, 1, bands, 0.0);
  for (std::size_t b = 0; b < bands; ++b) cube(b, 0, b) = 1.0;
  return cube;
}

SystemConfig srf_config() {
  SystemConfig c = preset_config("small");  // 400..700 nm in 10 nm steps, the built-in camera
  c.n = 32;
  c.padding_px = 8;
  c.sensor_distance_m = 0.0125 * 32.0 / 256.0;
  c.read_noise_sigma = 0;
  c.full_well_photons = 0;
  c.validate();
  return c;
}

// ---- Area weights from first principles ---------------------------------------------------
// Input cell i covers [(i - n/2) - 1/2, (i - n/2) + 1/2] input pitches around the axis; output
// pixel o covers [(o - s/2) - 1/2, (o - s/2) + 1/2] output pitches. The weight is the length of
// the overlap in units of the input cell (the fraction of cell i inside pixel o).
double overlap_weight(std::size_t o, std::size_t s, double pitch_out, std::size_t i, std::size_t n, double pitch_in) {
  const double o_lo = (double(o) - double(s / 2) - 0.5) * pitch_out, o_hi = o_lo + pitch_out;
  const double i_lo = (double(i) - double(n / 2) - 0.5) * pitch_in, i_hi = i_lo + pitch_in;
  return std::max(0.0, std::min(o_hi, i_hi) - std::max(o_lo, i_lo)) / pitch_in;
}

// Dense S x N matrix of AreaWeights (start/taps layout unpacked).
std::vector<double> dense(const AreaWeights& a) {
  std::vector<double> m(a.s * a.n, 0.0);
  for (std::size_t o = 0; o < a.s; ++o)
    for (std::size_t t = 0; t < a.taps; ++t) {
      const long i = a.start[o] + long(t);
      if (i >= 0 && i < long(a.n)) m[o * a.n + std::size_t(i)] += a.w[o * a.taps + t];
    }
  return m;
}

// psf (planes x n x n) -> planes x s x s with the first-principles weights, normalised per plane.
RealStack resample_independent(const RealStack& psf, std::size_t s, double pitch_in, double pitch_out) {
  const std::size_t n = psf.rows;
  std::vector<double> w(s * n);
  for (std::size_t o = 0; o < s; ++o)
    for (std::size_t i = 0; i < n; ++i) w[o * n + i] = overlap_weight(o, s, pitch_out, i, n, pitch_in);
  RealStack out(psf.planes, s, s, 0.0);
  for (std::size_t p = 0; p < psf.planes; ++p) {
    double sum = 0;
    for (std::size_t oy = 0; oy < s; ++oy)
      for (std::size_t ox = 0; ox < s; ++ox) {
        double acc = 0;
        for (std::size_t iy = 0; iy < n; ++iy) {
          const double wy = w[oy * n + iy];
          if (wy == 0) continue;
          for (std::size_t ix = 0; ix < n; ++ix) acc += wy * w[ox * n + ix] * psf(p, iy, ix);
        }
        out(p, oy, ox) = acc;
        sum += acc;
      }
    for (std::size_t k = 0; k < s * s; ++k) out.plane(p)[k] /= sum;
  }
  return out;
}

}  // namespace

TEST_SUITE("references") {
  TEST_CASE("n - 1 and k per band equal the published Sellmeier/Cauchy formulas and 2 pi / lambda") {
    // Same formula, independent code and typed-in coefficients: agreement to double rounding
    // (a few 1e-16 relative on n ~ 1.5); 1e-12 leaves margin and is 1e12 times below the
    // n-instead-of-(n-1) error (which is 1.0).
    for (const auto& mat : material_names()) {
      CAPTURE(mat);
      SystemConfig c = preset_config("small");
      c.material = mat;
      c.validate();
      const auto dn = delta_n_per_band(c);
      const auto k = wavenumber_per_band(c);
      REQUIRE(dn.size() == 31);
      REQUIRE(k.size() == 31);
      for (std::size_t b = 0; b < 31; ++b) {
        const double wl = 400.0 + 10.0 * double(b);
        CAPTURE(wl);
        CHECK(std::fabs(dn[b] - independent_n_minus_1(mat, wl)) <= 1e-12);
        CHECK(std::fabs(k[b] - 2 * M_PI / (wl * 1e-9)) <= 1e-12 * k[b]);
      }
    }
    // Anchor of the typed-in SK1300 coefficients (REFERENCE §1: n(700 nm) = 1.45546).
    CHECK(std::fabs(independent_n_minus_1("OHARA_SK1300", 700) - 0.45546) <= 1e-5);
  }

  TEST_CASE("the DOE field phase (kernel and CPU reference) is 2 pi / lambda (n - 1) H with independent n - 1") {
    SystemConfig c = tiny_config(32, 5);  // 450 .. 550 nm
    c.scene_at_infinity = true;           // plane wave: the phase is the DOE term alone
    c.validate();
    const double h0 = 0.37 * c.h_max_m();
    const Map2D flat(c.n, c.n, h0);
    Simulator sim(runtime(), c, Precision::F32);
    sim.set_heights(flat);
    const ComplexStack got = field_after_doe(sim);
    const ComplexStack ref_field = ref::doe_field(c, flat, sim.geometry());
    const std::size_t centre = sim.geometry().offset + c.n / 2;
    for (std::size_t b = 0; b < c.bands; ++b) {
      const double wl = c.wavelengths_nm()[b];
      CAPTURE(wl);
      const double phase = 2 * M_PI / (wl * 1e-9) * independent_n_minus_1(c.material, wl) * h0;
      const cdouble want = std::polar(1.0, phase);
      // float32: the kernel evaluates a phase of |phase| <~ 2.5 rad (k (n-1) H with H = 0.37
      // h_max) and its sine/cosine; a few ulps of that is < 1e-6 rad; 1e-5 rad is the bound.
      // The n-instead-of-(n-1) bug adds k H = 2π H / λ ~ 10 rad here.
      CHECK(std::fabs(std::arg(got(b, centre, centre) / want)) <= 1e-5);
      CHECK(std::fabs(std::arg(ref_field(b, centre, centre) / want)) <= 1e-12);
      CHECK(std::abs(got(b, centre, centre)) == doctest::Approx(1.0).epsilon(1e-6));
    }
  }

  TEST_CASE("a single-band cube gives that band's camera-response column (CSV parsed here; kernels, imager, CPU reference)") {
    const SystemConfig c = srf_config();
    {
      // Without ../shared too: ratios of raw values typed from the upstream constants.py
      // ([B,G,R] rows) — B 460/400 nm, G 540/400 nm, R 610/400 nm, R 450/460 nm — against the
      // built-in response (ratios cancel the row normalisation). Double: 1e-9 relative.
      const Eigen::MatrixXd s0 = sensor_response(c);
      CHECK(s0(2, 6) / s0(2, 0) == doctest::Approx(49.34113124 / 18.73589729).epsilon(1e-9));
      CHECK(s0(1, 14) / s0(1, 0) == doctest::Approx(61.75104661 / 6.425137553).epsilon(1e-9));
      CHECK(s0(0, 21) / s0(0, 0) == doctest::Approx(56.03542013 / 7.111793475).epsilon(1e-9));
      CHECK(s0(0, 5) / s0(0, 6) == doctest::Approx(2.011189415 / 1.765684355).epsilon(1e-9));
    }
    const std::string path = std::string(shared_dir()) + kSharedSrf;
    SrfTable t;
    if (!skip_unless(read_srf_csv(path, t), path + " not found (needs ../shared)")) return;
    REQUIRE(t.wl.size() == 31);
    const auto want = expected_srf(t, c.wavelength_start_nm, c.wavelength_step_nm, c.bands);
    // Spot values typed from the upstream constants.py ([B,G,R] rows), independent of any file:
    // channel peaks B at 460 nm, G at 540 nm, R at 610 nm against the 400 nm row.
    CHECK(want[2][6] / want[2][0] == doctest::Approx(49.34113124 / 18.73589729).epsilon(1e-9));
    CHECK(want[1][14] / want[1][0] == doctest::Approx(61.75104661 / 6.425137553).epsilon(1e-9));
    CHECK(want[0][21] / want[0][0] == doctest::Approx(56.03542013 / 7.111793475).epsilon(1e-9));

    // The host table: same numbers, independent parsing and normalisation: 1e-12 relative.
    const Eigen::MatrixXd s = sensor_response(c);
    for (int ch = 0; ch < 3; ++ch)
      for (std::size_t b = 0; b < c.bands; ++b) CHECK(s(ch, Eigen::Index(b)) == doctest::Approx(want[ch][b]).epsilon(1e-12));

    // Kernel sensor integration of band impulses: float32 products of values < 0.1 summed over
    // 31 bands (30 of them zero): error < 1e-8 absolute; 1e-7 is the bound. Columns of the
    // response differ by > 1e-4 between neighbouring bands in at least one channel.
    Simulator sim(runtime(), c, Precision::F32);
    const RealStack imp = band_impulses(c.bands);
    const RealStack rgb_k = sim.integrate(imp);
    const RealStack rgb_r = ref::sensor_integrate(imp, sensor_response(c));
    for (int ch = 0; ch < 3; ++ch)
      for (std::size_t b = 0; b < c.bands; ++b) {
        CAPTURE(ch);
        CAPTURE(b);
        CHECK(std::fabs(rgb_k(std::size_t(ch), 0, b) - want[ch][b]) <= 1e-7);
        CHECK(std::fabs(rgb_r(std::size_t(ch), 0, b) - want[ch][b]) <= 1e-14);
      }

    // Through the optics: a cube uniform in one band, any unit-sum PSF. Circular convolution
    // (Simulator) keeps a uniform plane exactly; linear convolution (Camera, exact mode)
    // keeps it at pixels whose PSF footprint (offsets up to S/2) lies inside the scene. float32
    // FFT convolution of values <= 1 over a <= 64 x 64 grid: error ~ eps log2(P) ~ 1e-6; 1e-5
    // is the bound (a band swap moves some channel by >= 1e-4).
    SystemConfig cc = c;
    cc.convolution = ConvolutionMode::Circular;
    Simulator simc(runtime(), cc, Precision::F32);
    Camera camc(simc);
    simc.set_heights(random_heights(cc.n, cc.h_max_m(), 5));
    simc.compute_psf();
    sim.set_heights(random_heights(c.n, c.h_max_m(), 5));
    sim.compute_psf();
    const std::size_t hw = 24, s_px = sim.sensor_size();  // S = 16: centre pixel 12 has offsets 4 .. 20
    std::vector<RealStack> cubes;
    for (std::size_t b = 0; b < c.bands; ++b) {
      RealStack cube(c.bands, hw, hw, 0.0);
      for (std::size_t i = 0; i < hw * hw; ++i) cube.plane(b)[i] = 1.0;
      cubes.push_back(cube);
    }
    const auto circ = camc.images(cubes, no_skipping());
    Camera imager(sim);
    SkipOptions exact;
    exact.exact = true;
    const auto lin = imager.images(cubes, exact);
    const RealStack ref_lin = ref::sensor_integrate(ref::convolve(cubes[7], sim.psf_sensor(), ConvolutionMode::Linear),
                                                    sensor_response(c));
    REQUIRE(hw / 2 >= s_px / 2);
    for (std::size_t b = 0; b < c.bands; ++b)
      for (int ch = 0; ch < 3; ++ch) {
        CAPTURE(b);
        CAPTURE(ch);
        CHECK(std::fabs(circ[b](std::size_t(ch), 3, 17) - want[ch][b]) <= 1e-5);
        CHECK(std::fabs(lin[b](std::size_t(ch), hw / 2, hw / 2) - want[ch][b]) <= 1e-5);
      }
    // The CPU reference convolves with the kernels' float32 PSF, whose sum is 1 only to float32
    // rounding (S² = 256 values of relative error <= 6e-8): 2e-6 relative covers it.
    for (int ch = 0; ch < 3; ++ch)
      CHECK(std::fabs(ref_lin(std::size_t(ch), hw / 2, hw / 2) - want[ch][7]) <= 2e-6 * want[ch][7]);
  }

  TEST_CASE("an interpolated camera response equals the hand-computed linear interpolation") {
    const std::string path = std::string(shared_dir()) + kSharedSrf;
    SrfTable t;
    if (!skip_unless(read_srf_csv(path, t), path + " not found (needs ../shared)")) return;
    SystemConfig c = srf_config();
    c.wavelength_start_nm = 403;  // 403, 413, ... 693 nm: 0.3 of the way between table rows
    c.bands = 30;
    c.srf_interpolate = true;
    c.validate();
    // By hand: band k lies between rows k and k + 1 with weight 0.7 on row k, 0.3 on row k + 1.
    std::vector<std::vector<double>> want(3, std::vector<double>(30));
    for (int ch = 0; ch < 3; ++ch) {
      double sum = 0;
      for (std::size_t k = 0; k < 30; ++k) sum += want[ch][k] = 0.7 * t.channel(ch)[k] + 0.3 * t.channel(ch)[k + 1];
      for (double& v : want[ch]) v /= sum;
    }
    const auto generic = expected_srf(t, 403, 10, 30);  // the helper above agrees
    const Eigen::MatrixXd s = sensor_response(c);
    Simulator sim(runtime(), c, Precision::F32);
    const RealStack rgb = sim.integrate(band_impulses(c.bands));
    for (int ch = 0; ch < 3; ++ch)
      for (std::size_t k = 0; k < 30; ++k) {
        CAPTURE(ch);
        CAPTURE(k);
        CHECK(generic[ch][k] == doctest::Approx(want[ch][k]).epsilon(1e-12));
        // Flipping the weights (0.3 <-> 0.7) moves a value by 0.4 |row k+1 - row k| / sum,
        // > 1e-4 for most bands; double: 1e-12 relative; float32 kernel: 1e-7 absolute (as above).
        CHECK(s(ch, Eigen::Index(k)) == doctest::Approx(want[ch][k]).epsilon(1e-12));
        CHECK(std::fabs(rgb(std::size_t(ch), 0, k) - want[ch][k]) <= 1e-7);
      }
  }

  TEST_CASE("sensor area weights are pixel-interval overlaps; an axis point lands on the centre pixel") {
    // Pitch ratios 2 (4 -> 8 µm) and 2.5 (4 -> 10 µm, fractional overlaps).
    for (double pitch_out : {8e-6, 10e-6}) {
      CAPTURE(pitch_out);
      const std::size_t n = 64, s = std::size_t(std::llround(64 * 4e-6 / pitch_out));
      const AreaWeights a = AreaWeights::make(n, 4e-6, s, pitch_out);
      const auto m = dense(a);
      for (std::size_t o = 0; o < s; ++o)
        for (std::size_t i = 0; i < n; ++i) {
          CAPTURE(o);
          CAPTURE(i);
          // Overlaps are sums/differences of multiples of 0.5: exact up to a few ulps.
          CHECK(std::fabs(m[o * n + i] - overlap_weight(o, s, pitch_out, i, n, 4e-6)) <= 1e-12);
        }
      // A point on the native axis (cell n/2, [-2, 2] µm) lies wholly in the centre pixel
      // ([-p/2, p/2]); its neighbour (cell n/2 + 1, [2, 6] µm) splits 0.5 : 0.5 at p = 8 µm
      // ([-4, 4] µm holds [2, 4]) and 0.75 : 0.25 at p = 10 µm ([-5, 5] holds [2, 5]).
      CHECK(m[(s / 2) * n + n / 2] == 1.0);
      for (std::size_t o = 0; o < s; ++o)
        if (o != s / 2) CHECK(m[o * n + n / 2] == 0.0);
      const double w_next = pitch_out == 8e-6 ? 0.5 : 0.75;
      CHECK(std::fabs(m[(s / 2) * n + n / 2 + 1] - w_next) <= 1e-12);
      CHECK(std::fabs(m[(s / 2 + 1) * n + n / 2 + 1] - (1 - w_next)) <= 1e-12);
    }

    // The real path: a focused PSF resampled by the kernels equals the first-principles
    // resampling of the kernels' own native PSF. float32 sums of <= 9 weighted terms then a
    // normalisation: ~1e-6 relative; 1e-5 is the bound (a half-pixel shift of the grid moves a
    // focused spot's energy between pixels by tens of percent).
    SystemConfig c = tiny_config(64, 2);
    c.sensor_pitch_m = 10e-6;
    c.scene_at_infinity = true;
    c.validate();
    Simulator sim(runtime(), c, Precision::F32);
    sim.set_heights(lens_design(c, 500));
    sim.compute_psf();
    const RealStack want = resample_independent(sim.psf_native(), sim.sensor_size(), c.pitch_m, c.sensor_pitch_m);
    const auto d = diff(sim.psf_sensor().data, want.data);
    CAPTURE(d.rel_l2);
    CHECK(d.rel_l2 <= 1e-5);
    // And the CPU reference chain (its native PSF, AreaWeights, normalisation): double.
    const auto rp = ref::psf_stack(c, lens_design(c, 500));
    RealStack rs = ref::resample_area(rp.psf, AreaWeights::make(c.n, c.pitch_m, sim.sensor_size(), c.sensor_pitch_m));
    ref::normalize_planes(rs);
    const RealStack want_r = resample_independent(rp.psf, sim.sensor_size(), c.pitch_m, c.sensor_pitch_m);
    CHECK(diff(rs.data, want_r.data).rel_l2 <= 1e-12);
  }
}
