// The PSF from the propagated field on the device (kernels/psf.cl): intensity of the N x N crop,
// per-plane sums and normalisation, area resampling onto the sensor pitch, and their adjoints.
// The CPU references are ref::psf_stack, ref::resample_area (cpu_reference.hpp) and the adjoints
// of adjoint.hpp.
//
// Planes: designs x points x bands, design-major then point-major (points = cfg.point_count()). Native stack: planes x N x N reals of the precision
// (row-major); sensor stack: planes x S x S (S = cfg.sensor_size_px()); per-plane sums: planes
// reals; field: planes x M x M complex in the FieldStage layout (field.hpp: the crop at [0, N)^2).
#pragma once
#include <CL/opencl.hpp>

#include <cstddef>

#include "qdo/data/config.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/runtime/runtime.hpp"

namespace qdo {

class PsfStage {
 public:
  // One per (configuration, precision, designs); the configuration is taken as valid. Uploads the
  // area weights N -> S.
  PsfStage(Runtime& rt, const SystemConfig& cfg, Precision p, std::size_t designs = 1);
  PsfStage(const PsfStage&) = delete;
  // The sensor window centred on a moved optical axis (sensor_weights(cfg), optics.hpp) without a
  // new stage: the area weights made and uploaded again (their transpose on next use).
  void set_sensor_weights(const SystemConfig& cfg);
  PsfStage& operator=(const PsfStage&) = delete;

  // psf = |field|² on the crop (planes x N x N, unnormalised) and sums = its per-plane sums
  // (intensity_crop_sums, finalize_sums).
  void intensity_crop_sums(const cl::Buffer& field, cl::Buffer& psf, cl::Buffer& sums);
  // native (planes x N x N) -> sensor (planes x S x S) with AreaWeights::make(N, pitch, S, sensor pitch).
  void resample(const cl::Buffer& native, cl::Buffer& sensor);
  // The transpose: sensor-grid values (planes x S x S) -> native grid (planes x N x N), with
  // weights_transposed().
  void resample_transposed(const cl::Buffer& sensor, cl::Buffer& native);
  // sums = per-plane sums of x (planes x len), then x /= sums where sums > 0.
  void normalize(cl::Buffer& x, std::size_t len, cl::Buffer& sums);
  // x /= sums per plane (x: planes x len) where sums > 0.
  void scale(cl::Buffer& x, std::size_t len, const cl::Buffer& sums);

  // Adjoints (one design: planes = points x bands; "bands" below reads planes).
  // VJP of y = x / Σx per plane, in place on g (bands x len): g <- (g - <g, y>) / Σx (0 where Σx <= 0).
  void normalize_vjp(cl::Buffer& g, const cl::Buffer& y, std::size_t len, const cl::Buffer& sums);
  // VJP of P = |U|² on the crop: gfield (bands x M x M complex) = 2 g_native U inside [0, N)^2,
  // 0 outside, from g_native (bands x N x N) and the propagated field. crop_rows: rows [0, N) and
  // the columns up to N rounded to the work-group size are written (enough for a pruned
  // propagation), else the whole window.
  void intensity_vjp(const cl::Buffer& g_native, const cl::Buffer& field, cl::Buffer& gfield, bool crop_rows);

  const AreaWeights& weights() const { return weights_; }
  // The transposed weights S -> N (made and uploaded on first use).
  const AreaWeights& weights_transposed();
  std::size_t sensor_size() const { return s_; }

 private:
  Runtime& rt_;
  SystemConfig cfg_;
  Precision prec_;
  std::size_t nb_ = 0, s_ = 0, m_ = 0, rsz_ = 4;
  static constexpr std::size_t kGroupsPerBand = 32;
  AreaWeights weights_, weights_t_;
  cl::Kernel k_crop_sums_, k_sums_, k_finalize_, k_scale_, k_resample_, k_dot_, k_norm_vjp_, k_int_vjp_;
  cl::Buffer wstart_, wts_, wstart_t_, wts_t_;  // area weights (start ints, taps reals) and their transpose
  cl::Buffer partial_;                          // per-work-group partial sums: planes x groups
  cl::Buffer dots_;                             // normalize_vjp's <g, y> per plane (made on first use)
};

}  // namespace qdo
