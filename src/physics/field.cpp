// FieldStage (include/qdo/physics/field.hpp): the launcher of kernels/field.cl.
#include "qdo/physics/field.hpp"

#include <algorithm>
#include <cmath>

#include "physics/device_buffers.hpp"
#include "qdo/runtime/error.hpp"

namespace qdo {

namespace {
constexpr double kPi = 3.14159265358979323846;
}  // namespace

std::vector<double> FieldStage::point_table(const SystemConfig& cfg) {
  std::vector<double> t;
  for (const ObjectPoint& pt : cfg.points()) {
    const double tx = std::tan(pt.field_x_deg * kPi / 180.0), ty = std::tan(pt.field_y_deg * kPi / 180.0);
    if (pt.at_infinity()) {
      // Direction cosines of (tan θx, tan θy, 1); exactly 0 on axis.
      const double g = std::sqrt(1.0 + tx * tx + ty * ty);
      t.insert(t.end(), {tx / g, ty / g, -1.0, 0.0});
    } else {
      // The points move with the optical axis (cfg.aperture_offset_*_m); a plane wave's tilt is the
      // same about any centre (a constant phase apart).
      const double d = pt.distance_m, x0 = d * tx + cfg.aperture_offset_x_m, y0 = d * ty + cfg.aperture_offset_y_m;
      t.insert(t.end(), {x0, y0, d, std::sqrt(x0 * x0 + y0 * y0 + d * d)});
    }
  }
  return t;
}

FieldStage::FieldStage(Runtime& rt, const SystemConfig& cfg, Precision p, std::size_t designs, bool phase_fp64)
    : rt_(rt), cfg_(cfg), prec_(p), designs_(designs), points_(cfg.point_count()), nb_(cfg.bands * designs * points_),
      phase_fp64_(phase_fp64 && p == Precision::F32), geom_(PropagationGeometry::from_config(cfg)) {
  if (designs_ < 1) reject("designs", designs_, ">= 1");
  if (phase_fp64_ && !rt_.has_fp64())
    reject("phase_fp64", "true", "false on this device (" + rt_.info().name + " has no cl_khr_fp64)");
  k_field_ = phase_fp64_ ? rt_.kernel("field.cl", "doe_field_p64", p, "-DQDO_PHASE_FP64=1")
                         : rt_.kernel("field.cl", "doe_field", p);
  k_phase_vjp_ = rt_.kernel("field.cl", "phase_vjp", p);
  // Per-plane tables: the band grid repeats for every (design, point) group.
  std::vector<double> kk, dd;
  for (std::size_t d = 0; d < designs_ * points_; ++d) {
    const auto k1 = wavenumber_per_band(cfg_), d1 = delta_n_per_band(cfg_);
    kk.insert(kk.end(), k1.begin(), k1.end());
    dd.insert(dd.end(), d1.begin(), d1.end());
  }
  k_ = detail::upload_real(rt_, kk, prec_);
  dn_ = detail::upload_real(rt_, dd, prec_);
  if (phase_fp64_) {
    k64_ = detail::upload(rt_, kk);
    dn64_ = detail::upload(rt_, dd);
  }
  set_axis(cfg_);
}

void FieldStage::set_axis(const SystemConfig& cfg) {
  cfg_.aperture_edge = cfg.aperture_edge;
  cfg_.aperture_offset_x_m = cfg.aperture_offset_x_m;
  cfg_.aperture_offset_y_m = cfg.aperture_offset_y_m;
  const std::vector<double> pts = point_table(cfg_);
  pt_ = detail::upload_real(rt_, pts, prec_);
  if (phase_fp64_) pt64_ = detail::upload(rt_, pts);
  // The aperture's weights (kernels/field.cl use_amp): N x N with aperture_edge "area", else one
  // unread element.
  use_amp_ = cfg_.aperture_edge == ApertureEdge::Area;
  amp_ = detail::upload_real(rt_, use_amp_ ? aperture_transmission(cfg_) : std::vector<double>{1.0}, prec_);
}

template <typename A3, typename A4>
void FieldStage::set_phase_args(cl::Kernel& k, Precision p, const cl::Buffer& heights, const cl::Buffer& k_tab,
                                const cl::Buffer& dn_tab, const A3& a3, const A4& a4, std::size_t planes) {
  const double r_ap2_px = cfg_.aperture_inside_px2();  // as ref::doe_field: half an integer, exact in float
  const cl::Buffer& pt = p == Precision::F64 && phase_fp64_ ? pt64_ : pt_;
  set_args(k, p, heights, k_tab, dn_tab, a3, a4, int(cfg_.n), int(geom_.m), int(kOffset), int(planes ? planes : nb_),
           Real{cfg_.pitch_m}, pt, int(points_), Real{r_ap2_px}, amp_, int(use_amp_));
}

void FieldStage::run(const cl::Buffer& heights, cl::Buffer& field, bool crop_rows) {
  // Argument 4: planes per (design, point) group (plane b belongs to group b / bands).
  // doe_field_p64 takes the tables and scalars in double.
  if (phase_fp64_)
    set_phase_args(k_field_, Precision::F64, heights, k64_, dn64_, field, int(cfg_.bands));
  else
    set_phase_args(k_field_, prec_, heights, k_, dn_, field, int(cfg_.bands));
  // 3-D NDRange (columns, rows, designs), work-group (kLocalSize, 1, 1); crop_rows: rows [0, N)
  // and the columns up to N rounded to the work-group size (the rest of the window is not read).
  const std::size_t m = geom_.m, n = cfg_.n, rows = crop_rows ? n : m;
  const std::size_t cols = crop_rows ? std::min(Runtime::global_for(n), Runtime::global_for(m)) : Runtime::global_for(m);
  rt_.queue().enqueueNDRangeKernel(k_field_, cl::NullRange, cl::NDRange(cols, rows, designs_ * points_),
                                   cl::NDRange(Runtime::kLocalSize, 1, 1));
}

void FieldStage::run_chunk(const cl::Buffer& heights, cl::Buffer& field, std::size_t chunk, std::size_t i) {
  if (designs_ != 1) reject("designs", designs_, "1 for a chunk of planes");
  if (points_ != 1) reject("object points", points_, "1 for a chunk of planes");
  const std::size_t bands = nb_, n = cfg_.n, m = geom_.m;
  if (chunk < 1) reject("chunk", chunk, ">= 1 planes");
  const std::size_t chunks = (bands + chunk - 1) / chunk;
  if (i >= chunks) reject("chunk index", i, "< " + to_str(chunks) + " (chunks of " + to_str(chunk) + " of " + to_str(bands) + " planes)");
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
      chunk_k_.push_back(phase_fp64_ ? detail::upload(rt_, k1) : detail::upload_real(rt_, k1, prec_));
      chunk_dn_.push_back(phase_fp64_ ? detail::upload(rt_, d1) : detail::upload_real(rt_, d1, prec_));
    }
  }
  const Precision pp = phase_fp64_ ? Precision::F64 : prec_;  // doe_field_p64 takes its scalars in double
  const std::size_t cols = std::min(Runtime::global_for(n), Runtime::global_for(m));
  const std::size_t c = std::min(chunk, bands - i * chunk);
  // doe_field over c planes of one design (bands_per_design = bands = c), rows [0, N) only, as
  // run(..., true).
  set_phase_args(k_field_, pp, heights, chunk_k_[i], chunk_dn_[i], field, int(c), c);
  rt_.queue().enqueueNDRangeKernel(k_field_, cl::NullRange, cl::NDRange(cols, n, 1), cl::NDRange(Runtime::kLocalSize, 1, 1));
}

void FieldStage::phase_vjp(const cl::Buffer& heights, const cl::Buffer& gfield, cl::Buffer& dh) {
  set_phase_args(k_phase_vjp_, prec_, heights, k_, dn_, gfield, dh);
  rt_.enqueue_1d(k_phase_vjp_, cfg_.n * cfg_.n);
}

ComplexStack FieldStage::centred(const cl::Buffer& field) {
  const std::size_t m = geom_.m, o = geom_.offset;
  const std::vector<cdouble> dev = detail::download_complex(rt_, field, nb_ * m * m, prec_);
  ComplexStack out(nb_, m, m);
  for (std::size_t b = 0; b < nb_; ++b)
    for (std::size_t y = 0; y < m; ++y)
      for (std::size_t x = 0; x < m; ++x) out(b, y, x) = dev[(b * m + (y + m - o) % m) * m + (x + m - o) % m];
  return out;
}

}  // namespace qdo
