// PropagationStage (include/qdo/physics/propagate.hpp): the launcher of kernels/propagate.cl, the FFT plans
// around it and the fused host propagation (HostPropagator, src/runtime/propagate_fftw.cpp).
#include "qdo/physics/propagate.hpp"

#include <algorithm>
#include <cmath>
#include <cstdlib>

#include "physics/device_buffers.hpp"
#include "qdo/runtime/error.hpp"

namespace qdo {

PropagationStage::~PropagationStage() = default;

PropagationStage::PropagationStage(Runtime& rt, const SystemConfig& cfg, Precision p, std::size_t designs)
    : rt_(rt), cfg_(cfg), prec_(p), nb_(cfg.bands * designs * cfg.point_count()), rsz_(real_size(p)),
      geom_(PropagationGeometry::from_config(cfg)) {
  if (designs < 1) reject("designs", designs, ">= 1");
  for (std::size_t d = 0; d < designs * cfg_.point_count(); ++d)
    for (double w : cfg_.wavelengths_nm()) wavelengths_nm_.push_back(w);
  const bool fresnel = cfg_.propagator == Propagator::Fresnel;
  k_tf_ = rt_.kernel("propagate.cl", fresnel ? "tf_separable" : "tf_table", p);
  k_tf_energy_ = rt_.kernel("propagate.cl", fresnel ? "tf_energy_separable" : "tf_energy_table", p);
  k_finalize3_ = rt_.kernel("propagate.cl", "finalize_sums3", p);
  const std::size_t m = geom_.m;
  std::vector<int> klim(nb_);
  for (std::size_t b = 0; b < nb_; ++b) {
    const double f = transfer_function_limit_per_m(cfg_.propagator, wavelengths_nm_[b], cfg_.sensor_distance_m, m, cfg_.pitch_m);
    klim[b] = std::isfinite(f) ? static_cast<int>(std::min(double(m), std::floor(f * double(m) * cfg_.pitch_m))) : int(m);
  }
  klim_ = detail::upload(rt_, klim);
  klim_host_ = klim;
  tf_ = make_tf(cfg_.sensor_distance_m);
  const auto& ctx = rt_.context();
  partial_ = cl::Buffer(ctx, CL_MEM_READ_WRITE, nb_ * kGroupsPerBand * 3 * rsz_);
  energy3_ = cl::Buffer(ctx, CL_MEM_READ_WRITE, nb_ * 3 * rsz_);
  // Bake what the first propagation will use now, so its cost is not charged to it.
  if (host(true))
    host_propagator();
  else
    plan();
}

bool PropagationStage::host(bool hinted) const {
  return host_fusion_ && hinted && cfg_.n < geom_.m && rt_.fft_backend() == FftBackend::FFTW;
}

HostPropagator& PropagationStage::host_propagator() {
  if (!host_prop_) host_prop_ = make_host_propagator(rt_, geom_.m, cfg_.n, nb_, prec_);
  return *host_prop_;
}

FftPlan& PropagationStage::plan(bool hinted) {
  const std::size_t m = geom_.m, n = cfg_.n;
  if (!hinted || n >= m) return rt_.fft(m, m, nb_, prec_);
  return rt_.fft(m, m, nb_, prec_, rt_.fft_backend(), FftZeroPad{n, m, n, m});
}

// Transfer function over z_m: Fresnel as the separable planes x M table t[b][k] =
// exp(-iπ λ_b z f_k²); angular spectrum as the full planes x M x M table (zero beyond the
// band limit). Both computed in double on the host, then converted to the device precision.
cl::Buffer PropagationStage::make_tf(double z_m) const {
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
  return detail::upload_complex(rt_, t, prec_);
}

cl::Buffer PropagationStage::tf(double z_m) {
  if (z_m == cfg_.sensor_distance_m) return tf_;
  if (z_m == -cfg_.sensor_distance_m) {
    if (!tf_back_()) tf_back_ = make_tf(z_m);
    return tf_back_;
  }
  return make_tf(z_m);
}

bool PropagationStage::run(cl::Buffer& field, double z_m, bool record_sampling, bool hinted, cl::Buffer* intensity,
                           cl::Buffer* crop_sums) {
  const std::size_t m = geom_.m, bands = nb_;
  cl::Buffer t = tf(z_m);
  if (host(hinted)) {
    HostPropagator::Outputs out;
    if (record_sampling) {
      out.energy3 = &energy3_;
      out.klim = klim_host_.data();
    }
    out.intensity = intensity;
    out.crop_sums = intensity ? crop_sums : nullptr;
    host_propagator().run(field, HostPropagator::Tf{&t, cfg_.propagator == Propagator::Fresnel}, out);
    if (record_sampling) {
      sampling_z_m_ = z_m;
      sampling_fresh_ = false;
    }
    return intensity != nullptr;
  }
  FftPlan& fft = plan(hinted);
  fft.forward(field);
  if (record_sampling) {
    // One pass: TF multiplication plus the sampling-check and energy reductions; the sums
    // stay on the device (energy3_) until sampling() asks for them.
    set_args(k_tf_energy_, prec_, field, t, klim_, partial_, int(m), int(kGroupsPerBand),
             cl::Local(3 * Runtime::kLocalSize * rsz_));
    rt_.queue().enqueueNDRangeKernel(k_tf_energy_, cl::NullRange, cl::NDRange(kGroupsPerBand * Runtime::kLocalSize, bands),
                                     cl::NDRange(Runtime::kLocalSize, 1));
    rt_.launch_1d(k_finalize3_, bands, prec_, partial_, energy3_, int(kGroupsPerBand), int(bands));
    sampling_z_m_ = z_m;
    sampling_fresh_ = false;
  } else {
    if (cfg_.propagator == Propagator::Fresnel) {
      set_args(k_tf_, prec_, field, t, int(m), int(bands));
      rt_.queue().enqueueNDRangeKernel(k_tf_, cl::NullRange, cl::NDRange(Runtime::global_for(m), m, bands),
                                       cl::NDRange(Runtime::kLocalSize, 1, 1));
    } else {
      rt_.launch_1d(k_tf_, bands * m * m, prec_, field, t, int(bands * m * m));
    }
  }
  fft.inverse(field);
  return false;
}

std::size_t PropagationStage::chunk_planes() {
  const std::size_t threads = std::max<std::size_t>(1, host_propagator().threads());
  // A multiple of the threads, at least kMinChunk: each chunk costs a field launch and a
  // hand-over between PoCL's threads and the propagation's (BENCHMARKS "CPU speed": at the paper
  // preset on 2 cores, 8 planes beat 2 and 4 and one chunk of all 31). The environment variable
  // QDO_STREAM_BANDS (an integer >= 1) overrides it, for such measurements.
  constexpr std::size_t kMinChunk = 8;
  std::size_t chunk = threads * ((kMinChunk + threads - 1) / threads);
  if (const char* e = std::getenv("QDO_STREAM_BANDS"); e && *e) {
    char* end = nullptr;
    const long v = std::strtol(e, &end, 10);
    if (*end != '\0' || v < 1) reject("QDO_STREAM_BANDS", e, "an integer >= 1 (bands per streamed chunk)");
    chunk = std::size_t(v);
  }
  return std::min(nb_, chunk);
}

void PropagationStage::run_planes(cl::Buffer& field, std::size_t first, std::size_t count, cl::Buffer& intensity,
                                  cl::Buffer& crop_sums) {
  const cl::Buffer t = tf(cfg_.sensor_distance_m);
  HostPropagator::Outputs out;
  out.energy3 = &energy3_;
  out.klim = klim_host_.data();
  out.intensity = &intensity;
  out.crop_sums = &crop_sums;
  host_propagator().run_planes(field, first, count, HostPropagator::Tf{&t, cfg_.propagator == Propagator::Fresnel}, out);
  sampling_z_m_ = cfg_.sensor_distance_m;
  sampling_fresh_ = false;
}

void PropagationStage::run_adjoint(cl::Buffer& gfield, const HostPropagator::IntensityAdjointInput& in) {
  const cl::Buffer t = tf(-cfg_.sensor_distance_m);
  host_propagator().run(gfield, HostPropagator::Tf{&t, cfg_.propagator == Propagator::Fresnel}, HostPropagator::Outputs{},
                        &in);
}

const SamplingReport& PropagationStage::sampling(const cl::Buffer* crop_sums) const {
  if (sampling_fresh_) return sampling_;
  // The per-plane energies of the last recording propagation, read back once (planes x 3 and planes).
  const std::size_t m = geom_.m, bands = nb_;
  const auto e3 = detail::download_real(rt_, energy3_, bands * 3, prec_);
  const auto crop = crop_sums ? detail::download_real(rt_, *crop_sums, bands, prec_) : std::vector<double>(bands, 0.0);
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
    bs.energy_outside_window = crop_sums && after > 0 ? std::max(0.0, 1.0 - crop[b] / after) : 0.0;
  }
  check_source_sampling(cfg_, sampling_.bands);
  sampling_fresh_ = true;
  return sampling_;
}

}  // namespace qdo
