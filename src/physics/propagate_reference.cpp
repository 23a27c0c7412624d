#include "qdo/physics/propagate_reference.hpp"

#include <cmath>

#include "qdo/runtime/error.hpp"
#include "reference_internal.hpp"

namespace qdo::ref {

using detail::fft2_batch;

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
