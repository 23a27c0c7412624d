// The rotationally symmetric PSF engine: the PSF stack of a radial design (N/2 ring heights,
// doe.hpp Parameterization::Radial) without any 2-D FFT, forward and adjoint, on the device
// (float32 / float64) and as a plain CPU reference in double (namespace ref).
//
// Model (per band b; REFERENCE §1 conventions). The 2-D path's field is, pixel by pixel, a function of
// the pixel-centre radius only: U1(r) = [r <= r_ap] exp(i k (r²/(sqrt(r²+d²)+d) + (n_b - 1) h_ring(r))) with
// ring(r) = floor(r / pitch) (expand_parameters: pixels at radius r in [k, k+1) pitches take h_k). Its
// continuous counterpart is a staircase in r, whose Hankel transform is computed exactly ring by ring:
//   c_bk      = exp(i k_b src(r_mid,k)) exp(i k_b (n_b - 1) h_k), r_mid,k the middle of ring k within the
//               aperture (the source phase varies by at most k r pitch / d across a ring: 0.13 rad at the
//               rim of the paper's aperture at 400 nm; it is taken at the ring middle)
//   spectrum  G(rho_m) = sum_k Q_mk c_bk, Q_mk = scale_m * 2 pi int_{ring k} J0(2 pi rho_m r) r dr
//               = scale_m [r J1(2 pi rho_m r) / rho_m]_{k pitch}^{min((k+1) pitch, r_ap)}: one real K x N/2
//               matrix for all bands, at the frequencies rho_m = j_m / (2 pi R) of the quasi-discrete Hankel
//               transform (Guizar-Sicairos & Gutierrez-Vega, JOSA A 21, 53 (2004); j_m the zeros of J0,
//               R the radial window, scale_m = j_{K+1} / (2 pi R² |J1(j_m)|) its normalisation)
//   propagate G' = TF_b(rho) G, the 2-D path's transfer function (Fresnel exp(-i pi lambda z rho²), or the
//               angular spectrum with its band limit applied radially, rho <= f_lim)
//   field     u(r_j) = sum_m B_jm G'_m, B_jm = 2 J0(2 pi rho_m r_j) / (j_{K+1} |J1(j_m)|): the inverse
//               transform (Fourier-Bessel series on [0, R]) evaluated on the uniform grid r_j = j dr,
//               dr = pitch / render_oversample, j = 0..J-1, J reaching past the native grid's corner
//   intensity I_j = |u(r_j)|²
//   render    the 2-D path samples |U2|² at DOE pixel centres and area-integrates onto the sensor pitch.
//               Here: I at the centre radius sqrt(di² + dj²) pitch of every native pixel by 4-point Lagrange
//               (cubic) interpolation (I is even in r: I(-dr) = I(dr)), then the identical AreaWeights, then
//               normalisation per band (the 2-D path's first, native normalisation cancels in the second).
//               On the device the native grid never exists: interpolation + area weights form one sparse
//               matrix onto the distinct sensor values (sensor pixels whose per-axis tap sets agree up to
//               sign and axis swap are equal: about S²/8 classes), applied per band, then expanded.
// The residual against the 2-D path is the 2-D path's own discretisation: its pixel samples of the
// staircase alias the staircase's higher diffraction orders back into the sensor (the continuous model
// sends them beyond 1 / pitch), and the square-pixel aperture/ring edges; see tests/test_radial.cpp.
//
// Sampling rules (defaults chosen by measurement against the 2-D path, the "[measure]" cases of
// tests/test_radial.cpp, paper physics scaled to N = 128 / 256):
//   R = window_factor * M * pitch / 2 (M the 2-D path's padded window: the same propagation area;
//   factors 1.5 and 2 agreed worse), K = ceil(node_oversample * R / pitch) frequencies, band limit
//   ~ node_oversample / (2 pitch): at 1 (default) the 2-D grid's per-axis Nyquist. 1.5-2 bring a focused
//   lens's PSF closer to the 2-D path (6.8 % instead of 9 % relative L2 at N = 256) but, where the
//   Fresnel chirp is under-sampled (the paper's padding), add spectrum the 2-D path aliases differently:
//   gradient directions then agree worse (cosine to the 2-D gradient 0.69-0.99 instead of 0.94-0.998).
//   Output step pitch / render_oversample: 2 and 4 agree to 1e-3 in the PSF; default 2.
#pragma once
#include <CL/opencl.hpp>

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/psf_source.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

// The K x K quasi-discrete Hankel transform matrix T_mn = 2 J0(j_m j_n / S) / (S |J1(j_m)| |J1(j_n)|),
// S = j_{K+1} (symmetric, T T = I to ~1e-9): for tests of the transform the engine is built on.
std::vector<double> qdht_matrix(std::size_t k);

// Bessel functions of the first kind (double, std::cyl_bessel_j with a sign-correct J1 for x < 0).
double bessel_j0(double x);
double bessel_j1(double x);
// The first `count` positive zeros of J0, ascending (McMahon's asymptotic start, Newton on J0 with
// J0' = -J1, converged to a few ulps).
std::vector<double> bessel_j0_zeros(std::size_t count);

struct RadialOptions {
  double window_factor = 1.0;      // R = window_factor * M * pitch / 2; allowed [0.5, 4]
  double node_oversample = 1.0;    // K = ceil(node_oversample * R / pitch); allowed [0.5, 8]
  double render_oversample = 2.0;  // output radial step pitch / render_oversample; allowed [1, 32]
  void validate() const;           // InputError naming the field
};

// Every constant table of one (configuration, options), in double. Shapes in the comments.
struct RadialTables {
  std::size_t n = 0, rings = 0, bands = 0, k = 0, j = 0, s = 0;  // N, N/2, bands, frequencies, output samples, S
  double window_m = 0, pitch_m = 0, dr_m = 0;                     // R, DOE pitch, output step
  std::vector<double> rho_per_m;                                  // K
  std::vector<double> inv_j1;                                     // K: 1 / |J1(j_m)|
  std::vector<double> kdn_per_m;                                  // bands: k_b (n_b - 1)
  std::vector<double> q;                                          // K x N/2 row-major: ring -> spectrum
  std::vector<double> b;                                          // J x K row-major: spectrum -> field
  std::vector<cdouble> source;                                    // bands x N/2: exp(i k_b src(r_mid)), 0 outside
  std::vector<cdouble> tf;                                        // bands x K: transfer function at rho_m
  AreaWeights weights;                                            // N -> S per axis (as the 2-D path)
  // Sensor classes: per-axis class of each sensor index, members of each class (CSR), class
  // pairs (cy <= cx) -> unique values u = cx (cx + 1) / 2 + cy, their multiplicity.
  std::size_t classes = 0, unique = 0;
  std::vector<int> class_of;                                      // S
  std::vector<int> class_start, class_members;                    // classes + 1, S
  std::vector<int> pair_y, pair_x;                                // unique
  std::vector<double> multiplicity;                               // unique
  // Render matrix A (unique x J, CSR) and its transpose (J x unique, CSR), in double.
  std::vector<int> a_start, a_col;
  std::vector<double> a_val;
  std::vector<int> at_start, at_col;
  std::vector<double> at_val;

  // Validates cfg and opt (InputError) and builds everything (O(K N/2 + J K) Bessel evaluations:
  // ~3 s on 2 cores at N = 1024).
  static RadialTables build(const SystemConfig& cfg, const RadialOptions& opt);
  // The same, shared: one table set per (configuration, options) while any holder keeps it alive
  // (process-wide, thread-safe), so Designers and engines re-created for a configuration reuse it.
  static std::shared_ptr<const RadialTables> cached(const SystemConfig& cfg, const RadialOptions& opt);
};

// Per-ring heights (N/2 values, metres) of a radial height map: the value at pixel (N/2, N/2 + k),
// which expand_parameters(Radial, ...) and any per-pixel map of a ring-constant map share.
std::vector<double> ring_heights_of_map(const Map2D& h);
// Gradient on the N x N map that spreads g_ring[k] evenly over the pixels of ring k (as
// expand_parameters assigns them), so ref::expand_parameters_vjp of it gives back g_ring
// (and the per-pixel quantizer adjoints of a ring-constant map act per ring).
Map2D spread_ring_gradient(const std::vector<double>& g_ring, std::size_t n);

// The OpenCL engine. One per (configuration, precision, options); tables built once and kept on the
// device. Buffers persist between calls; forward then adjoint reuse the forward state. A PsfSource
// (psf_source.hpp) whose parameters are the N/2 ring heights (metres, from the centre out).
// The configuration the radial path computes for cfg: cfg itself without object points; with one
// on-axis object point, point_config(cfg, 0) (that point's distance as scene_distance_m); an
// InputError naming object_points for off-axis points or several points (the 2-D path's).
SystemConfig radial_config(const SystemConfig& cfg);

class RadialEngine final : public PsfSource {
 public:
  // cfg passes through radial_config (one on-axis object point at any distance is served).
  RadialEngine(Runtime& rt, const SystemConfig& cfg, Precision p, const RadialOptions& opt = {});
  ~RadialEngine();
  RadialEngine(const RadialEngine&) = delete;
  RadialEngine& operator=(const RadialEngine&) = delete;

  const RadialTables& tables() const { return *tab_; }
  Runtime& runtime() const override { return rt_; }
  const SystemConfig& config() const override { return cfg_; }
  Precision precision() const override { return prec_; }
  std::size_t sensor_size() const override { return tab_->s; }
  std::size_t psf_planes() const override { return cfg_.bands; }
  bool psf_ready() const override { return valid_; }
  std::uint64_t psf_generation() const override { return generation_; }
  std::size_t parameter_count() const override { return cfg_.n / 2; }
  std::vector<double> parameter_vjp(const cl::Buffer& g_psf_sensor) override { return psf_sensor_vjp(g_psf_sensor); }
  std::string describe() const override;

  // Forward: ring heights (N/2 values, metres; finite, within [0, 2 h_max], else InputError) ->
  // sensor PSF stack (bands x S x S, each band sums to 1), on the device.
  void compute_psf(const std::vector<double>& ring_heights_m);
  RealStack psf_sensor() const override;      // host copy, bands x S x S
  std::vector<double> intensity() const;      // host copy of I, bands x J (tests)
  // Adjoint at the last compute_psf(): dL/dpsf_sensor (bands x S x S) -> dL/dh_ring (N/2, per metre).
  std::vector<double> psf_sensor_vjp(const RealStack& g_psf_sensor);
  // Device forms: the buffer behind psf_sensor() (bands x S x S reals of precision(), row-major,
  // valid after compute_psf()), and the adjoint from a gradient in that layout on the device (read,
  // not modified; the same numbers as the host form for the same values).
  const cl::Buffer& psf_sensor_buffer() const override;
  std::vector<double> psf_sensor_vjp(const cl::Buffer& g_psf_sensor);
  // Seconds of the last compute_psf / psf_sensor_vjp (device work included, queue finished).
  double last_forward_seconds() const { return t_fwd_; }
  double last_adjoint_seconds() const { return t_adj_; }

 private:
  struct Impl;
  std::vector<double> vjp_from(const cl::Buffer& g_s, std::chrono::steady_clock::time_point t0);
  Runtime& rt_;
  SystemConfig cfg_;
  Precision prec_;
  std::shared_ptr<const RadialTables> tab_;
  std::unique_ptr<Impl> impl_;
  bool valid_ = false;
  std::uint64_t generation_ = 0;  // incremented by every compute_psf()
  double t_fwd_ = 0, t_adj_ = 0;
};

namespace ref {

// The radial chain in double on the CPU, stage by stage (tables from RadialTables::build).
// Field vectors are bands x N/2, bands x K or bands x J complex, row-major.
struct RadialState {
  std::vector<cdouble> c;     // bands x N/2: source x exp(i kdn h) per ring
  std::vector<cdouble> g;     // bands x K: Q c (spectrum, before the transfer function)
  std::vector<cdouble> u2;    // bands x J: B (TF g), field on the output grid
  std::vector<double> i;      // bands x J: |u2|²
};
RadialState radial_forward(const RadialTables& t, const std::vector<double>& ring_heights_m);
// Linear pieces and their transposes (for dot-product tests). x: bands x K / bands x J.
std::vector<cdouble> radial_spectrum(const RadialTables& t, const std::vector<cdouble>& c);          // Q c (N/2 -> K)
std::vector<cdouble> radial_spectrum_adjoint(const RadialTables& t, const std::vector<cdouble>& g);  // Q^T g (K -> N/2)
std::vector<cdouble> radial_output(const RadialTables& t, const std::vector<cdouble>& x);            // B x (K -> J)
std::vector<cdouble> radial_output_adjoint(const RadialTables& t, const std::vector<cdouble>& y);    // B^T y (J -> K)
// Native rendering: I (bands x J) -> bands x N x N, I at every pixel-centre radius (not normalised).
RealStack radial_render_native(const RadialTables& t, const std::vector<double>& i);
RealStack radial_render_native_adjoint(const RadialTables& t, const RealStack& g);   // bands x N x N -> bands x J
// Native PSF (bands x N x N, each band normalised) and the sensor PSF (bands x S x S): render,
// ref::resample_area with the 2-D path's weights, normalise.
RealStack radial_psf_native(const RadialTables& t, const std::vector<double>& ring_heights_m);
RealStack radial_psf_sensor(const RadialTables& t, const std::vector<double>& ring_heights_m);
// dL/dh_ring (N/2) for dL/dpsf_sensor (bands x S x S), by the adjoint of every stage above.
std::vector<double> radial_psf_sensor_vjp(const RadialTables& t, const std::vector<double>& ring_heights_m,
                                          const RealStack& g_psf_sensor);

}  // namespace ref
// 4-point Lagrange interpolation on a uniform grid of step dr_m (index j at j * dr_m) for an even
// function (index -1 mirrors to 1): the 4 (index, weight) pairs for radius r_m. Shared by the
// tables (rendering onto the sensor grid) and the CPU reference.
void radial_lagrange4(double r_m, double dr_m, int idx[4], double w[4]);

}  // namespace qdo
