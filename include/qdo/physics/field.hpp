// The field just after the DOE on the device (kernels/field.cl), and the vector-Jacobian product of
// its phase back to the heights. The CPU reference is ref::doe_field (cpu_reference.hpp).
//
// Planes: designs x points x bands, design-major then point-major (plane (d * points + p) * bands + b
// uses height map d, object point p of cfg.points() and band b; points = cfg.point_count(), 1 unless
// the configuration lists object points).
// Heights: designs x N x N reals of the precision (DoeStage's buffer, doe.hpp). Field: planes x M x M
// complex (interleaved, the precision, row-major; M = PropagationGeometry::m), the N x N DOE samples
// stored at rows/cols [kOffset, kOffset + N) = [0, N): the centred window of PropagationGeometry
// circularly shifted by -offset (see PropagationStage::plan in propagate.hpp); every other sample,
// and every sample outside the aperture, is zero; with aperture_edge "area" each sample carries its
// aperture weight (aperture_transmission, optics.hpp).
#pragma once
#include <CL/opencl.hpp>

#include <cstddef>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

class FieldStage {
 public:
  // Where the DOE samples sit in the stored M x M window (see above).
  static constexpr std::size_t kOffset = 0;

  // One per (configuration, precision, designs); the configuration (with its object points) is
  // taken as valid. phase_fp64
  // (float32 only; the device needs cl_khr_fp64): the field from doe_field_p64, the phase and its
  // sine/cosine in double before rounding to float; phase_vjp stays float32. Ignored for F64.
  FieldStage(Runtime& rt, const SystemConfig& cfg, Precision p, std::size_t designs = 1, bool phase_fp64 = false);
  FieldStage(const FieldStage&) = delete;
  FieldStage& operator=(const FieldStage&) = delete;

  // The field of every plane into `field` (planes() x M x M complex). crop_rows: only rows [0, N)
  // and the columns up to N rounded to the work-group size are written (all a pruned propagation
  // reads); otherwise the whole window.
  void run(const cl::Buffer& heights, cl::Buffer& field, bool crop_rows = false);
  // The planes [i * chunk, min((i + 1) * chunk, planes())) of a one-design stage into `field`
  // (their count x M x M complex, plane i * chunk + j at complex offset j * M * M), rows [0, N)
  // only as run(..., true): the streamed PSF, which makes and propagates a chunk of planes at a time.
  void run_chunk(const cl::Buffer& heights, cl::Buffer& field, std::size_t chunk, std::size_t i);
  // dL/dH (N x N reals into dh) at the heights of a one-design stage, from the gradient on the
  // field after the DOE: gfield (points x bands x M x M complex; [0, N)^2 read); the gradients of
  // all object points add up.
  void phase_vjp(const cl::Buffer& heights, const cl::Buffer& gfield, cl::Buffer& dh);
  // A host copy of a field of the stored layout (planes() x M x M) as the centred window of
  // PropagationGeometry (samples at [offset, offset + N)), the layout of ref::doe_field.
  ComplexStack centred(const cl::Buffer& field);

  // The optical axis moved (cfg.aperture_offset_*_m, aperture_edge "area"; config.hpp) without a
  // new stage: the object points' table and the aperture's weights uploaded again. cfg must equal
  // the stage's configuration but for those two keys (taken as valid).
  void set_axis(const SystemConfig& cfg);

  std::size_t planes() const { return nb_; }
  std::size_t points() const { return points_; }
  // The object points as doe_field reads them: points x 4 doubles (x0, y0, d, R0) per point of
  // cfg.points() (kernels/field.cl; a plane wave: (α, β, -1, 0), its direction cosines), moved
  // with the optical axis (cfg.aperture_offset_*_m).
  static std::vector<double> point_table(const SystemConfig& cfg);
  const PropagationGeometry& geometry() const { return geom_; }
  bool phase_fp64() const { return phase_fp64_; }

 private:
  // Sets the arguments doe_field, doe_field_p64 and phase_vjp share: (height, k_tab, dn_tab, a3,
  // a4, n, m, offset, planes, pitch, point table, points, aperture radius^2), the scalars
  // in precision p; planes = `planes`, or all planes (nb_) when 0.
  template <typename A3, typename A4>
  void set_phase_args(cl::Kernel& k, Precision p, const cl::Buffer& heights, const cl::Buffer& k_tab,
                      const cl::Buffer& dn_tab, const A3& a3, const A4& a4, std::size_t planes = 0);

  Runtime& rt_;
  SystemConfig cfg_;
  Precision prec_;
  std::size_t designs_ = 1, points_ = 1, nb_ = 0;
  bool phase_fp64_ = false;
  PropagationGeometry geom_;
  cl::Kernel k_field_, k_phase_vjp_;
  cl::Buffer k_, dn_;      // per plane: 2π/λ (1/m) and n - 1, reals of the precision
  cl::Buffer k64_, dn64_;  // the same in double for doe_field_p64
  cl::Buffer pt_, pt64_;   // point_table(cfg) in the precision, and in double for doe_field_p64
  cl::Buffer amp_;         // aperture_transmission(cfg) (N x N reals of the precision) when use_amp_
  bool use_amp_ = false;   // aperture_edge area
  std::vector<cl::Buffer> chunk_k_, chunk_dn_;  // per chunk of run_chunk: its planes' k and dn
  std::size_t chunk_planes_ = 0;                // the planes per chunk those tables were made for
};

}  // namespace qdo
