#include "qdo/simulator.hpp"

#include "qdo/camera.hpp"

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "qdo/error.hpp"
#include "qdo/fft.hpp"

namespace qdo {

namespace {
// QDO_STAGE_TIMES=1: a queue.finish() after each stage and its time on stderr (diagnostics: the
// finishes cost a little; bench_psf's stage times come from here). Otherwise free.
class StageTimer {
 public:
  StageTimer(cl::CommandQueue& q, const char* chain) : q_(q), chain_(chain) {}
  void operator()(const char* what) {
    if (!enabled()) return;
    q_.finish();
    const auto now = std::chrono::steady_clock::now();
    std::fprintf(stderr, "%s stage %-16s %.4f s\n", chain_, what, std::chrono::duration<double>(now - t_).count());
    t_ = now;
  }

 private:
  static bool enabled() {
    static const bool on = [] {
      const char* e = std::getenv("QDO_STAGE_TIMES");
      return e && std::string(e) == "1";
    }();
    return on;
  }
  cl::CommandQueue& q_;
  const char* chain_;
  std::chrono::steady_clock::time_point t_ = std::chrono::steady_clock::now();
};
}  // namespace

Simulator::~Simulator() = default;

std::string Simulator::describe() const {
  return "simulated (2-D, N = " + to_str(cfg_.n) + (designs_ > 1 ? ", " + to_str(designs_) + " designs" : "") + ", " +
         to_string(prec_) + ")";
}

Simulator::Simulator(Runtime& rt, const SystemConfig& cfg, Precision p, std::size_t designs, bool phase_fp64)
    : rt_(rt), cfg_(cfg), prec_(p), designs_(designs), phase_fp64_(phase_fp64 && p == Precision::F32) {
  cfg_.validate();
  rt_.require(p);
  if (phase_fp64_ && !rt_.has_fp64())
    reject("phase_fp64", "true", "false on this device (" + rt_.info().name + " has no cl_khr_fp64)");
  rsz_ = real_size(p);
  geom_ = PropagationGeometry::from_config(cfg_);
  s_ = cfg_.sensor_size_px();
  if (designs_ < 1) reject("designs", designs_, ">= 1");
  nb_ = cfg_.bands * designs_;
  // Per-plane tables for designs x bands planes: the band grid repeats for every design.
  for (std::size_t d = 0; d < designs_; ++d)
    for (double w : cfg_.wavelengths_nm()) wavelengths_nm_.push_back(w);
  srf_ = sensor_response(cfg_);
  weights_ = AreaWeights::make(cfg_.n, cfg_.pitch_m, s_, cfg_.sensor_pitch_m);

  const std::size_t bands = nb_, m = geom_.m;
  const std::size_t field_bytes = bands * m * m * 2 * rsz_;
  if (field_bytes > rt_.info().max_alloc_bytes)
    reject("n", cfg_.n,
           "a size whose padded field (" + to_str(bands) + " bands x " + to_str(m) + " x " + to_str(m) + " complex " +
               to_string(p) + " = " + to_str(double(field_bytes) / 1048576.0) + " MiB) fits the device's largest allocation (" +
               to_str(double(rt_.info().max_alloc_bytes) / 1048576.0) + " MiB); reduce n, padding_px or bands");

  const std::string opts;
  k_field_ = phase_fp64_ ? rt_.kernel("field.cl", "doe_field_p64", p, "-DQDO_PHASE_FP64=1")
                        : rt_.kernel("field.cl", "doe_field", p);
  k_tf_ = rt_.kernel("propagate.cl", cfg_.propagator == Propagator::Fresnel ? "tf_separable" : "tf_table", p);
  k_tf_energy_ = rt_.kernel("propagate.cl", cfg_.propagator == Propagator::Fresnel ? "tf_energy_separable" : "tf_energy_table", p);
  k_finalize3_ = rt_.kernel("propagate.cl", "finalize_sums3", p);
  k_crop_sums_ = rt_.kernel("psf.cl", "intensity_crop_sums", p);
  k_sums_ = rt_.kernel("psf.cl", "band_sums", p);
  k_finalize_ = rt_.kernel("psf.cl", "finalize_sums", p);
  k_scale_ = rt_.kernel("psf.cl", "scale_by_sums", p);
  k_resample_ = rt_.kernel("psf.cl", "resample_area", p);
  k_sensor_ = rt_.kernel("sensor.cl", "sensor_integrate", p);
  k_expand_ = rt_.kernel("doe.cl", "expand_params", p);
  k_quantize_ = rt_.kernel("doe.cl", "quantize_blend", p);
  k_dot_ = rt_.kernel("psf.cl", "band_dot", p);
  k_norm_vjp_ = rt_.kernel("psf.cl", "normalize_vjp", p);
  k_int_vjp_ = rt_.kernel("psf.cl", "intensity_vjp", p);
  k_phase_vjp_ = rt_.kernel("field.cl", "phase_vjp", p);

  std::vector<double> kk, dd;
  for (std::size_t d = 0; d < designs_; ++d) {
    const auto k1 = wavenumber_per_band(cfg_), d1 = delta_n_per_band(cfg_);
    kk.insert(kk.end(), k1.begin(), k1.end());
    dd.insert(dd.end(), d1.begin(), d1.end());
  }
  k_ = upload_real(kk);
  dn_ = upload_real(dd);
  if (phase_fp64_) {
    k64_ = upload(kk);
    dn64_ = upload(dd);
  }
  std::vector<int> klim(bands);
  for (std::size_t b = 0; b < bands; ++b) {
    const double f = transfer_function_limit_per_m(cfg_.propagator, wavelengths_nm_[b], cfg_.sensor_distance_m, m, cfg_.pitch_m);
    klim[b] = std::isfinite(f) ? static_cast<int>(std::min(double(m), std::floor(f * double(m) * cfg_.pitch_m))) : int(m);
  }
  klim_ = upload(klim);
  klim_host_ = klim;
  tf_ = make_tf(cfg_.sensor_distance_m);
  wstart_ = upload(weights_.start);
  wts_ = upload_real(weights_.w);
  std::vector<double> srf(srf_.size());
  for (Eigen::Index c = 0; c < 3; ++c)
    for (Eigen::Index b = 0; b < srf_.cols(); ++b) srf[static_cast<std::size_t>(c * srf_.cols() + b)] = srf_(c, b);
  srf_buf_ = upload_real(srf);

  const auto& ctx = rt_.context();
  heights_ = cl::Buffer(ctx, CL_MEM_READ_WRITE, designs_ * cfg_.n * cfg_.n * rsz_);
  field_ = cl::Buffer(ctx, CL_MEM_READ_WRITE, field_bytes);
  psf_ = cl::Buffer(ctx, CL_MEM_READ_WRITE, bands * cfg_.n * cfg_.n * rsz_);
  psf_s_ = cl::Buffer(ctx, CL_MEM_READ_WRITE, bands * s_ * s_ * rsz_);
  partial_ = cl::Buffer(ctx, CL_MEM_READ_WRITE, bands * kGroupsPerBand * 3 * rsz_);
  energy3_ = cl::Buffer(ctx, CL_MEM_READ_WRITE, bands * 3 * rsz_);
  sums_crop_ = cl::Buffer(ctx, CL_MEM_READ_WRITE, bands * rsz_);
  sums_sensor_ = cl::Buffer(ctx, CL_MEM_READ_WRITE, bands * rsz_);
  // Bake what the first PSF will use now, so its cost is not charged to it.
  if (host_propagation(true))
    host_propagator();
  else
    field_plan();
}

bool Simulator::host_propagation(bool hinted) const {
  return host_fusion_ && hinted && cfg_.n < geom_.m && rt_.fft_backend() == FftBackend::FFTW;
}

HostPropagator& Simulator::host_propagator() {
  if (!host_prop_) host_prop_ = make_host_propagator(rt_, geom_.m, cfg_.n, nb_, prec_);
  return *host_prop_;
}

// The field's N x N samples are stored at window rows/cols [0, N), i.e. the centred window of
// PropagationGeometry circularly shifted by -offset. Propagation is a circular convolution, so it
// commutes with that shift: the propagated field's crop is again [0, N). The zero rows and
// columns [N, M) then form one block per axis, which the FFT's zero-padding hint prunes (FFTW
// skips the zero rows forward and the unread columns inverse, VkFFT skips both).
FftPlan& Simulator::field_plan(bool hinted) {
  const std::size_t m = geom_.m, n = cfg_.n;
  if (!hinted || n >= m) return rt_.fft(m, m, nb_, prec_);
  return rt_.fft(m, m, nb_, prec_, rt_.fft_backend(), FftZeroPad{n, m, n, m});
}

ComplexStack Simulator::centred(const cl::Buffer& field) const {
  const std::size_t m = geom_.m, o = geom_.offset;
  const std::vector<cdouble> dev = download_complex(field, nb_ * m * m);
  ComplexStack out(nb_, m, m);
  for (std::size_t b = 0; b < nb_; ++b)
    for (std::size_t y = 0; y < m; ++y)
      for (std::size_t x = 0; x < m; ++x) out(b, y, x) = dev[(b * m + (y + m - o) % m) * m + (x + m - o) % m];
  return out;
}

template <typename T>
cl::Buffer Simulator::upload(const std::vector<T>& host, cl_mem_flags flags) const {
  std::vector<T> copy(host.empty() ? std::vector<T>(1) : host);
  return cl::Buffer(rt_.context(), flags | CL_MEM_COPY_HOST_PTR, copy.size() * sizeof(T), copy.data());
}

cl::Buffer Simulator::upload_real(const std::vector<double>& host, cl_mem_flags flags) const {
  if (prec_ == Precision::F64) return upload(host, flags);
  return upload(std::vector<float>(host.begin(), host.end()), flags);
}

cl::Buffer Simulator::upload_complex(const std::vector<cdouble>& host, cl_mem_flags flags) const {
  std::vector<double> flat(host.size() * 2);
  for (std::size_t i = 0; i < host.size(); ++i) {
    flat[2 * i] = host[i].real();
    flat[2 * i + 1] = host[i].imag();
  }
  return upload_real(flat, flags);
}

// Writes host reals into a scratch buffer kept across calls (allocated on first use with the
// size of `host`, which is fixed per call site), in the device precision.
cl::Buffer& Simulator::write_scratch(cl::Buffer& buf, const std::vector<double>& host) {
  if (!buf()) buf = cl::Buffer(rt_.context(), CL_MEM_READ_WRITE, host.size() * rsz_);
  rt_.write_reals(buf, host.data(), host.size(), prec_);
  return buf;
}

std::vector<double> Simulator::download_real(const cl::Buffer& b, std::size_t count) const {
  std::vector<double> out(count);
  rt_.read_reals(b, out.data(), count, prec_);
  return out;
}

std::vector<cdouble> Simulator::download_complex(const cl::Buffer& b, std::size_t count) const {
  const auto flat = download_real(b, count * 2);
  std::vector<cdouble> out(count);
  for (std::size_t i = 0; i < count; ++i) out[i] = cdouble(flat[2 * i], flat[2 * i + 1]);
  return out;
}

// Transfer function over z_m: Fresnel as the separable bands x M table t[b][k] =
// exp(-iπ λ_b z f_k²); angular spectrum as the full bands x M x M table (zero beyond the
// band limit). Both computed in double on the host, then converted to the device precision.
cl::Buffer Simulator::make_tf(double z_m) const {
  const std::size_t m = geom_.m, bands = nb_;
  std::vector<cdouble> t;
  if (cfg_.propagator == Propagator::Fresnel) {
    t.resize(bands * m);
    for (std::size_t b = 0; b < bands; ++b)
      for (std::size_t k = 0; k < m; ++k) {
        const double f = fft_frequency(k, m, cfg_.pitch_m);
        t[b * m + k] = std::polar(1.0, -M_PI * wavelengths_nm_[b] * 1e-9 * z_m * f * f);
      }
  } else {
    t.assign(bands * m * m, cdouble(0, 0));
    for (std::size_t b = 0; b < bands; ++b) {
      const double lambda = wavelengths_nm_[b] * 1e-9, inv_l = 1.0 / lambda;
      const double flim = transfer_function_limit_per_m(Propagator::AngularSpectrum, wavelengths_nm_[b], z_m, m, cfg_.pitch_m);
      for (std::size_t ky = 0; ky < m; ++ky) {
        const double fy = fft_frequency(ky, m, cfg_.pitch_m);
        for (std::size_t kx = 0; kx < m; ++kx) {
          const double fx = fft_frequency(kx, m, cfg_.pitch_m);
          const double f2 = fx * fx + fy * fy;
          if (std::fabs(fx) > flim || std::fabs(fy) > flim || f2 * lambda * lambda >= 1.0) continue;
          t[(b * m + ky) * m + kx] = std::polar(1.0, -2.0 * M_PI * z_m * f2 / (std::sqrt(inv_l * inv_l - f2) + inv_l));
        }
      }
    }
  }
  return upload_complex(t);
}

void Simulator::set_heights(const Map2D& height_m) { set_heights_batch({height_m}); }

void Simulator::set_heights_batch(const std::vector<Map2D>& maps) {
  if (maps.size() != designs_) reject("height maps", maps.size(), "one per design of this simulator (" + to_str(designs_) + ")");
  std::vector<double> all;
  all.reserve(designs_ * cfg_.n * cfg_.n);
  for (const Map2D& height_m : maps) {
  if (height_m.rows != cfg_.n || height_m.cols != cfg_.n)
    reject("height_m", to_str(height_m.rows) + " x " + to_str(height_m.cols), "a square N x N map with N = " + to_str(cfg_.n));
  const double hmax = cfg_.h_max_m();
  for (std::size_t i = 0; i < height_m.data.size(); ++i) {
    const double h = height_m.data[i];
    if (!std::isfinite(h) || h < 0 || h > 2 * hmax)
      reject("height_m[" + to_str(i / cfg_.n) + "][" + to_str(i % cfg_.n) + "]", h,
             "finite heights in [0, 2 h_max] = [0, " + to_str(2 * hmax) + "] m");
  }
  all.insert(all.end(), height_m.data.begin(), height_m.data.end());
  }
  if (prec_ == Precision::F64) {
    rt_.queue().enqueueWriteBuffer(heights_, CL_TRUE, 0, all.size() * 8, all.data());
  } else {
    const std::vector<float> f(all.begin(), all.end());
    rt_.queue().enqueueWriteBuffer(heights_, CL_TRUE, 0, f.size() * 4, f.data());
  }
  heights_set_ = true;
  psf_valid_ = false;
}

void Simulator::set_design(Parameterization kind, const std::vector<double>& params, const Quantizer* q, double alpha) {
  require_single_design("set_design");
  const std::size_t n = cfg_.n;
  if (params.size() != qdo::parameter_count(kind, n))
    reject("params.size()", params.size(), "exactly " + to_str(qdo::parameter_count(kind, n)) + " for this parameterization and N");
  for (std::size_t i = 0; i < params.size(); ++i)
    if (!std::isfinite(params[i])) reject("params[" + to_str(i) + "]", params[i], "finite heights in metres");
  if (q) {
    q->validate();
    if (!(alpha >= 0 && alpha <= 1)) reject("alpha", alpha, "within [0, 1]");
  }
  const double hmax = cfg_.h_max_m();
  const cl::Buffer pbuf = upload_real(params);
  const int kind_code = kind == Parameterization::Full2D ? 0 : kind == Parameterization::Radial ? 1 : 2;
  rt_.launch_1d(k_expand_, n * n, prec_, pbuf, heights_, int(n), kind_code, Real{hmax});
  if (q) {
    std::vector<double> table;
    for (int l = 0; l < q->levels; ++l) table.push_back(q->level_value(l));
    const cl::Buffer obuf = upload_real(table);
    rt_.launch_1d(k_quantize_, n * n, prec_, heights_, int(n * n), Real{hmax}, int(q->levels),
                  int(q->placement == Placement::Inclusive ? 0 : 1), obuf, Real{alpha});
  }
  rt_.queue().finish();  // pbuf and obuf are released when this function returns
  heights_set_ = true;
  psf_valid_ = false;
}

Map2D Simulator::heights() const {
  Map2D h(cfg_.n, cfg_.n);
  h.data = download_real(heights_, h.data.size());
  return h;
}

template <typename A3, typename A4>
void Simulator::set_phase_args(cl::Kernel& k, Precision p, const cl::Buffer& k_tab, const cl::Buffer& dn_tab,
                               const A3& a3, const A4& a4, std::size_t planes) {
  const double r_ap2_px = cfg_.aperture_inside_px2();  // as ref::doe_field: half an integer, exact in float
  const double d = cfg_.scene_at_infinity ? -1.0 : cfg_.scene_distance_m;
  set_args(k, p, heights_, k_tab, dn_tab, a3, a4, int(cfg_.n), int(geom_.m), int(kFieldOffset), int(planes ? planes : nb_),
           Real{cfg_.pitch_m}, Real{d}, Real{r_ap2_px});
}

void Simulator::run_doe_field(bool crop_rows) {
  if (!heights_set_) throw Error("Simulator: set_heights() must be called before computing fields or PSFs");
  // Argument 4: planes per design (plane b uses height map b / bands). doe_field_p64 takes the
  // tables and scalars in double.
  if (phase_fp64_)
    set_phase_args(k_field_, Precision::F64, k64_, dn64_, field_, int(cfg_.bands));
  else
    set_phase_args(k_field_, prec_, k_, dn_, field_, int(cfg_.bands));
  // 3-D NDRange (columns, rows, designs), work-group (kLocalSize, 1, 1); crop_rows: rows [0, N)
  // and the columns up to N rounded to the work-group size (the rest of the window is not read).
  const std::size_t m = geom_.m, n = cfg_.n, rows = crop_rows ? n : m;
  const std::size_t cols = crop_rows ? std::min(Runtime::global_for(n), Runtime::global_for(m)) : Runtime::global_for(m);
  rt_.queue().enqueueNDRangeKernel(k_field_, cl::NullRange, cl::NDRange(cols, rows, designs_),
                                   cl::NDRange(Runtime::kLocalSize, 1, 1));
}

// The transfer function over z_m: the cached +z and -z tables, else a new one.
cl::Buffer Simulator::tf_for(double z_m) {
  if (z_m == cfg_.sensor_distance_m) return tf_;
  if (z_m == -cfg_.sensor_distance_m) {
    if (!tf_back_()) tf_back_ = make_tf(z_m);
    return tf_back_;
  }
  return make_tf(z_m);
}

bool Simulator::run_propagation(cl::Buffer& field, double z_m, bool record_sampling, bool hinted, cl::Buffer* intensity,
                                cl::Buffer* crop_sums) {
  const std::size_t m = geom_.m, bands = nb_;
  cl::Buffer tf = tf_for(z_m);
  if (host_propagation(hinted)) {
    HostPropagator::Outputs out;
    if (record_sampling) {
      out.energy3 = &energy3_;
      out.klim = klim_host_.data();
    }
    out.intensity = intensity;
    out.crop_sums = intensity ? crop_sums : nullptr;
    host_propagator().run(field, HostPropagator::Tf{&tf, cfg_.propagator == Propagator::Fresnel}, out);
    if (record_sampling) {
      sampling_z_m_ = z_m;
      sampling_fresh_ = false;
    }
    return intensity != nullptr;
  }
  FftPlan& fft = field_plan(hinted);
  fft.forward(field);
  if (record_sampling) {
    // One pass: TF multiplication plus the sampling-check and energy reductions; the sums
    // stay on the device (energy3_) until sampling() asks for them.
    set_args(k_tf_energy_, prec_, field, tf, klim_, partial_, int(m), int(kGroupsPerBand),
             cl::Local(3 * Runtime::kLocalSize * rsz_));
    rt_.queue().enqueueNDRangeKernel(k_tf_energy_, cl::NullRange, cl::NDRange(kGroupsPerBand * Runtime::kLocalSize, bands),
                                     cl::NDRange(Runtime::kLocalSize, 1));
    rt_.launch_1d(k_finalize3_, bands, prec_, partial_, energy3_, int(kGroupsPerBand), int(bands));
    sampling_z_m_ = z_m;
    sampling_fresh_ = false;
  } else {
    if (cfg_.propagator == Propagator::Fresnel) {
      set_args(k_tf_, prec_, field, tf, int(m), int(bands));
      rt_.queue().enqueueNDRangeKernel(k_tf_, cl::NullRange, cl::NDRange(Runtime::global_for(m), m, bands),
                                       cl::NDRange(Runtime::kLocalSize, 1, 1));
    } else {
      rt_.launch_1d(k_tf_, bands * m * m, prec_, field, tf, int(bands * m * m));
    }
  }
  fft.inverse(field);
  return false;
}

const SamplingReport& Simulator::sampling() const {
  if (sampling_fresh_) return sampling_;
  // The per-band energies of the last compute_psf(), read back once (bands x 3 and bands).
  const std::size_t m = geom_.m, bands = nb_;
  const auto e3 = download_real(energy3_, bands * 3);
  // The crop sums exist only once compute_psf() has run past propagation (not for the debug
  // accessors, which stop after it).
  const auto crop = psf_valid_ ? download_real(sums_crop_, bands) : std::vector<double>(bands, 0.0);
  const double z_m = sampling_z_m_;
  sampling_.bands.assign(bands, BandSampling{});
  for (std::size_t b = 0; b < bands; ++b) {
    const double tot = e3[3 * b], beyond = e3[3 * b + 1], after = e3[3 * b + 2] / double(m * m);
    BandSampling& bs = sampling_.bands[b];
    bs.wavelength_nm = wavelengths_nm_[b];
    bs.f_limit_per_m = transfer_function_limit_per_m(cfg_.propagator, wavelengths_nm_[b], z_m, m, cfg_.pitch_m);
    bs.f_nyquist_per_m = 0.5 / cfg_.pitch_m;
    bs.undersampled = bs.f_limit_per_m < bs.f_nyquist_per_m;
    bs.aliased_energy_fraction = tot > 0 ? beyond / tot : 0.0;
    bs.energy_outside_window = psf_valid_ && after > 0 ? std::max(0.0, 1.0 - crop[b] / after) : 0.0;
  }
  check_source_sampling(cfg_, sampling_.bands);
  sampling_fresh_ = true;
  return sampling_;
}

void Simulator::band_reduce(cl::Kernel& k, const cl::Buffer& x, std::size_t len, cl::Buffer& sums) {
  const std::size_t bands = nb_;
  set_args(k, prec_, x, int(len), partial_, int(kGroupsPerBand), cl::Local(Runtime::kLocalSize * rsz_));
  rt_.queue().enqueueNDRangeKernel(k, cl::NullRange, cl::NDRange(kGroupsPerBand * Runtime::kLocalSize, bands),
                                   cl::NDRange(Runtime::kLocalSize, 1));
  rt_.launch_1d(k_finalize_, bands, prec_, partial_, sums, int(kGroupsPerBand), int(bands));
}

// Per-band sums of x (bands x len) into `sums`, then x /= sums (on the device).
void Simulator::normalize_bands(cl::Buffer& x, std::size_t len, cl::Buffer& sums) {
  band_reduce(k_sums_, x, len, sums);
  rt_.launch_1d(k_scale_, nb_ * len, prec_, x, sums, int(len), int(nb_));
}

// Area resampling bands x n_in x n_in -> bands x n_out x n_out with the given weight table
// (AreaWeights, or its transpose for the adjoint).
void Simulator::resample(const cl::Buffer& in, cl::Buffer& out, const cl::Buffer& start, const cl::Buffer& w, std::size_t n_in,
                         std::size_t n_out, std::size_t taps) {
  rt_.launch_1d(k_resample_, nb_ * n_out * n_out, prec_, in, out, start, w, int(n_in), int(n_out), int(taps), int(nb_));
}

void Simulator::compute_psf() {
  const std::size_t n = cfg_.n, m = geom_.m, bands = nb_;
  StageTimer stage(rt_.queue(), "compute_psf");
  const bool host = host_propagation(true);
  const bool streamed = host && !keep_field_ && designs_ == 1;
  // Intensity of the N x N crop and its per-band sums (fused into the host propagation, else one
  // kernel pass). The native stack stays unnormalised (normalising it before the linear area
  // resampling would not change the normalised sensor stack); psf_native() and the adjoints
  // normalise it when they need it.
  if (streamed) {
    run_streamed_propagation();  // field, propagation and crop a chunk of planes at a time
    stage("field+propagation+crop (streamed)");
  } else {
    run_doe_field(host);
    stage("field");
    if (run_propagation(field_, cfg_.sensor_distance_m, true, true, &psf_, &sums_crop_)) {
      stage("propagation+crop");
    } else {
      stage("propagation");
      set_args(k_crop_sums_, prec_, field_, psf_, int(n), int(m), int(kFieldOffset), partial_, int(kGroupsPerBand),
               cl::Local(Runtime::kLocalSize * rsz_));
      rt_.queue().enqueueNDRangeKernel(k_crop_sums_, cl::NullRange, cl::NDRange(kGroupsPerBand * Runtime::kLocalSize, bands),
                                       cl::NDRange(Runtime::kLocalSize, 1));
      rt_.launch_1d(k_finalize_, bands, prec_, partial_, sums_crop_, int(kGroupsPerBand), int(bands));
      stage("crop");
    }
  }
  native_normalized_ = false;
  resample(psf_, psf_s_, wstart_, wts_, n, s_, weights_.taps);
  stage("resample");
  normalize_bands(psf_s_, s_ * s_, sums_sensor_);
  stage("normalise");
  psf_valid_ = true;
  field_valid_ = !streamed;
  field_streamed_ = streamed;
  ++psf_generation_;
  if (cfg_.strict_sampling) {
    sampling();
    sampling_.enforce();
  }
}

void Simulator::run_streamed_propagation() {
  if (!heights_set_) throw Error("Simulator: set_heights() must be called before computing fields or PSFs");
  HostPropagator& hp = host_propagator();
  const std::size_t m = geom_.m, n = cfg_.n, bands = nb_, threads = std::max<std::size_t>(1, hp.threads());
  // Planes per chunk: a multiple of the threads, at least kMinChunk: each chunk costs a field
  // launch and a hand-over between PoCL's threads and the propagation's (BENCHMARKS "CPU speed":
  // at the paper preset on 2 cores, 8 planes beat 2 and 4 and one chunk of all 31). The
  // environment variable QDO_STREAM_BANDS (an integer >= 1) overrides it, for such measurements.
  constexpr std::size_t kMinChunk = 8;
  std::size_t chunk = threads * ((kMinChunk + threads - 1) / threads);
  if (const char* e = std::getenv("QDO_STREAM_BANDS"); e && *e) {
    char* end = nullptr;
    const long v = std::strtol(e, &end, 10);
    if (*end != '\0' || v < 1) reject("QDO_STREAM_BANDS", e, "an integer >= 1 (bands per streamed chunk)");
    chunk = std::size_t(v);
  }
  chunk = std::min(bands, chunk);
  const std::size_t chunks = (bands + chunk - 1) / chunk;
  const std::size_t ring_bytes = chunk * m * m * 2 * rsz_;
  if (!field_ring_() || field_ring_.getInfo<CL_MEM_SIZE>() < ring_bytes)
    field_ring_ = cl::Buffer(rt_.context(), CL_MEM_READ_WRITE, ring_bytes);
  if (chunk_k_.size() != chunks || chunk_planes_ != chunk) {
    chunk_planes_ = chunk;
    // Each chunk's k and dn as their own small tables, so doe_field writes just those planes
    // (a sub-buffer would need an aligned origin).
    const auto kk = wavenumber_per_band(cfg_), dd = delta_n_per_band(cfg_);
    chunk_k_.clear();
    chunk_dn_.clear();
    for (std::size_t b0 = 0; b0 < bands; b0 += chunk) {
      const std::size_t c = std::min(chunk, bands - b0);
      const std::vector<double> k1(kk.begin() + std::ptrdiff_t(b0), kk.begin() + std::ptrdiff_t(b0 + c));
      const std::vector<double> d1(dd.begin() + std::ptrdiff_t(b0), dd.begin() + std::ptrdiff_t(b0 + c));
      chunk_k_.push_back(phase_fp64_ ? upload(k1) : upload_real(k1));
      chunk_dn_.push_back(phase_fp64_ ? upload(d1) : upload_real(d1));
    }
  }
  const Precision pp = phase_fp64_ ? Precision::F64 : prec_;  // doe_field_p64 takes its scalars in double
  const std::size_t cols = std::min(Runtime::global_for(n), Runtime::global_for(m));
  const cl::Buffer tf = tf_for(cfg_.sensor_distance_m);
  HostPropagator::Outputs out;
  out.energy3 = &energy3_;
  out.klim = klim_host_.data();
  out.intensity = &psf_;
  out.crop_sums = &sums_crop_;
  for (std::size_t i = 0; i < chunks; ++i) {
    const std::size_t b0 = i * chunk, c = std::min(chunk, bands - b0);
    // doe_field over c planes of one design (bands_per_design = bands = c), rows [0, N) only, as
    // run_doe_field(true).
    set_phase_args(k_field_, pp, chunk_k_[i], chunk_dn_[i], field_ring_, int(c), c);
    rt_.queue().enqueueNDRangeKernel(k_field_, cl::NullRange, cl::NDRange(cols, n, 1), cl::NDRange(Runtime::kLocalSize, 1, 1));
    hp.run_planes(field_ring_, b0, c, HostPropagator::Tf{&tf, cfg_.propagator == Propagator::Fresnel}, out);
  }
  sampling_z_m_ = cfg_.sensor_distance_m;
  sampling_fresh_ = false;
}

void Simulator::ensure_native_normalized() {
  if (native_normalized_) return;
  rt_.launch_1d(k_scale_, nb_ * cfg_.n * cfg_.n, prec_, psf_, sums_crop_, int(cfg_.n * cfg_.n), int(nb_));
  native_normalized_ = true;
}

RealStack Simulator::psf_native() const {
  if (!psf_valid_) throw Error("Simulator: compute_psf() has not run for the current heights");
  RealStack out;  // filled straight from the device (no zeroed allocation first)
  out.planes = nb_;
  out.rows = out.cols = cfg_.n;
  out.data = download_real(psf_, nb_ * cfg_.n * cfg_.n);
  if (!native_normalized_) {
    // Normalise on the host (in double) with the device's per-band sums, as scale_by_sums.
    const auto sums = download_real(sums_crop_, nb_);
    const std::size_t nn = cfg_.n * cfg_.n;
    for (std::size_t b = 0; b < nb_; ++b)
      if (sums[b] > 0)
        for (std::size_t e = 0; e < nn; ++e) out.data[b * nn + e] /= sums[b];
  }
  return out;
}

RealStack Simulator::psf_sensor() const {
  if (!psf_valid_) throw Error("Simulator: compute_psf() has not run for the current heights");
  RealStack out;  // filled straight from the device (no zeroed allocation first)
  out.planes = nb_;
  out.rows = out.cols = s_;
  out.data = download_real(psf_s_, nb_ * s_ * s_);
  return out;
}

void Simulator::require_adjoint_state() const {
  if (psf_valid_ && !field_valid_ && field_streamed_)
    throw Error("Simulator: the adjoints need the propagated field, which the last compute_psf() did not keep "
                "(set_keep_field(false)); call set_keep_field(true) and compute_psf() again");
  if (!psf_valid_ || !field_valid_) throw Error("Simulator: compute_psf() must run before an adjoint");
}

void Simulator::require_single_design(const char* what) const {
  if (designs_ != 1)
    throw Error(std::string("Simulator: ") + what + " needs a simulator of one design (this one batches " + to_str(designs_) +
                "); construct one with designs = 1");
}

void Simulator::normalize_vjp(cl::Buffer& g, const cl::Buffer& y, std::size_t len, const cl::Buffer& sums) {
  const std::size_t bands = cfg_.bands;
  set_args(k_dot_, prec_, g, y, int(len), partial_, int(kGroupsPerBand), cl::Local(Runtime::kLocalSize * rsz_));
  rt_.queue().enqueueNDRangeKernel(k_dot_, cl::NullRange, cl::NDRange(kGroupsPerBand * Runtime::kLocalSize, bands),
                                   cl::NDRange(Runtime::kLocalSize, 1));
  rt_.launch_1d(k_finalize_, bands, prec_, partial_, dots_, int(kGroupsPerBand), int(bands));
  rt_.launch_1d(k_norm_vjp_, bands * len, prec_, g, dots_, sums, int(len), int(bands));
}

Map2D Simulator::backward_from_native(const cl::Buffer& g_native) {
  const std::size_t n = cfg_.n, m = geom_.m, bands = cfg_.bands;
  StageTimer stage(rt_.queue(), "adjoint");
  if (!gfield_()) gfield_ = cl::Buffer(rt_.context(), CL_MEM_READ_WRITE, bands * m * m * 2 * rsz_);
  if (!dh_()) dh_ = cl::Buffer(rt_.context(), CL_MEM_READ_WRITE, n * n * rsz_);
  set_args(k_int_vjp_, prec_, g_native, field_, gfield_, int(n), int(m), int(kFieldOffset), int(bands));
  // The host propagation reads only [0, N)^2: the kernel then covers rows [0, N) and the columns
  // up to N rounded to the work-group size.
  const bool host = host_propagation(true);
  const std::size_t rows = host ? n : m, cols = host ? std::min(Runtime::global_for(n), Runtime::global_for(m)) : Runtime::global_for(m);
  rt_.queue().enqueueNDRangeKernel(k_int_vjp_, cl::NullRange, cl::NDRange(cols, rows, bands),
                                   cl::NDRange(Runtime::kLocalSize, 1, 1));
  stage("intensity_vjp");
  run_propagation(gfield_, -cfg_.sensor_distance_m, false);  // adjoint of +z propagation
  stage("propagation");
  return phase_vjp_gradient(stage);
}

// dL/dH from the back-propagated field gradient in gfield_ ([0, N)^2), read back to the host.
template <typename Stage>
Map2D Simulator::phase_vjp_gradient(Stage& stage) {
  const std::size_t n = cfg_.n;
  set_phase_args(k_phase_vjp_, prec_, k_, dn_, gfield_, dh_);
  rt_.enqueue_1d(k_phase_vjp_, n * n);
  stage("phase_vjp");
  Map2D out(n, n);
  out.data = download_real(dh_, n * n);
  stage("read-back");
  return out;
}

Map2D Simulator::psf_native_vjp(const RealStack& g_psf) {
  require_single_design("psf_native_vjp");
  require_adjoint_state();
  if (g_psf.planes != cfg_.bands || g_psf.rows != cfg_.n || g_psf.cols != cfg_.n)
    reject("g_psf", to_str(g_psf.planes) + " x " + to_str(g_psf.rows) + " x " + to_str(g_psf.cols),
           "bands x N x N = " + to_str(cfg_.bands) + " x " + to_str(cfg_.n) + " x " + to_str(cfg_.n));
  if (!dots_()) dots_ = cl::Buffer(rt_.context(), CL_MEM_READ_WRITE, cfg_.bands * rsz_);
  cl::Buffer& g = write_scratch(g_native_, g_psf.data);
  ensure_native_normalized();
  normalize_vjp(g, psf_, cfg_.n * cfg_.n, sums_crop_);
  return backward_from_native(g);
}

Map2D Simulator::psf_sensor_vjp(const RealStack& g_psf_sensor) {
  require_single_design("psf_sensor_vjp");
  require_adjoint_state();
  if (g_psf_sensor.planes != cfg_.bands || g_psf_sensor.rows != s_ || g_psf_sensor.cols != s_)
    reject("g_psf_sensor", to_str(g_psf_sensor.planes) + " x " + to_str(g_psf_sensor.rows) + " x " + to_str(g_psf_sensor.cols),
           "bands x S x S = " + to_str(cfg_.bands) + " x " + to_str(s_) + " x " + to_str(s_));
  return sensor_vjp_in_scratch(write_scratch(g_sensor_, g_psf_sensor.data));
}

Map2D Simulator::psf_sensor_vjp(const cl::Buffer& g_psf_sensor) {
  require_single_design("psf_sensor_vjp");
  require_adjoint_state();
  const std::size_t bytes = cfg_.bands * s_ * s_ * rsz_;
  if (g_psf_sensor.getInfo<CL_MEM_SIZE>() < bytes)
    reject("g_psf_sensor buffer", to_str(g_psf_sensor.getInfo<CL_MEM_SIZE>()) + " bytes",
           ">= " + to_str(bytes) + " (bands x S x S reals of the simulator's precision)");
  // The host path only reads its input; the kernel path works in place on it: a copy into the
  // scratch buffer first (device to device).
  if (host_propagation(true)) {
    cl::Buffer read_only = g_psf_sensor;  // a second handle to the caller's buffer, not a copy
    return sensor_vjp_in_scratch(read_only);
  }
  if (!g_sensor_()) g_sensor_ = cl::Buffer(rt_.context(), CL_MEM_READ_WRITE, bytes);
  rt_.queue().enqueueCopyBuffer(g_psf_sensor, g_sensor_, 0, 0, bytes);
  return sensor_vjp_in_scratch(g_sensor_);
}

// g_sensor (bands x S x S, the scratch g_sensor_) is overwritten by the kernel path (read only by the host one).
Map2D Simulator::sensor_vjp_in_scratch(cl::Buffer& g_sensor) {
  const std::size_t n = cfg_.n, bands = cfg_.bands;
  if (!dots_()) dots_ = cl::Buffer(rt_.context(), CL_MEM_READ_WRITE, bands * rsz_);
  if (!wts_t_()) {
    weights_t_ = weights_.transposed();
    wstart_t_ = upload(weights_t_.start);
    wts_t_ = upload_real(weights_t_.w);
  }
  StageTimer stage(rt_.queue(), "adjoint");
  if (host_propagation(true)) {
    // Fused on the host: normalisation vjp, transposed resampling, |U|² vjp and the -z
    // propagation in one pass (HostPropagator::IntensityAdjointInput), then the phase vjp kernel.
    const std::size_t m = geom_.m;
    if (!gfield_()) gfield_ = cl::Buffer(rt_.context(), CL_MEM_READ_WRITE, bands * m * m * 2 * rsz_);
    if (!dh_()) dh_ = cl::Buffer(rt_.context(), CL_MEM_READ_WRITE, n * n * rsz_);
    HostPropagator::IntensityAdjointInput in;
    in.g_sensor = &g_sensor;
    in.u = &field_;
    in.s = s_;
    in.taps = weights_t_.taps;
    in.start = weights_t_.start.data();
    in.w = weights_t_.w.data();
    in.y_sensor = &psf_s_;
    in.sensor_sums = &sums_sensor_;
    const cl::Buffer tf = tf_for(-cfg_.sensor_distance_m);
    host_propagator().run(gfield_, HostPropagator::Tf{&tf, cfg_.propagator == Propagator::Fresnel}, HostPropagator::Outputs{},
                          &in);
    stage("normalize+resample+intensity+propagation vjp");
    return phase_vjp_gradient(stage);
  }
  normalize_vjp(g_sensor, psf_s_, s_ * s_, sums_sensor_);
  stage("normalize_vjp");
  // Transposed area resampling: the same kernel with the transposed weights (S -> N).
  if (!g_native_()) g_native_ = cl::Buffer(rt_.context(), CL_MEM_READ_WRITE, bands * n * n * rsz_);
  cl::Buffer& g = g_native_;
  // The forward resampled the unnormalised intensity (the native normalisation cancels in
  // the sensor normalisation), so the transposed resampling already gives dL/d|U|².
  resample(g_sensor, g, wstart_t_, wts_t_, s_, n, weights_t_.taps);
  stage("resample_vjp");
  return backward_from_native(g);
}

Camera& Simulator::camera(const char* what) {
  require_single_design(what);
  if (!psf_valid_) throw Error(std::string("Simulator: compute_psf() must run before ") + what);
  if (!camera_) camera_ = std::make_unique<Camera>(*this);
  return *camera_;
}

RealStack Simulator::sensor_images_vjp(const std::vector<RealStack>& g_rgb) {
  return camera("sensor_images_vjp").vjp(g_rgb, false).psf;
}

ComplexStack Simulator::debug_field_after_doe() {
  field_valid_ = field_streamed_ = false;  // field_ now holds the field before propagation: the adjoints need it after
  run_doe_field();
  return centred(field_);
}

ComplexStack Simulator::debug_field_after_propagation() {
  run_doe_field();
  run_propagation(field_, cfg_.sensor_distance_m, true, false);  // unpruned: the whole window is returned
  field_streamed_ = false;
  field_valid_ = true;  // the same propagated field compute_psf() leaves for the adjoints
  return centred(field_);
}

ComplexStack Simulator::propagate_field(const ComplexStack& field, double z_m) {
  if (field.planes != nb_ || field.rows != geom_.m || field.cols != geom_.m)
    reject("field", to_str(field.planes) + " x " + to_str(field.rows) + " x " + to_str(field.cols),
           "bands x M x M = " + to_str(nb_) + " x " + to_str(geom_.m) + " x " + to_str(geom_.m));
  cl::Buffer rw = upload_complex(field.data, CL_MEM_READ_WRITE);
  run_propagation(rw, z_m, false, false);  // any field (no zero block), in the centred layout
  ComplexStack out(field.planes, field.rows, field.cols);
  out.data = download_complex(rw, out.size());
  return out;
}

std::vector<RealStack> Simulator::convolve_batch(const std::vector<RealStack>& cubes) {
  return camera("convolving").blur(cubes);
}

RealStack Simulator::convolve(const RealStack& cube) { return convolve_batch({cube}).front(); }

void Simulator::run_sensor(const cl::Buffer& in, cl::Buffer& out, std::size_t hw, std::size_t scenes) {
  rt_.launch_1d(k_sensor_, scenes * 3 * hw, prec_, in, srf_buf_, out, int(hw), int(cfg_.bands),
                Real{cfg_.read_noise_sigma}, Real{cfg_.full_well_photons}, cl_uint(cfg_.noise_seed & 0xffffffffull),
                cl_uint(cfg_.noise_seed >> 32), int(scenes));
}

std::vector<RealStack> Simulator::sensor_images(const std::vector<RealStack>& cubes) {
  SkipOptions exact;
  exact.exact = true;
  return camera("sensor_images").images(cubes, exact);
}

RealStack Simulator::sensor_image(const RealStack& cube) { return sensor_images({cube}).front(); }

RealStack Simulator::integrate(const RealStack& cube) {
  require_single_design("integrate");
  if (cube.planes != cfg_.bands)
    reject("cube bands", cube.planes, "the configuration's band count (" + to_str(cfg_.bands) + ")");
  const std::size_t hw = cube.plane_size();
  const cl::Buffer in = upload_real(cube.data);
  cl::Buffer out_buf(rt_.context(), CL_MEM_READ_WRITE, 3 * hw * rsz_);
  run_sensor(in, out_buf, hw, 1);
  RealStack out(3, cube.rows, cube.cols);
  out.data = download_real(out_buf, out.size());
  return out;
}

}  // namespace qdo
