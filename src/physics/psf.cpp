// PsfStage (include/qdo/physics/psf.hpp): the launcher of kernels/psf.cl.
#include "qdo/physics/psf.hpp"

#include <algorithm>

#include "physics/device_buffers.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/physics/field.hpp"

namespace qdo {

PsfStage::PsfStage(Runtime& rt, const SystemConfig& cfg, Precision p, std::size_t designs)
    : rt_(rt), cfg_(cfg), prec_(p), nb_(cfg.bands * designs * cfg.point_count()), s_(cfg.sensor_size_px()),
      m_(PropagationGeometry::from_config(cfg).m), rsz_(real_size(p)) {
  if (designs < 1) reject("designs", designs, ">= 1");
  set_sensor_weights(cfg_);
  k_crop_sums_ = rt_.kernel("psf.cl", "intensity_crop_sums", p);
  k_sums_ = rt_.kernel("psf.cl", "band_sums", p);
  k_finalize_ = rt_.kernel("psf.cl", "finalize_sums", p);
  k_scale_ = rt_.kernel("psf.cl", "scale_by_sums", p);
  k_resample_ = rt_.kernel("psf.cl", "resample_area", p);
  k_dot_ = rt_.kernel("psf.cl", "band_dot", p);
  k_norm_vjp_ = rt_.kernel("psf.cl", "normalize_vjp", p);
  k_int_vjp_ = rt_.kernel("psf.cl", "intensity_vjp", p);
  partial_ = cl::Buffer(rt_.context(), CL_MEM_READ_WRITE, nb_ * kGroupsPerBand * rsz_);
}

void PsfStage::set_sensor_weights(const SystemConfig& cfg) {
  cfg_.aperture_offset_x_m = cfg.aperture_offset_x_m;
  cfg_.aperture_offset_y_m = cfg.aperture_offset_y_m;
  weights_ = sensor_weights(cfg_);  // the sensor window centred on the optical axis
  wstart_ = detail::upload(rt_, weights_.start);
  wts_ = detail::upload_real(rt_, weights_.w, prec_);
  wts_t_ = cl::Buffer();  // weights_transposed() makes them again
  wstart_t_ = cl::Buffer();
}

void PsfStage::intensity_crop_sums(const cl::Buffer& field, cl::Buffer& psf, cl::Buffer& sums) {
  const std::size_t bands = nb_;
  set_args(k_crop_sums_, prec_, field, psf, int(cfg_.n), int(m_), int(FieldStage::kOffset), partial_, int(kGroupsPerBand),
           cl::Local(Runtime::kLocalSize * rsz_));
  rt_.queue().enqueueNDRangeKernel(k_crop_sums_, cl::NullRange, cl::NDRange(kGroupsPerBand * Runtime::kLocalSize, bands),
                                   cl::NDRange(Runtime::kLocalSize, 1));
  rt_.launch_1d(k_finalize_, bands, prec_, partial_, sums, int(kGroupsPerBand), int(bands));
}

void PsfStage::resample(const cl::Buffer& native, cl::Buffer& sensor) {
  rt_.launch_1d(k_resample_, nb_ * s_ * s_, prec_, native, sensor, wstart_, wts_, int(cfg_.n), int(s_), int(weights_.taps),
                int(nb_), int(weights_.col_offset));
}

const AreaWeights& PsfStage::weights_transposed() {
  if (!wts_t_()) {
    weights_t_ = weights_.transposed();
    wstart_t_ = detail::upload(rt_, weights_t_.start);
    wts_t_ = detail::upload_real(rt_, weights_t_.w, prec_);
  }
  return weights_t_;
}

void PsfStage::resample_transposed(const cl::Buffer& sensor, cl::Buffer& native) {
  const std::size_t n = cfg_.n;
  const std::size_t taps = weights_transposed().taps;
  rt_.launch_1d(k_resample_, nb_ * n * n, prec_, sensor, native, wstart_t_, wts_t_, int(s_), int(n), int(taps), int(nb_),
                int(weights_t_.col_offset));
}

void PsfStage::normalize(cl::Buffer& x, std::size_t len, cl::Buffer& sums) {
  const std::size_t bands = nb_;
  set_args(k_sums_, prec_, x, int(len), partial_, int(kGroupsPerBand), cl::Local(Runtime::kLocalSize * rsz_));
  rt_.queue().enqueueNDRangeKernel(k_sums_, cl::NullRange, cl::NDRange(kGroupsPerBand * Runtime::kLocalSize, bands),
                                   cl::NDRange(Runtime::kLocalSize, 1));
  rt_.launch_1d(k_finalize_, bands, prec_, partial_, sums, int(kGroupsPerBand), int(bands));
  scale(x, len, sums);
}

void PsfStage::scale(cl::Buffer& x, std::size_t len, const cl::Buffer& sums) {
  rt_.launch_1d(k_scale_, nb_ * len, prec_, x, sums, int(len), int(nb_));
}

void PsfStage::normalize_vjp(cl::Buffer& g, const cl::Buffer& y, std::size_t len, const cl::Buffer& sums) {
  const std::size_t bands = nb_;  // one design: points x bands planes
  if (!dots_()) dots_ = cl::Buffer(rt_.context(), CL_MEM_READ_WRITE, bands * rsz_);
  set_args(k_dot_, prec_, g, y, int(len), partial_, int(kGroupsPerBand), cl::Local(Runtime::kLocalSize * rsz_));
  rt_.queue().enqueueNDRangeKernel(k_dot_, cl::NullRange, cl::NDRange(kGroupsPerBand * Runtime::kLocalSize, bands),
                                   cl::NDRange(Runtime::kLocalSize, 1));
  rt_.launch_1d(k_finalize_, bands, prec_, partial_, dots_, int(kGroupsPerBand), int(bands));
  rt_.launch_1d(k_norm_vjp_, bands * len, prec_, g, dots_, sums, int(len), int(bands));
}

void PsfStage::intensity_vjp(const cl::Buffer& g_native, const cl::Buffer& field, cl::Buffer& gfield, bool crop_rows) {
  const std::size_t n = cfg_.n, m = m_, bands = nb_;  // one design: points x bands planes
  set_args(k_int_vjp_, prec_, g_native, field, gfield, int(n), int(m), int(FieldStage::kOffset), int(bands));
  const std::size_t rows = crop_rows ? n : m;
  const std::size_t cols = crop_rows ? std::min(Runtime::global_for(n), Runtime::global_for(m)) : Runtime::global_for(m);
  rt_.queue().enqueueNDRangeKernel(k_int_vjp_, cl::NullRange, cl::NDRange(cols, rows, bands),
                                   cl::NDRange(Runtime::kLocalSize, 1, 1));
}

}  // namespace qdo
