#include "qdo/decode/encoders.hpp"

#include <algorithm>
#include <cmath>
#include <utility>

#include "qdo/physics/cpu_reference.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/fftw2.hpp"
#include "qdo/data/materials.hpp"
#include "qdo/runtime/rng.hpp"

namespace qdo {
namespace {

using Eigen::Index;

Index idx(std::size_t i) { return static_cast<Index>(i); }

void check_finite(const std::string& name, const std::vector<double>& v) {
  for (std::size_t i = 0; i < v.size(); ++i)
    if (!std::isfinite(v[i])) reject(name + "[" + to_str(i) + "]", v[i], "finite values");
}

void check_sigma(double noise_sigma) {
  if (!(noise_sigma >= 0) || !std::isfinite(noise_sigma)) reject("noise_sigma", noise_sigma, ">= 0, finite");
}

ComplexStack to_complex(const RealStack& r) {
  ComplexStack c(r.planes, r.rows, r.cols);
  for (std::size_t i = 0; i < r.size(); ++i) c.data[i] = r.data[i];
  return c;
}

RealStack real_part(const ComplexStack& c) {
  RealStack r(c.planes, c.rows, c.cols);
  for (std::size_t i = 0; i < c.size(); ++i) r.data[i] = c.data[i].real();
  return r;
}

double dot(const std::vector<double>& a, const std::vector<double>& b) {
  double s = 0;
  for (std::size_t i = 0; i < a.size(); ++i) s += a[i] * b[i];
  return s;
}

// C^power per bin, applied in the DFT domain (see encoders.hpp).
class PriorPower {
 public:
  PriorPower(const wiener::SpectralPrior& prior, double power) : bands_(prior.bands), rows_(prior.rows), cols_(prior.cols) {
    prior.validate();
    if (!std::isfinite(power)) reject("power", power, "finite");
    // The spectrum of a real x is Hermitian and P^power is real and shared by f and -f, so the
    // output is Hermitian too: only one frequency of each pair (f, -f) is computed.
    members_.resize(prior.bins);
    mirrors_.resize(prior.bins);
    for (std::size_t ky = 0; ky < rows_; ++ky)
      for (std::size_t kx = 0; kx < cols_; ++kx) {
        const std::size_t f = ky * cols_ + kx, mirror = ((rows_ - ky) % rows_) * cols_ + (cols_ - kx) % cols_;
        if (mirror < f) continue;
        const std::size_t k = wiener::radial_bin(ky, kx, rows_, cols_, prior.bins);
        members_[k].push_back(f);
        mirrors_[k].push_back(mirror);
      }
    mats_.resize(prior.bins);
    for (std::size_t k = 0; k < prior.bins; ++k) {
      if (members_[k].empty()) continue;  // never applied on this grid
      const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(prior.bin(k));
      Eigen::VectorXd ev = es.eigenvalues();
      const double scale = std::max(ev.cwiseAbs().maxCoeff(), 1e-300);
      for (Index i = 0; i < ev.size(); ++i) {
        if (power > 0) {
          ev(i) = power == 1.0 ? std::max(ev(i), 0.0) : std::pow(std::max(ev(i), 0.0), power);
        } else {
          if (!(ev(i) > 1e-14 * scale))
            reject("prior.cov (bin " + to_str(k) + ")", ev(i), "positive definite for power " + to_str(power));
          ev(i) = std::pow(ev(i), power);
        }
      }
      mats_[k] = es.eigenvectors() * ev.asDiagonal() * es.eigenvectors().transpose();
    }
  }

  // out = C^power x; x, out: B x H x W on the prior's grid (out is resized; may alias x).
  // Not const: reuses its transform buffer (one PriorPower per thread).
  void apply(const RealStack& x, RealStack& out) {
    if (x.planes != bands_ || x.rows != rows_ || x.cols != cols_)
      reject("x", shape(x), "the prior's B x H x W = " + shape(bands_, rows_, cols_));
    ComplexStack& c = work_;
    if (c.size() != x.size()) c = ComplexStack(bands_, rows_, cols_);
    for (std::size_t i = 0; i < x.size(); ++i) c.data[i] = x.data[i];
    fftw2(c, true);
    // Per bin, one real GEMM: P^power (B x B) times the bin's coefficients as B x 2m reals
    // (real parts, then imaginary parts).
    const std::size_t n = rows_ * cols_;
    Eigen::MatrixXd& g = gemm_;
    for (std::size_t k = 0; k < members_.size(); ++k) {
      const std::vector<std::size_t>& fs = members_[k];
      const std::vector<std::size_t>& ms = mirrors_[k];
      const std::size_t m = fs.size();
      if (m == 0) continue;
      g.resize(idx(bands_), idx(2 * m));
      for (std::size_t b = 0; b < bands_; ++b)
        for (std::size_t j = 0; j < m; ++j) {
          const cdouble v = c.data[b * n + fs[j]];
          g(idx(b), idx(j)) = v.real();
          g(idx(b), idx(m + j)) = v.imag();
        }
      gemm_out_.resize(idx(bands_), idx(2 * m));
      gemm_out_.noalias() = mats_[k] * g;
      for (std::size_t b = 0; b < bands_; ++b)
        for (std::size_t j = 0; j < m; ++j) {
          c.data[b * n + fs[j]] = cdouble(gemm_out_(idx(b), idx(j)), gemm_out_(idx(b), idx(m + j)));
          c.data[b * n + ms[j]] = std::conj(c.data[b * n + fs[j]]);  // exact Hermitian symmetry
        }
    }
    fftw2(c, false, true);
    if (out.planes != bands_ || out.rows != rows_ || out.cols != cols_) out = RealStack(bands_, rows_, cols_);
    for (std::size_t i = 0; i < c.size(); ++i) out.data[i] = c.data[i].real();
  }
  RealStack apply(const RealStack& x) {
    RealStack out;
    apply(x, out);
    return out;
  }

 private:
  std::size_t bands_, rows_, cols_;
  std::vector<std::vector<std::size_t>> members_;  // per bin, one DFT frequency ky·W + kx of each pair (f, -f)
  std::vector<std::vector<std::size_t>> mirrors_;  // the index of -f for each member (= f when self-conjugate)
  std::vector<Eigen::MatrixXd> mats_;  // bins x (B x B), P^power
  ComplexStack work_;                  // B x H x W spectrum
  Eigen::MatrixXd gemm_, gemm_out_;    // B x 2m, one bin's coefficients
};

}  // namespace

// ---------------------------------------------------------------------------------------------
Map2D fresnel_lens_heights(const SystemConfig& cfg, double design_wavelength_nm, int levels, Placement placement) {
  if (levels != 0 && (levels < 2 || levels > 65536)) reject("levels", levels, "0 (full precision) or an integer in [2, 65536]");
  Map2D lens = lens_design(cfg, design_wavelength_nm);
  if (levels == 0) return lens;
  const double dn = material_by_name(cfg.material).index(design_wavelength_nm, "design_wavelength_nm") - 1.0;
  const double h_2pi_m = design_wavelength_nm * 1e-9 / dn;
  Quantizer q;
  q.levels = levels;
  q.placement = placement;
  return quantize_heights(lens, h_2pi_m, q);
}

// ---------------------------------------------------------------------------------------------
Map2D random_binary_mask(std::size_t rows, std::size_t cols, double fill_factor, std::uint64_t seed) {
  if (rows == 0 || cols == 0) reject("rows x cols", to_str(rows) + " x " + to_str(cols), "both >= 1");
  if (!(fill_factor >= 0 && fill_factor <= 1)) reject("fill_factor", fill_factor, "within [0, 1]");
  Map2D m(rows, cols);
  for (std::size_t i = 0; i < m.data.size(); ++i) {
    const auto r = philox4x32({std::uint32_t(i), std::uint32_t(std::uint64_t(i) >> 32), 0xCA551u, 0u},
                              {std::uint32_t(seed), std::uint32_t(seed >> 32)});
    m.data[i] = uniform_open(r[0]) < fill_factor ? 1.0 : 0.0;
  }
  return m;
}

// ---------------------------------------------------------------------------------------------
CassiEncoder::CassiEncoder(Map2D mask, std::size_t bands, std::size_t shift_px_per_band, Eigen::MatrixXd response)
    : mask_(std::move(mask)), bands_(bands), shift_(shift_px_per_band), response_(std::move(response)) {
  if (mask_.rows == 0 || mask_.cols == 0 || mask_.data.size() != mask_.rows * mask_.cols)
    reject("mask", to_str(mask_.rows) + " x " + to_str(mask_.cols), "a non-empty H x W map");
  check_finite("mask", mask_.data);
  if (bands_ == 0) reject("bands", bands_, ">= 1");
  if (response_.size() == 0) response_ = Eigen::MatrixXd::Constant(1, idx(bands_), 1.0 / double(bands_));
  if (static_cast<std::size_t>(response_.cols()) != bands_)
    reject("response", to_str(response_.rows()) + " x " + to_str(response_.cols()), "C x B with B = " + to_str(bands_));
  if (!response_.allFinite() || response_.minCoeff() < 0)
    reject("response", "min " + to_str(response_.minCoeff()), "finite, non-negative entries");
}

RealStack CassiEncoder::measure(const RealStack& x) const {
  const std::size_t h = rows(), w = cols(), wo = out_cols(), nc = channels();
  if (x.planes != bands_ || x.rows != h || x.cols != w) reject("x", shape(x), "B x H x W = " + shape(bands_, h, w));
  RealStack y(nc, h, wo);
  for (std::size_t b = 0; b < bands_; ++b) {
    const std::size_t off = b * shift_;
    for (std::size_t c = 0; c < nc; ++c) {
      const double g = response_(idx(c), idx(b));
      if (g == 0) continue;
      for (std::size_t r = 0; r < h; ++r) {
        const double* xr = &x(b, r, 0);
        const double* mr = &mask_(r, 0);
        double* yr = &y(c, r, off);
        for (std::size_t col = 0; col < w; ++col) yr[col] += g * mr[col] * xr[col];
      }
    }
  }
  return y;
}

RealStack CassiEncoder::adjoint(const RealStack& y) const {
  const std::size_t h = rows(), w = cols(), wo = out_cols(), nc = channels();
  if (y.planes != nc || y.rows != h || y.cols != wo) reject("y", shape(y), "C x H x W' = " + shape(nc, h, wo));
  RealStack x(bands_, h, w);
  for (std::size_t b = 0; b < bands_; ++b) {
    const std::size_t off = b * shift_;
    for (std::size_t c = 0; c < nc; ++c) {
      const double g = response_(idx(c), idx(b));
      if (g == 0) continue;
      for (std::size_t r = 0; r < h; ++r) {
        double* xr = &x(b, r, 0);
        const double* mr = &mask_(r, 0);
        const double* yr = &y(c, r, off);
        for (std::size_t col = 0; col < w; ++col) xr[col] += g * mr[col] * yr[col];
      }
    }
  }
  return x;
}

// ---------------------------------------------------------------------------------------------
DoeEncoder::DoeEncoder(ComplexStack otf, Eigen::MatrixXd srf) : otf_(std::move(otf)), srf_(std::move(srf)) {
  if (otf_.size() == 0 || otf_.size() != otf_.planes * otf_.rows * otf_.cols)
    reject("otf", shape(otf_), "a non-empty B x H x W stack");
  for (std::size_t i = 0; i < otf_.size(); ++i)
    if (!std::isfinite(otf_.data[i].real()) || !std::isfinite(otf_.data[i].imag()))
      reject("otf[" + to_str(i) + "]", otf_.data[i], "finite values");
  if (srf_.rows() < 1 || static_cast<std::size_t>(srf_.cols()) != otf_.planes || !srf_.allFinite())
    reject("srf", to_str(srf_.rows()) + " x " + to_str(srf_.cols()), "finite C x B with B = " + to_str(otf_.planes));
}

RealStack DoeEncoder::measure(const RealStack& x) const {
  if (x.planes != bands() || x.rows != rows() || x.cols != cols())
    reject("x", shape(x), "B x H x W = " + shape(bands(), rows(), cols()));
  return wiener::simulate_measurement(x, otf_, srf_);
}

RealStack DoeEncoder::adjoint(const RealStack& y) const {
  const std::size_t nc = channels(), nb = bands(), n = rows() * cols();
  if (y.planes != nc || y.rows != rows() || y.cols != cols())
    reject("y", shape(y), "C x H x W = " + shape(nc, rows(), cols()));
  ComplexStack yf = to_complex(y);
  fftw2(yf, true);
  ComplexStack xf(nb, rows(), cols());
  for (std::size_t b = 0; b < nb; ++b) {
    cdouble* xo = xf.plane(b);
    for (std::size_t c = 0; c < nc; ++c) {
      const double g = srf_(idx(c), idx(b));
      if (g == 0) continue;
      const cdouble* yo = yf.plane(c);
      for (std::size_t f = 0; f < n; ++f) xo[f] += g * yo[f];
    }
    const cdouble* o = otf_.plane(b);
    for (std::size_t f = 0; f < n; ++f) xo[f] *= std::conj(o[f]);
  }
  fftw2(xf, false, true);
  return real_part(xf);
}

// ---------------------------------------------------------------------------------------------
MaskedEncoder::MaskedEncoder(std::shared_ptr<const Encoder> inner, Map2D mask) : inner_(std::move(inner)), mask_(std::move(mask)) {
  if (!inner_) reject("encoder", "null", "an encoder");
  if (mask_.rows != inner_->rows() || mask_.cols != inner_->out_cols())
    reject("mask", to_str(mask_.rows) + " x " + to_str(mask_.cols),
           "the sensor's H x W' = " + to_str(inner_->rows()) + " x " + to_str(inner_->out_cols()));
  for (std::size_t i = 0; i < mask_.data.size(); ++i)
    if (mask_.data[i] != 0.0 && mask_.data[i] != 1.0) reject("mask[" + to_str(i) + "]", mask_.data[i], "0 or 1");
}

void MaskedEncoder::apply_mask(RealStack& y) const {
  const std::size_t n = mask_.data.size();
  for (std::size_t c = 0; c < y.planes; ++c) {
    double* p = y.plane(c);
    for (std::size_t i = 0; i < n; ++i) p[i] *= mask_.data[i];
  }
}

RealStack MaskedEncoder::measure(const RealStack& x) const {
  RealStack y = inner_->measure(x);
  apply_mask(y);
  return y;
}

RealStack MaskedEncoder::adjoint(const RealStack& y) const {
  if (y.planes != channels() || y.rows != rows() || y.cols != out_cols())
    reject("y", shape(y), "C x H x W' = " + shape(channels(), rows(), out_cols()));
  RealStack m = y;
  apply_mask(m);
  return inner_->adjoint(m);
}

// ---------------------------------------------------------------------------------------------
RealStack apply_prior_power(const wiener::SpectralPrior& prior, const RealStack& x, double power) {
  return PriorPower(prior, power).apply(x);
}

CgResult solve_map_cg(const Encoder& encoder, const RealStack& y, const wiener::SpectralPrior& prior,
                      double noise_sigma, const CgOptions& options) {
  check_sigma(noise_sigma);
  if (!(options.tolerance >= 0) || !std::isfinite(options.tolerance)) reject("tolerance", options.tolerance, ">= 0, finite");
  const std::size_t nb = encoder.bands(), h = encoder.rows(), w = encoder.cols();
  if (prior.bands != nb || prior.rows != h || prior.cols != w)
    reject("prior", shape(prior.bands, prior.rows, prior.cols) + " (B x H x W)",
           "the encoder's B x H x W = " + shape(nb, h, w));
  if (y.planes != encoder.channels() || y.rows != h || y.cols != encoder.out_cols())
    reject("y", shape(y), "C x H x W' = " + shape(encoder.channels(), h, encoder.out_cols()));
  check_finite("y", y.data);
  PriorPower half(prior, 0.5);
  const double s2 = noise_sigma * noise_sigma;

  // gz = G z = C^{1/2} Aᵀ A C^{1/2} z + σ² z, on B x H x W stacks (tmp: workspace).
  RealStack tmp;
  auto apply_g = [&](const RealStack& z, RealStack& gz) {
    half.apply(z, tmp);
    half.apply(encoder.adjoint(encoder.measure(tmp)), gz);
    for (std::size_t i = 0; i < gz.size(); ++i) gz.data[i] += s2 * z.data[i];
  };

  RealStack b;
  half.apply(encoder.adjoint(y), b);
  const double b_norm = std::sqrt(dot(b.data, b.data));
  CgResult res;
  RealStack z(nb, h, w);
  if (b_norm == 0) {
    res.x = RealStack(nb, h, w);
    res.converged = true;
    return res;
  }
  RealStack r = b, p = b, gp;
  double rr = dot(r.data, r.data);
  const double stop = options.tolerance * b_norm;
  std::size_t it = 0;
  while (it < options.max_iterations && std::sqrt(rr) > stop) {
    apply_g(p, gp);
    const double pgp = dot(p.data, gp.data);
    if (!(pgp > 0)) break;  // G p = 0: the residual is already outside G's range (or breakdown)
    const double alpha = rr / pgp;
    for (std::size_t i = 0; i < z.size(); ++i) {
      z.data[i] += alpha * p.data[i];
      r.data[i] -= alpha * gp.data[i];
    }
    const double rr_new = dot(r.data, r.data);
    const double beta = rr_new / rr;
    rr = rr_new;
    for (std::size_t i = 0; i < p.size(); ++i) p.data[i] = r.data[i] + beta * p.data[i];
    ++it;
  }
  // The true residual (the recursion drifts from it in long runs).
  apply_g(z, gp);
  double true_rr = 0;
  for (std::size_t i = 0; i < gp.size(); ++i) true_rr += (b.data[i] - gp.data[i]) * (b.data[i] - gp.data[i]);
  res.iterations = it;
  res.residual = std::sqrt(true_rr) / b_norm;
  res.converged = res.residual <= options.tolerance;
  half.apply(z, res.x);
  return res;
}

// ---------------------------------------------------------------------------------------------
CgDecoder::CgDecoder(std::shared_ptr<const Encoder> encoder, wiener::SpectralPrior prior, double noise_sigma,
                     CgOptions options)
    : encoder_(std::move(encoder)), prior_(std::move(prior)), noise_sigma_(noise_sigma), options_(options) {
  if (!encoder_) reject("encoder", "null", "an encoder");
  check_sigma(noise_sigma_);
  prior_.validate();
  if (prior_.bands != encoder_->bands() || prior_.rows != encoder_->rows() || prior_.cols != encoder_->cols())
    reject("prior", shape(prior_.bands, prior_.rows, prior_.cols) + " (B x H x W)",
           "the encoder's B x H x W = " + shape(encoder_->bands(), encoder_->rows(), encoder_->cols()));
  if (!(options_.tolerance >= 0) || !std::isfinite(options_.tolerance)) reject("tolerance", options_.tolerance, ">= 0, finite");
}

CgResult CgDecoder::solve(const RealStack& y) const { return solve_map_cg(*encoder_, y, prior_, noise_sigma_, options_); }

RealStack CgDecoder::decode(const RealStack& y) const { return solve(y).x; }

// ---------------------------------------------------------------------------------------------
EncoderEval evaluate_encoder(const Encoder& encoder, const Decoder& decoder, const std::vector<RealStack>& cubes,
                             double sigma, std::uint64_t seed) {
  if (!(sigma >= 0) || !std::isfinite(sigma)) reject("sigma", sigma, ">= 0, finite");
  if (cubes.empty()) reject("cubes", 0, "at least one test cube");
  if (decoder.bands() != encoder.bands() || decoder.channels() != encoder.channels())
    reject("decoder", to_str(decoder.channels()) + " channels -> " + to_str(decoder.bands()) + " bands",
           "the encoder's " + to_str(encoder.channels()) + " channels, " + to_str(encoder.bands()) + " bands");
  EncoderEval e;
  const double n = double(cubes.size());
  for (std::size_t k = 0; k < cubes.size(); ++k) {
    const RealStack& x = cubes[k];
    RealStack y = encoder.measure(x);
    ref::add_noise(y, sigma, 0.0, seed, k);
    RealStack xh = decoder.decode(y);
    if (xh.planes != x.planes || xh.rows != x.rows || xh.cols != x.cols)
      reject("decoder output", shape(xh), "the cube's shape " + shape(x));
    for (double& v : xh.data) v = std::clamp(v, 0.0, 1.0);  // as `qdo eval`
    e.psnr_db += metrics::psnr(xh, x) / n;
    e.ssim += metrics::ssim(xh, x) / n;
    e.rmse += metrics::rmse(xh, x) / n;
    e.ergas += metrics::ergas(xh, x) / n;
    e.sam_rad += metrics::sam(xh, x) / n;
  }
  e.cubes = cubes.size();
  return e;
}

}  // namespace qdo
