#include "qdo/cpu_reference.hpp"

#include <fftw3.h>

#include <cmath>
#include <memory>
#include <mutex>

#include "qdo/error.hpp"
#include "qdo/fftw2.hpp"
#include "qdo/rng.hpp"

namespace qdo::ref {
namespace {

// In-place batched 2-D FFT of the planes of s; the backward transform is scaled by 1/(rows*cols).
void fft2_batch(ComplexStack& s, int sign) { fftw2(s, sign == FFTW_FORWARD, true); }

}  // namespace

ComplexStack doe_field(const SystemConfig& cfg, const Map2D& height_m, const PropagationGeometry& g) {
  if (height_m.rows != cfg.n || height_m.cols != cfg.n)
    reject("height_m", to_str(height_m.rows) + " x " + to_str(height_m.cols), "an N x N map with N = " + to_str(cfg.n));
  const auto k = wavenumber_per_band(cfg);
  const auto dn = delta_n_per_band(cfg);
  // Aperture: integer pixel radius² against cfg.aperture_inside_px2() (aperture_edge), as kernels/field.cl.
  const double r_ap2_px = cfg.aperture_inside_px2();
  const double d = cfg.scene_distance_m;
  ComplexStack f(cfg.bands, g.m, g.m, cdouble(0, 0));
  for (std::size_t b = 0; b < cfg.bands; ++b) {
    for (std::size_t i = 0; i < g.n; ++i) {
      for (std::size_t j = 0; j < g.n; ++j) {
        const double y = (double(i) - double(g.n / 2)) * g.pitch_m, x = (double(j) - double(g.n / 2)) * g.pitch_m;
        const double r2 = x * x + y * y;
        const double di = double(i) - double(g.n / 2), dj = double(j) - double(g.n / 2);
        if (di * di + dj * dj > r_ap2_px) continue;
        const double src = cfg.scene_at_infinity ? 0.0 : r2 / (std::sqrt(r2 + d * d) + d);
        const double phase = k[b] * (src + dn[b] * height_m(i, j));
        f(b, g.offset + i, g.offset + j) = std::polar(1.0, phase);
      }
    }
  }
  return f;
}

void propagate(ComplexStack& field, const std::vector<double>& wavelengths_nm, double pitch_m, double z_m,
               Propagator method, std::vector<BandSampling>* sampling) {
  if (field.rows != field.cols) reject("field", to_str(field.rows) + " x " + to_str(field.cols), "a square window");
  if (wavelengths_nm.size() != field.planes) reject("wavelengths_nm.size()", wavelengths_nm.size(), "one per plane");
  const std::size_t m = field.rows;
  fft2_batch(field, FFTW_FORWARD);
  if (sampling) sampling->assign(field.planes, BandSampling{});
  for (std::size_t b = 0; b < field.planes; ++b) {
    const double lambda = wavelengths_nm[b] * 1e-9;
    const double f_lim = transfer_function_limit_per_m(method, wavelengths_nm[b], z_m, m, pitch_m);
    double e_total = 0, e_beyond = 0;
    for (std::size_t ky = 0; ky < m; ++ky) {
      const double fy = fft_frequency(ky, m, pitch_m);
      for (std::size_t kx = 0; kx < m; ++kx) {
        const double fx = fft_frequency(kx, m, pitch_m);
        cdouble& v = field(b, ky, kx);
        const double e = std::norm(v);
        e_total += e;
        const bool beyond = std::fabs(fx) > f_lim || std::fabs(fy) > f_lim;
        if (beyond) e_beyond += e;
        const double f2 = fx * fx + fy * fy;
        double phase = 0;
        if (method == Propagator::Fresnel) {
          phase = -M_PI * lambda * z_m * f2;
        } else {
          // Band-limited angular spectrum: 2πz (sqrt(1/λ² - f²) - 1/λ), zero beyond the limit.
          if (beyond || f2 * lambda * lambda >= 1.0) {
            v = 0;
            continue;
          }
          const double inv_l = 1.0 / lambda;
          phase = -2.0 * M_PI * z_m * f2 / (std::sqrt(inv_l * inv_l - f2) + inv_l);
        }
        v *= std::polar(1.0, phase);
      }
    }
    if (sampling) {
      BandSampling& s = (*sampling)[b];
      s.wavelength_nm = wavelengths_nm[b];
      s.f_limit_per_m = f_lim;
      s.f_nyquist_per_m = 0.5 / pitch_m;
      s.undersampled = f_lim < s.f_nyquist_per_m;
      s.aliased_energy_fraction = e_total > 0 ? e_beyond / e_total : 0.0;
    }
  }
  fft2_batch(field, FFTW_BACKWARD);
}

PsfResult psf_stack(const SystemConfig& cfg, const Map2D& height_m) {
  cfg.validate();
  const auto g = PropagationGeometry::from_config(cfg);
  for (double h : height_m.data)
    if (!std::isfinite(h)) reject("height_m", h, "finite heights");
  ComplexStack f = doe_field(cfg, height_m, g);
  PsfResult out;
  propagate(f, cfg.wavelengths_nm(), cfg.pitch_m, cfg.sensor_distance_m, cfg.propagator, &out.sampling.bands);
  out.psf = RealStack(cfg.bands, g.n, g.n);
  for (std::size_t b = 0; b < cfg.bands; ++b) {
    double total = 0, inside = 0;
    for (std::size_t i = 0; i < g.m * g.m; ++i) total += std::norm(f.plane(b)[i]);
    for (std::size_t i = 0; i < g.n; ++i)
      for (std::size_t j = 0; j < g.n; ++j) {
        const double e = std::norm(f(b, g.offset + i, g.offset + j));
        out.psf(b, i, j) = e;
        inside += e;
      }
    out.sampling.bands[b].energy_outside_window = total > 0 ? 1.0 - inside / total : 0.0;
  }
  normalize_planes(out.psf);
  check_source_sampling(cfg, out.sampling.bands);
  if (cfg.strict_sampling) out.sampling.enforce();
  return out;
}

RealStack resample_area(const RealStack& psf, const AreaWeights& w) {
  if (psf.rows != w.n || psf.cols != w.n) reject("psf", to_str(psf.rows) + " x " + to_str(psf.cols), "N x N with N = " + to_str(w.n));
  RealStack out(psf.planes, w.s, w.s);
  for (std::size_t b = 0; b < psf.planes; ++b)
    for (std::size_t oy = 0; oy < w.s; ++oy)
      for (std::size_t ox = 0; ox < w.s; ++ox) {
        double acc = 0;
        for (std::size_t ty = 0; ty < w.taps; ++ty) {
          const double wy = w.w[oy * w.taps + ty];
          if (wy == 0) continue;
          const std::size_t iy = static_cast<std::size_t>(w.start[oy]) + ty;
          for (std::size_t tx = 0; tx < w.taps; ++tx) {
            const double wx = w.w[ox * w.taps + tx];
            if (wx == 0) continue;
            acc += wy * wx * psf(b, iy, static_cast<std::size_t>(w.start[ox]) + tx);
          }
        }
        out(b, oy, ox) = acc;
      }
  return out;
}

void normalize_planes(RealStack& s) {
  for (std::size_t b = 0; b < s.planes; ++b) {
    double sum = 0;
    for (std::size_t i = 0; i < s.plane_size(); ++i) sum += s.plane(b)[i];
    if (sum > 0)
      for (std::size_t i = 0; i < s.plane_size(); ++i) s.plane(b)[i] /= sum;
  }
}

RealStack convolve(const RealStack& cube, const RealStack& psf, ConvolutionMode mode) {
  if (cube.planes != psf.planes) reject("cube bands", cube.planes, "the PSF stack's band count (" + to_str(psf.planes) + ")");
  if (psf.rows != psf.cols) reject("psf", to_str(psf.rows) + " x " + to_str(psf.cols), "square PSFs");
  const std::size_t h = cube.rows, w = cube.cols, s = psf.rows, c = s / 2;
  const std::size_t py = mode == ConvolutionMode::Linear ? fast_fft_size(h + s - 1) : h;
  const std::size_t px = mode == ConvolutionMode::Linear ? fast_fft_size(w + s - 1) : w;
  ComplexStack a(cube.planes, py, px, cdouble(0, 0)), k(cube.planes, py, px, cdouble(0, 0));
  for (std::size_t b = 0; b < cube.planes; ++b) {
    for (std::size_t y = 0; y < h; ++y)
      for (std::size_t x = 0; x < w; ++x) a(b, y, x) = cube(b, y, x);
    // PSF centre (c, c) goes to index (0, 0); wrap (and, for circular, fold) the rest.
    for (std::size_t y = 0; y < s; ++y)
      for (std::size_t x = 0; x < s; ++x) {
        const std::size_t ty = (y + py * s - c) % py, tx = (x + px * s - c) % px;
        k(b, ty, tx) += psf(b, y, x);
      }
  }
  fft2_batch(a, FFTW_FORWARD);
  fft2_batch(k, FFTW_FORWARD);
  for (std::size_t i = 0; i < a.size(); ++i) a.data[i] *= k.data[i];
  fft2_batch(a, FFTW_BACKWARD);
  RealStack out(cube.planes, h, w);
  for (std::size_t b = 0; b < cube.planes; ++b)
    for (std::size_t y = 0; y < h; ++y)
      for (std::size_t x = 0; x < w; ++x) out(b, y, x) = a(b, y, x).real();
  return out;
}

RealStack sensor_integrate(const RealStack& blurred, const Eigen::MatrixXd& srf) {
  if (srf.rows() != 3 || static_cast<std::size_t>(srf.cols()) != blurred.planes)
    reject("srf", to_str(srf.rows()) + " x " + to_str(srf.cols()), "3 x bands with bands = " + to_str(blurred.planes));
  const std::size_t hw = blurred.plane_size();
  RealStack rgb(3, blurred.rows, blurred.cols);
  Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>> x(
      blurred.data.data(), static_cast<Eigen::Index>(blurred.planes), static_cast<Eigen::Index>(hw));
  Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>> y(rgb.data.data(), 3,
                                                                                       static_cast<Eigen::Index>(hw));
  y.noalias() = srf * x;
  return rgb;
}

void add_noise(RealStack& rgb, double read_noise_sigma, double full_well_photons, unsigned long long seed,
               std::size_t scene_index) {
  if (!(read_noise_sigma >= 0) || !std::isfinite(read_noise_sigma)) reject("read_noise_sigma", read_noise_sigma, ">= 0, finite");
  if (!(full_well_photons >= 0) || !std::isfinite(full_well_photons)) reject("full_well_photons", full_well_photons, ">= 0, finite");
  if (read_noise_sigma == 0 && full_well_photons == 0) return;
  const std::size_t hw = rgb.plane_size();
  for (std::size_t c = 0; c < rgb.planes; ++c)
    for (std::size_t p = 0; p < hw; ++p) {
      const NoiseDraw d = noise_draw(seed, (scene_index * hw + p) * 3 + c);
      double v = rgb.plane(c)[p];
      if (full_well_photons > 0) v = poisson_from(std::fmax(v, 0.0) * full_well_photons, d) / full_well_photons;
      rgb.plane(c)[p] = v + read_noise_sigma * d.gaussian;
    }
}

ComplexStack fresnel_integral_direct(const ComplexStack& field, double wavelength_nm, double pitch_m, double z_m) {
  const double lambda = wavelength_nm * 1e-9;
  const std::size_t n = field.rows;
  ComplexStack out(1, n, n, cdouble(0, 0));
  // U2(x) = 1/(iλz) Σ U1(x') exp(iπ/(λz) |x - x'|²) Δ²  (exp(ikz) dropped)
  const cdouble pre = pitch_m * pitch_m / (cdouble(0, 1) * lambda * z_m);
  std::vector<cdouble> kern(2 * n - 1);
  for (std::size_t t = 0; t < 2 * n - 1; ++t) {
    const double dx = (double(t) - double(n - 1)) * pitch_m;
    kern[t] = std::polar(1.0, M_PI * dx * dx / (lambda * z_m));
  }
  for (std::size_t i = 0; i < n; ++i)
    for (std::size_t j = 0; j < n; ++j) {
      cdouble acc = 0;
      for (std::size_t a = 0; a < n; ++a) {
        const cdouble ky = kern[i + n - 1 - a];
        for (std::size_t b = 0; b < n; ++b) acc += field(0, a, b) * ky * kern[j + n - 1 - b];
      }
      out(0, i, j) = pre * acc;
    }
  return out;
}

}  // namespace qdo::ref
