// The radial PSF engine (include/qdo/physics/radial.hpp): the OpenCL engine. Its tables (Bessel
// functions, the QDHT, RadialTables) are built in radial_tables.cpp.
#include "qdo/physics/radial.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <utility>

#include "qdo/physics/adjoint.hpp"
#include "qdo/physics/cpu_reference.hpp"
#include "qdo/runtime/error.hpp"

namespace qdo {

// ---------------------------------------------------------------------------------------------
// OpenCL engine.

namespace {

using clock_type = std::chrono::steady_clock;

void check_ring_heights(const RadialTables& t, const std::vector<double>& h, double h_max_m) {
  if (h.size() != t.rings) reject("ring_heights_m.size()", h.size(), "exactly N/2 = " + to_str(t.rings));
  for (std::size_t k = 0; k < h.size(); ++k)
    if (!std::isfinite(h[k]) || h[k] < 0 || h[k] > 2 * h_max_m)
      reject("ring_heights_m[" + to_str(k) + "]", h[k], "finite, within [0, 2 h_max] = [0, " + to_str(2 * h_max_m) + "] m");
}

}  // namespace

namespace {
constexpr int kBandChunk = 8;  // bands per work-item in radial_matmul (RADIAL_BC in kernels/radial.cl)
}

struct RadialEngine::Impl {
  cl::Buffer q, qt, bt, b, source, tf, kdn, a_start, a_col, a_val, at_start, at_col, at_val,
      class_of, class_start, class_members, pair_y, pair_x, mult;
  cl::Buffer heights, c, g, gp, u2, inten, v, sums, psf_s;
  cl::Buffer g_s, g_u, dots, g_v, g_i, g_u2, g_g, g_c, g_h;
  cl::Kernel k_field, k_matmul, k_cmul, k_intensity, k_render, k_band_dot, k_expand, k_fold, k_norm_vjp, k_intensity_vjp,
      k_phase_ring;
};

SystemConfig radial_config(const SystemConfig& cfg) {
  if (cfg.aperture_edge == ApertureEdge::Area || cfg.aperture_offset())
    reject("aperture_edge", cfg.aperture_edge == ApertureEdge::Area ? "\"area\"" : "an aperture_offset_m",
           "\"inclusive\" or \"strict\" with the axis on the grid's centre for the radial path (its rings are whole "
           "samples about the centre); an area-weighted or moved aperture needs the 2-D path");
  if (cfg.object_points.empty()) return cfg;
  if (cfg.object_points.size() == 1 && cfg.object_points[0].on_axis()) return point_config(cfg, 0);
  reject("object_points", to_str(cfg.object_points.size()) + " points" + (cfg.object_points.size() == 1 ? " (off-axis)" : ""),
         "at most one on-axis point for the radial path (it serves on-axis points at any distance: one engine per point, "
         "e.g. with point_config(cfg, p)); off-axis points and stacks of points need the 2-D path");
}

RadialEngine::RadialEngine(Runtime& rt, const SystemConfig& cfg, Precision p, const RadialOptions& opt)
    : rt_(rt), cfg_(radial_config(cfg)), prec_(p) {
  cfg_.validate();
  opt.validate();
  rt_.require(p);
  tab_ = RadialTables::cached(cfg_, opt);
  impl_ = std::make_unique<Impl>();
  const RadialTables& t = *tab_;
  Impl& d = *impl_;
  const auto& ctx = rt_.context();
  const std::size_t rs = real_size(p);
  auto up_int = [&](const std::vector<int>& v) {
    std::vector<int> h = v.empty() ? std::vector<int>{0} : v;
    return cl::Buffer(ctx, CL_MEM_READ_ONLY | CL_MEM_COPY_HOST_PTR, h.size() * sizeof(int), h.data());
  };
  auto up_real = [&](const std::vector<double>& v) {
    std::vector<double> h = v.empty() ? std::vector<double>{0.0} : v;
    if (p == Precision::F64) return cl::Buffer(ctx, CL_MEM_READ_ONLY | CL_MEM_COPY_HOST_PTR, h.size() * 8, h.data());
    std::vector<float> f(h.begin(), h.end());
    return cl::Buffer(ctx, CL_MEM_READ_ONLY | CL_MEM_COPY_HOST_PTR, f.size() * 4, f.data());
  };
  auto up_complex = [&](const std::vector<cdouble>& v) {
    std::vector<double> h(2 * v.size());
    for (std::size_t e = 0; e < v.size(); ++e) {
      h[2 * e] = v[e].real();
      h[2 * e + 1] = v[e].imag();
    }
    return up_real(h);
  };
  d.q = up_real(t.q);
  std::vector<double> qt(t.rings * t.k), bt(t.k * t.j);
  for (std::size_t m = 0; m < t.k; ++m)
    for (std::size_t r = 0; r < t.rings; ++r) qt[r * t.k + m] = t.q[m * t.rings + r];
  d.qt = up_real(qt);
  for (std::size_t j = 0; j < t.j; ++j)
    for (std::size_t m = 0; m < t.k; ++m) bt[m * t.j + j] = t.b[j * t.k + m];
  d.bt = up_real(bt);
  d.b = up_real(t.b);
  d.source = up_complex(t.source);
  d.tf = up_complex(t.tf);
  d.kdn = up_real(t.kdn_per_m);
  d.a_start = up_int(t.a_start);
  d.a_col = up_int(t.a_col);
  d.a_val = up_real(t.a_val);
  d.at_start = up_int(t.at_start);
  d.at_col = up_int(t.at_col);
  d.at_val = up_real(t.at_val);
  d.class_of = up_int(t.class_of);
  d.class_start = up_int(t.class_start);
  d.class_members = up_int(t.class_members);
  d.pair_y = up_int(t.pair_y);
  d.pair_x = up_int(t.pair_x);
  d.mult = up_real(t.multiplicity);
  const std::size_t bands = t.bands, br = bands * t.rings, bk = bands * t.k, bj = bands * t.j, bu = bands * t.unique, bss = bands * t.s * t.s;
  auto rw = [&](std::size_t count) { return cl::Buffer(ctx, CL_MEM_READ_WRITE, std::max<std::size_t>(count, 1) * rs); };
  d.heights = rw(t.rings);
  d.c = rw(2 * br);
  d.g = rw(2 * bk);
  d.gp = rw(2 * bk);
  d.u2 = rw(2 * bj);
  d.inten = rw(bj);
  d.v = rw(bu);
  d.sums = rw(bands);
  d.psf_s = rw(bss);
  d.g_s = rw(bss);
  d.g_u = rw(bu);
  d.dots = rw(bands);
  d.g_v = rw(bu);
  d.g_i = rw(bj);
  d.g_u2 = rw(2 * bj);
  d.g_g = rw(2 * bk);
  d.g_c = rw(2 * br);
  d.g_h = rw(t.rings);
  const std::string f = "radial.cl", opts = "-DRADIAL_TILE=" + std::to_string(Runtime::kLocalSize);
  d.k_field = rt_.kernel(f, "radial_field", p, opts);
  d.k_matmul = rt_.kernel(f, "radial_matmul", p, opts);
  d.k_cmul = rt_.kernel(f, "radial_cmul_table", p, opts);
  d.k_intensity = rt_.kernel(f, "radial_intensity", p, opts);
  d.k_render = rt_.kernel(f, "radial_csr_apply", p, opts);
  d.k_band_dot = rt_.kernel(f, "radial_band_dot", p, opts);
  d.k_expand = rt_.kernel(f, "radial_expand", p, opts);
  d.k_fold = rt_.kernel(f, "radial_fold", p, opts);
  d.k_norm_vjp = rt_.kernel(f, "radial_normalize_vjp", p, opts);
  d.k_intensity_vjp = rt_.kernel(f, "radial_intensity_vjp", p, opts);
  d.k_phase_ring = rt_.kernel(f, "radial_phase_ring_vjp", p, opts);
}

RadialEngine::~RadialEngine() = default;

namespace {

// y (bands x rows complex) = M x (bands x cols complex), M given column-major (mt[c * rows + r]).
void matmul(cl::CommandQueue& q, cl::Kernel& k, Precision p, const cl::Buffer& mt, const cl::Buffer& x, cl::Buffer& y,
            std::size_t rows, std::size_t cols, std::size_t bands) {
  set_args(k, p, mt, x, y, int(rows), int(cols), int(bands));
  const std::size_t chunks = (bands + kBandChunk - 1) / kBandChunk;
  q.enqueueNDRangeKernel(k, cl::NullRange, cl::NDRange(Runtime::global_for(rows), chunks), cl::NDRange(Runtime::kLocalSize, 1));
}

void band_dot(cl::CommandQueue& q, cl::Kernel& k, Precision p, const cl::Buffer& x, const cl::Buffer& y,
              int y_band_stride, cl::Buffer& out, std::size_t len, std::size_t bands) {
  set_args(k, p, x, y, y_band_stride, int(len), out, cl::Local(Runtime::kLocalSize * sizeof(double)));
  q.enqueueNDRangeKernel(k, cl::NullRange, cl::NDRange(Runtime::kLocalSize, bands), cl::NDRange(Runtime::kLocalSize, 1));
}

std::vector<double> download(cl::CommandQueue& q, const cl::Buffer& b, std::size_t count, Precision p) {
  std::vector<double> out(count);
  Runtime::read_reals(q, b, out.data(), count, p);
  return out;
}

void upload_into(cl::CommandQueue& q, cl::Buffer& b, const std::vector<double>& v, Precision p) {
  Runtime::write_reals(q, b, v.data(), v.size(), p);
}

}  // namespace

void RadialEngine::compute_psf(const std::vector<double>& ring_heights_m) {
  const RadialTables& t = *tab_;
  check_ring_heights(t, ring_heights_m, cfg_.h_max_m());
  const auto t0 = clock_type::now();
  Impl& d = *impl_;
  cl::CommandQueue& q = rt_.queue();
  const std::size_t bands = t.bands;
  upload_into(q, d.heights, ring_heights_m, prec_);
  rt_.launch_1d(d.k_field, bands * t.rings, prec_, d.source, d.kdn, d.heights, d.c, int(t.rings), int(bands));
  matmul(q, d.k_matmul, prec_, d.qt, d.c, d.g, t.k, t.rings, bands);  // Q: Q^T row-major is Q column-major
  rt_.launch_1d(d.k_cmul, bands * t.k, prec_, d.g, d.tf, d.gp, int(bands * t.k), 0);
  matmul(q, d.k_matmul, prec_, d.bt, d.gp, d.u2, t.j, t.k, bands);
  rt_.launch_1d(d.k_intensity, bands * t.j, prec_, d.u2, d.inten, int(bands * t.j));
  rt_.launch_1d(d.k_render, bands * t.unique, prec_, d.a_start, d.a_col, d.a_val, d.inten, d.v, int(t.unique), int(t.j),
                int(bands));
  band_dot(q, d.k_band_dot, prec_, d.v, d.mult, 0, d.sums, t.unique, bands);
  rt_.launch_1d(d.k_expand, bands * t.s * t.s, prec_, d.v, d.sums, d.class_of, d.psf_s, int(t.s), int(t.unique),
                int(bands));
  q.finish();
  valid_ = true;
  ++generation_;
  t_fwd_ = std::chrono::duration<double>(clock_type::now() - t0).count();
}

RealStack RadialEngine::psf_sensor() const {
  if (!valid_) throw Error("RadialEngine: compute_psf() must run before psf_sensor()");
  const RadialTables& t = *tab_;
  RealStack out(t.bands, t.s, t.s);
  out.data = download(rt_.queue(), impl_->psf_s, out.size(), prec_);
  return out;
}

std::vector<double> RadialEngine::intensity() const {
  if (!valid_) throw Error("RadialEngine: compute_psf() must run before intensity()");
  return download(rt_.queue(), impl_->inten, tab_->bands * tab_->j, prec_);
}

std::vector<double> RadialEngine::psf_sensor_vjp(const RealStack& g_psf_sensor) {
  const RadialTables& t = *tab_;
  if (g_psf_sensor.planes != t.bands || g_psf_sensor.rows != t.s || g_psf_sensor.cols != t.s)
    reject("g_psf_sensor", to_str(g_psf_sensor.planes) + " x " + to_str(g_psf_sensor.rows) + " x " + to_str(g_psf_sensor.cols),
           "bands x S x S = " + to_str(t.bands) + " x " + to_str(t.s) + " x " + to_str(t.s));
  for (double v : g_psf_sensor.data)
    if (!std::isfinite(v)) reject("g_psf_sensor", v, "finite values");
  if (!valid_) throw Error("RadialEngine: compute_psf() must run before an adjoint");
  const auto t0 = clock_type::now();
  upload_into(rt_.queue(), impl_->g_s, g_psf_sensor.data, prec_);
  return vjp_from(impl_->g_s, t0);
}

const cl::Buffer& RadialEngine::psf_sensor_buffer() const { return impl_->psf_s; }

std::string RadialEngine::describe() const {
  return "simulated (radial, N = " + to_str(cfg_.n) + ", " + to_string(prec_) + ")";
}

std::vector<double> RadialEngine::psf_sensor_vjp(const cl::Buffer& g_psf_sensor) {
  const RadialTables& t = *tab_;
  const std::size_t bytes = t.bands * t.s * t.s * (prec_ == Precision::F64 ? sizeof(double) : sizeof(float));
  if (g_psf_sensor.getInfo<CL_MEM_SIZE>() < bytes)
    reject("g_psf_sensor buffer", to_str(g_psf_sensor.getInfo<CL_MEM_SIZE>()) + " bytes",
           ">= " + to_str(bytes) + " (bands x S x S reals of the engine's precision)");
  if (!valid_) throw Error("RadialEngine: compute_psf() must run before an adjoint");
  return vjp_from(g_psf_sensor, clock_type::now());
}

// The adjoint chain from dL/dpsf_sensor on the device (g_s: bands x S x S, only read).
std::vector<double> RadialEngine::vjp_from(const cl::Buffer& g_s, std::chrono::steady_clock::time_point t0) {
  const RadialTables& t = *tab_;
  Impl& d = *impl_;
  cl::CommandQueue& q = rt_.queue();
  const std::size_t bands = t.bands;
  rt_.launch_1d(d.k_fold, bands * t.unique, prec_, g_s, d.class_start, d.class_members, d.pair_y, d.pair_x, d.g_u,
                int(t.s), int(t.unique), int(bands));
  band_dot(q, d.k_band_dot, prec_, d.g_u, d.v, int(t.unique), d.dots, t.unique, bands);
  rt_.launch_1d(d.k_norm_vjp, bands * t.unique, prec_, d.g_u, d.mult, d.dots, d.sums, d.g_v, int(t.unique), int(bands));
  rt_.launch_1d(d.k_render, bands * t.j, prec_, d.at_start, d.at_col, d.at_val, d.g_v, d.g_i, int(t.j), int(t.unique),
                int(bands));
  rt_.launch_1d(d.k_intensity_vjp, bands * t.j, prec_, d.g_i, d.u2, d.g_u2, int(bands * t.j));
  matmul(q, d.k_matmul, prec_, d.b, d.g_u2, d.g_g, t.k, t.j, bands);  // B^T: B row-major is B^T column-major
  rt_.launch_1d(d.k_cmul, bands * t.k, prec_, d.g_g, d.tf, d.g_g, int(bands * t.k), 1);
  matmul(q, d.k_matmul, prec_, d.q, d.g_g, d.g_c, t.rings, t.k, bands);  // Q^T: Q row-major is Q^T column-major
  rt_.launch_1d(d.k_phase_ring, t.rings, prec_, d.g_c, d.c, d.kdn, d.g_h, int(t.rings), int(bands));
  std::vector<double> gh = download(q, d.g_h, t.rings, prec_);
  t_adj_ = std::chrono::duration<double>(clock_type::now() - t0).count();
  return gh;
}

}  // namespace qdo
