// The adjoint suite. One table (tests/adjoint_table.hpp) holds every forward/adjoint pair of the PSF
// chain, the camera references, the parameterizations and the quantizer, the radial engine, the
// encoders and the design loop, one Stage row each, and one test body (tests/adjoint_ladder.hpp)
// runs it: a dot-product test, a directional finite difference, central differences on probed
// parameters, in double. Then the checks the ladder has no rung for: the OpenCL adjoints against
// the CPU reference adjoints, the transposed area weights, the quantizer's blend and STE. This file
// builds the rows of the PSF chain, the camera references and the DOE.
#include <cmath>
#include <memory>
#include <random>
#include <set>
#include <string>

#include "adjoint_table.hpp"
#include "common.hpp"
#include "qdo/physics/adjoint.hpp"
#include "qdo/physics/cpu_reference.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/physics/simulator.hpp"

using namespace qdo;
using namespace qdo::test;

namespace {

Map2D random_map(std::size_t n, unsigned seed, double scale) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> u(0, scale);
  Map2D m(n, n);
  for (auto& v : m.data) v = u(rng);
  return m;
}
constexpr double kDotTol = 1e-11;  // relative, double precision with O(M² log M) operations

RealStack as_stack(const std::vector<double>& x, std::size_t p, std::size_t r, std::size_t c) {
  RealStack s(p, r, c);
  s.data = x;
  return s;
}
Map2D as_map(const std::vector<double>& x, std::size_t n) {
  Map2D m(n, n);
  m.data = x;
  return m;
}
// planes x m x m complex field from interleaved reals.
ComplexStack as_field(const std::vector<double>& x, std::size_t planes, std::size_t m) {
  ComplexStack f(planes, m, m);
  f.data = deinterleave(x);
  return f;
}

// Twelve heights inside the aperture (row-major indices i N + j), drawn with `seed`.
std::vector<std::size_t> aperture_probes(const SystemConfig& c, unsigned seed) {
  std::mt19937_64 rng(seed);
  std::vector<std::size_t> out;
  while (out.size() < 12) {
    const std::size_t i = rng() % c.n, j = rng() % c.n;
    const double y = (double(i) - double(c.n / 2)) * c.pitch_m, x = (double(j) - double(c.n / 2)) * c.pitch_m;
    if (x * x + y * y > c.aperture_radius() * c.aperture_radius()) continue;
    out.push_back(i * c.n + j);
  }
  return out;
}

// Finite-difference settings of a stage whose input is the height map (metres): rung 2 along
// x +- 1e-12 m d for a unit-scale d (phase steps ~1e-5 rad), within 1e-6 of the adjoint; rung 3 at
// twelve heights inside the aperture, +- 1e-11 m, within 1e-5 of the entry plus 1e-6 of the
// gradient's RMS.
void height_fd(Stage& st, const SystemConfig& c) {
  st.fd_tol = 0;
  st.dir_step = 1e-12;
  st.dir_rel = 1e-6;
  st.probes = aperture_probes(c, 7);
  st.probe_step = 1e-11;
  st.probe_rel = 1e-5;
  st.probe_rms = 1e-6;
}

// Heights -> sensor PSF through the CPU reference chain (jvp and vjp of adjoint.hpp).
Stage chain_row(const std::string& name, const SystemConfig& c) {
  const std::size_t s = c.sensor_size_px();
  Stage st(name, c.n * c.n, c.bands * s * s);
  st.forward = [c](const std::vector<double>& x) { return ref::psf_sensor_stack(c, as_map(x, c.n)).data; };
  st.vjp = [c, s](const std::vector<double>& x, const std::vector<double>& g) {
    return ref::psf_sensor_vjp(c, as_map(x, c.n), as_stack(g, c.bands, s, s)).data;
  };
  st.jvp = [c](const std::vector<double>& x, const std::vector<double>& d) {
    return ref::psf_sensor_jvp(c, as_map(x, c.n), as_map(d, c.n)).data;
  };
  st.dot_tol = 0;
  st.dot_rel = 1e-9;
  height_fd(st, c);
  return st;
}

}  // namespace

QDO_ADJOINT_ROWS(psf_chain, "PSF chain") {
  std::vector<Stage> rows;
  {  // The DOE phase (field stage): heights -> the field after the DOE, complex as interleaved reals.
    const SystemConfig c = tiny_config(32, 3);
    const auto geo = PropagationGeometry::from_config(c);
    Stage st("DOE phase: heights -> field (reference)", c.n * c.n, 2 * c.bands * geo.m * geo.m);
    st.forward = [c, geo](const std::vector<double>& x) { return interleave(ref::doe_field(c, as_map(x, c.n), geo).data); };
    st.vjp = [c, geo](const std::vector<double>& x, const std::vector<double>& g) {
      return ref::doe_phase_vjp(c, geo, ref::doe_field(c, as_map(x, c.n), geo), as_field(g, c.bands, geo.m)).data;
    };
    st.jvp = [c, geo](const std::vector<double>& x, const std::vector<double>& d) {
      return interleave(ref::doe_phase_jvp(c, geo, ref::doe_field(c, as_map(x, c.n), geo), as_map(d, c.n)).data);
    };
    st.x0 = smooth_heights(c, 41).data;
    st.d0 = random_map(c.n, 42, 1.0).data;
    st.dot_tol = 0;
    st.dot_rel = kDotTol;
    height_fd(st, c);
    rows.push_back(st);
  }
  SystemConfig c = tiny_config(32, 3);
  c.sensor_pitch_m = 10e-6;
  for (Propagator p : {Propagator::Fresnel, Propagator::AngularSpectrum}) {  // linear: forward over z, adjoint over -z
    const std::size_t m = 48;
    ComplexStack x(3, m, m), y(3, m, m);
    std::mt19937_64 rng(5);
    std::normal_distribution<double> nd;
    for (auto& v : x.data) v = cdouble(nd(rng), nd(rng));
    for (auto& v : y.data) v = cdouble(nd(rng), nd(rng));
    Stage st(std::string("propagation, ") + (p == Propagator::Fresnel ? "Fresnel" : "angular spectrum") + " (reference)",
             2 * x.size(), 2 * y.size());
    const std::vector<double> wl = c.wavelengths_nm();
    const double pitch = c.pitch_m, z = c.sensor_distance_m;
    st.forward = [wl, pitch, z, p, m](const std::vector<double>& v) {
      ComplexStack f = as_field(v, 3, m);
      ref::propagate(f, wl, pitch, z, p);
      return interleave(f.data);
    };
    st.vjp = [wl, pitch, z, p, m](const std::vector<double>&, const std::vector<double>& g) {
      ComplexStack f = as_field(g, 3, m);
      ref::propagate(f, wl, pitch, -z, p);
      return interleave(f.data);
    };
    st.jvp = [f = st.forward](const std::vector<double>&, const std::vector<double>& d) { return f(d); };
    st.d0 = interleave(x.data);
    st.g0 = interleave(y.data);
    st.dot_tol = 0;
    st.dot_rel = kDotTol;
    rows.push_back(st);
  }
  {  // Area resampling (linear; pitch ratio 2.5: fractional weights).
    const AreaWeights w = AreaWeights::make(c.n, c.pitch_m, c.sensor_size_px(), c.sensor_pitch_m);
    Stage st("area resampling, pitch ratio 2.5 (reference)", 3 * c.n * c.n, 3 * w.s * w.s);
    st.forward = [w](const std::vector<double>& x) { return ref::resample_area(as_stack(x, 3, w.n, w.n), w).data; };
    st.vjp = [w](const std::vector<double>&, const std::vector<double>& g) {
      return ref::resample_area_adjoint(as_stack(g, 3, w.s, w.s), w).data;
    };
    st.jvp = [f = st.forward](const std::vector<double>&, const std::vector<double>& d) { return f(d); };
    st.d0 = uniform_stack(3, c.n, c.n, 6).data;
    st.g0 = uniform_stack(3, w.s, w.s, 7).data;
    st.dot_tol = 0;
    st.dot_rel = kDotTol;
    rows.push_back(st);
  }
  {  // Normalisation (a nonlinear stage: its JVP and VJP at a point of positive planes).
    const auto normalised = [](const std::vector<double>& x, std::vector<double>& sums) {
      RealStack y = as_stack(x, 3, 8, 8);
      sums.clear();
      for (std::size_t b = 0; b < 3; ++b) {
        double s = 0;
        for (std::size_t i = 0; i < 64; ++i) s += y.plane(b)[i];
        sums.push_back(s);
      }
      ref::normalize_planes(y);
      return y;
    };
    Stage st("per-plane normalisation (reference)", 3 * 64, 3 * 64);
    st.forward = [normalised](const std::vector<double>& x) {
      std::vector<double> sums;
      return normalised(x, sums).data;
    };
    st.vjp = [normalised](const std::vector<double>& x, const std::vector<double>& g) {
      std::vector<double> sums;
      const RealStack y = normalised(x, sums);
      return ref::normalize_vjp(as_stack(g, 3, 8, 8), y, sums).data;
    };
    st.jvp = [normalised](const std::vector<double>& x, const std::vector<double>& d) {
      std::vector<double> sums;
      const RealStack y = normalised(x, sums);
      return ref::normalize_jvp(as_stack(d, 3, 8, 8), y, sums).data;
    };
    st.x0 = uniform_stack(3, 8, 8, 8, 0.1, 1.0).data;
    st.d0 = uniform_stack(3, 8, 8, 9).data;
    st.g0 = uniform_stack(3, 8, 8, 10).data;
    st.dot_tol = 0;
    st.dot_rel = kDotTol;
    rows.push_back(st);
  }
  {  // The whole chain H -> sensor PSF, pitch ratio 2.5 (d in metres of size 1e-8: rung 2 steps 1e-4 d).
    Stage st = chain_row("heights -> sensor PSF, pitch ratio 2.5 (reference)", c);
    st.x0 = smooth_heights(c, 1).data;
    st.d0 = random_map(c.n, 2, 1e-8).data;
    st.g0 = uniform_stack(c.bands, c.sensor_size_px(), c.sensor_size_px(), 3).data;
    st.dir_step = 1e-4;
    rows.push_back(st);
  }
  {  // The whole chain at the default sensor pitch.
    const SystemConfig c1 = tiny_config(32, 3);
    Stage st = chain_row("heights -> sensor PSF (reference)", c1);
    st.x0 = smooth_heights(c1, 4).data;
    st.d0 = random_map(c1.n, 6, 1.0).data;
    st.g0 = uniform_stack(c1.bands, c1.sensor_size_px(), c1.sensor_size_px(), 5).data;
    rows.push_back(st);
  }
  {  // Heights -> native PSF (bands x N x N on the DOE grid): psf_native_vjp.
    const SystemConfig c1 = tiny_config(32, 3);
    Stage st("heights -> native PSF (reference)", c1.n * c1.n, c1.bands * c1.n * c1.n);
    st.forward = [c1](const std::vector<double>& x) { return ref::psf_stack(c1, as_map(x, c1.n)).psf.data; };
    st.vjp = [c1](const std::vector<double>& x, const std::vector<double>& g) {
      return ref::psf_native_vjp(c1, as_map(x, c1.n), as_stack(g, c1.bands, c1.n, c1.n)).data;
    };
    st.x0 = smooth_heights(c1, 8).data;
    st.d0 = random_map(c1.n, 9, 1.0).data;
    height_fd(st, c1);
    rows.push_back(st);
  }
  return rows;
}

QDO_ADJOINT_ROWS(camera, "camera") {
  std::vector<Stage> rows;
  const SystemConfig c = tiny_config(32, 3);
  const std::size_t s = c.sensor_size_px();
  for (ConvolutionMode mode : {ConvolutionMode::Linear, ConvolutionMode::Circular}) {  // linear in the PSF
    const RealStack cube = uniform_stack(c.bands, 12, 15, 21, 0, 1), psf = uniform_stack(c.bands, s, s, 22, 0, 1);
    const RealStack g = uniform_stack(c.bands, 12, 15, 23);
    Stage st(std::string("convolution, PSF -> blurred cube, ") + (mode == ConvolutionMode::Linear ? "linear" : "circular") +
                 " (reference)",
             psf.size(), cube.size());
    const std::size_t bands = c.bands;
    st.forward = [cube, mode, bands, s](const std::vector<double>& x) { return ref::convolve(cube, as_stack(x, bands, s, s), mode).data; };
    st.vjp = [cube, mode, s](const std::vector<double>&, const std::vector<double>& gv) {
      return ref::convolve_vjp_psf(cube, as_stack(gv, cube.planes, cube.rows, cube.cols), s, mode).data;
    };
    st.jvp = [f = st.forward](const std::vector<double>&, const std::vector<double>& d) { return f(d); };
    st.d0 = psf.data;
    st.g0 = g.data;
    st.dot_tol = 0;
    st.dot_rel = kDotTol;
    rows.push_back(st);
  }
  {  // Sensor integration (linear): srf^T g.
    const Eigen::MatrixXd srf = sensor_response(c);
    const RealStack x = uniform_stack(c.bands, 5, 6, 24), gr = uniform_stack(3, 5, 6, 25);
    Stage st("sensor integration (reference)", x.size(), gr.size());
    const std::size_t bands = c.bands;
    st.forward = [srf, bands](const std::vector<double>& v) { return ref::sensor_integrate(as_stack(v, bands, 5, 6), srf).data; };
    st.vjp = [srf](const std::vector<double>&, const std::vector<double>& g) {
      return ref::sensor_integrate_vjp(as_stack(g, 3, 5, 6), srf).data;
    };
    st.jvp = [f = st.forward](const std::vector<double>&, const std::vector<double>& d) { return f(d); };
    st.d0 = x.data;
    st.g0 = gr.data;
    st.dot_tol = 0;
    st.dot_rel = 1e-12;
    rows.push_back(st);
  }
  // End to end on the device in float64: L(H) = sum_k <g_k, sensor_image_k(H)>, gradient through
  // every stage (PSF, convolution, sensor; the additive read noise has no effect on gradients).
  if (skip_unless(runtime().has_fp64(), "float64 cases: the device has no float64")) {
    SystemConfig cm = c;
    cm.convolution = ConvolutionMode::Linear;
    cm.read_noise_sigma = 0.01;  // additive: no effect on gradients
    auto sim = std::make_shared<Simulator>(runtime(), cm, Precision::F64);
    auto cam = std::make_shared<Camera>(*sim);  // follows sim's PSF
    const std::vector<RealStack> cubes = {uniform_stack(cm.bands, 20, 18, 27, 0, 1), uniform_stack(cm.bands, 20, 18, 28, 0, 1)};
    const std::vector<RealStack> g = {uniform_stack(3, 20, 18, 29), uniform_stack(3, 20, 18, 30)};
    const std::size_t n = cm.n, per = 3 * 20 * 18;
    Stage st("heights -> sensor images of two scenes, linear (device float64)", n * n, 2 * per);
    st.forward = [sim, cam, cubes, n](const std::vector<double>& x) {
      sim->set_heights(as_map(x, n));
      sim->compute_psf();
      const auto imgs = cam->images(cubes, no_skipping());
      std::vector<double> out = imgs[0].data;
      out.insert(out.end(), imgs[1].data.begin(), imgs[1].data.end());
      return out;
    };
    st.vjp = [sim, cam, cubes, n, per](const std::vector<double>& x, const std::vector<double>& gv) {
      sim->set_heights(as_map(x, n));
      sim->compute_psf();
      cam->images(cubes, no_skipping());
      const std::vector<RealStack> gk = {as_stack({gv.begin(), gv.begin() + long(per)}, 3, 20, 18),
                                         as_stack({gv.begin() + long(per), gv.end()}, 3, 20, 18)};
      return sim->psf_sensor_vjp(cam->vjp(gk, false).psf).data;
    };
    st.x0 = smooth_heights(cm, 26).data;
    st.g0 = g[0].data;
    st.g0.insert(st.g0.end(), g[1].data.begin(), g[1].data.end());
    st.d0 = random_map(n, 31, 1.0).data;
    height_fd(st, cm);
    st.probes = {16 * n + 16, 12 * n + 20, 20 * n + 9};
    st.probe_rms = 1e-7;
    rows.push_back(st);
  }
  return rows;
}

QDO_ADJOINT_ROWS(doe, "DOE") {
  std::vector<Stage> rows;
  const std::size_t n = 16;
  const double hmax = 1.5e-6;
  for (Parameterization p : {Parameterization::Full2D, Parameterization::Radial, Parameterization::Quad}) {
    // Expansion is linear inside the clamp: <E dp, g> = <dp, E^T g> (E dp with the clamp off).
    std::vector<double> params(parameter_count(p, n));
    std::mt19937_64 rng(3);
    std::uniform_real_distribution<double> u(0.1 * hmax, 0.9 * hmax);
    for (double& v : params) v = u(rng);
    std::vector<double> dp(params.size());
    for (double& v : dp) v = u(rng);
    Stage st(std::string("parameter expansion, ") + (p == Parameterization::Full2D ? "full 2-D" : p == Parameterization::Radial ? "radial" : "quad"),
             params.size(), n * n);
    st.forward = [p, n, hmax](const std::vector<double>& x) { return expand_parameters(p, x, n, hmax).data; };
    st.vjp = [p, n, hmax](const std::vector<double>& x, const std::vector<double>& g) {
      return ref::expand_parameters_vjp(p, x, n, hmax, as_map(g, n));
    };
    st.jvp = [p, n](const std::vector<double>&, const std::vector<double>& d) { return expand_parameters(p, d, n, 1e9).data; };
    st.x0 = params;
    st.d0 = dp;
    st.g0 = random_map(n, 8, 1.0).data;
    st.dot_tol = 0;
    st.dot_rel = 1e-12;
    st.dir_step = 0.01;    // x +- 0.01 d stays inside (0, h_max)
    st.probe_step = 1e-9;  // metres
    rows.push_back(st);
  }
  {  // Quantizer: the adaptive offsets a_1..a_3 (a_0 is fixed at 0) -> blended heights; each
     // offset moves its level by alpha h_max 0.5 / denom. Within 1e-8 (1 + min(|FD|, |adjoint|)).
    Quantizer q;
    q.levels = 4;
    q.offsets = {0.0, 0.2, -0.3, 0.1};
    const Map2D hf = random_heights(n, hmax, 9);
    const double alpha = 0.7;
    const auto with = [q](const std::vector<double>& a) {
      Quantizer qa = q;
      qa.offsets = {0.0, a[0], a[1], a[2]};
      return qa;
    };
    Stage st("quantizer offsets a_1..a_3 -> heights (alpha 0.7)", 3, n * n);
    st.forward = [hf, hmax, alpha, with](const std::vector<double>& x) { return quantize_heights(hf, hmax, with(x), alpha).data; };
    st.vjp = [hf, hmax, alpha, with, n](const std::vector<double>& x, const std::vector<double>& g) {
      const auto v = ref::quantize_vjp(hf, hmax, with(x), alpha, as_map(g, n));
      return std::vector<double>(v.g_offsets.begin() + 1, v.g_offsets.end());
    };
    st.x0 = {0.2, -0.3, 0.1};
    st.g0 = random_map(n, 10, 1.0).data;
    st.fd_tol = 0;
    st.fd_step = 1e-4;
    st.dir_rel = st.probe_rel = 1e-8;
    st.dir_abs = st.probe_abs = 1e-8;
    st.probes = {0, 1, 2};
    rows.push_back(st);
  }
  return rows;
}

TEST_SUITE("adjoint") {
  TEST_CASE("the adjoint table: every forward/adjoint pair through the ladder (dot product, directional and central differences)") {
    // Every group the test files registered (QDO_ADJOINT_ROWS), each once, each with rows. A
    // group's seeds come from its title (FNV-1a), not from its place in the registry.
    const std::vector<AdjointGroup>& groups = adjoint_groups();
    REQUIRE(!groups.empty());
    std::set<std::string> titles;
    for (const AdjointGroup& gr : groups) {
      INFO("group: " << gr.title);
      CHECK(titles.insert(gr.title).second);
      std::uint64_t h = 1469598103934665603ull;
      for (const char ch : gr.title) h = (h ^ std::uint64_t(static_cast<unsigned char>(ch))) * 1099511628211ull;
      std::uint64_t seed = 1000 * (1 + h % 100000);
      const std::vector<Stage> rows = gr.rows();
      CHECK(!rows.empty());
      for (const Stage& st : rows) check_ladder(st, seed += 10);
    }
  }

  TEST_CASE("area resampling: the transposed weights give the adjoint") {
    SystemConfig c = tiny_config(32, 3);
    c.sensor_pitch_m = 10e-6;
    const AreaWeights w = AreaWeights::make(c.n, c.pitch_m, c.sensor_size_px(), c.sensor_pitch_m);
    const RealStack y = uniform_stack(3, w.s, w.s, 7);
    // The transposed weights describe the same operator.
    const AreaWeights wt = w.transposed();
    CHECK(diff(ref::resample_area(y, wt).data, ref::resample_area_adjoint(y, w).data).max_abs <= 1e-14);
  }

  TEST_CASE("the quantizer's adjoint passes (1 - alpha) of the gradient to H_f, all of it with STE") {
    const std::size_t n = 16;
    const double hmax = 1.5e-6;
    Quantizer q;
    q.levels = 4;
    q.offsets = {0.0, 0.2, -0.3, 0.1};
    const Map2D hf = random_heights(n, hmax, 9);
    const Map2D g = random_map(n, 10, 1.0);
    const double alpha = 0.7;
    const auto vjp = ref::quantize_vjp(hf, hmax, q, alpha, g);
    for (std::size_t i = 0; i < hf.data.size(); ++i) CHECK(vjp.g_full.data[i] == doctest::Approx(0.3 * g.data[i]));
    CHECK(ref::quantize_vjp(hf, hmax, q, alpha, g, true).g_full.data[5] == g.data[5]);
  }

  TEST_CASE("the OpenCL adjoint matches the CPU reference adjoint") {
    for (Precision p : {Precision::F32, Precision::F64}) {
      if (p == Precision::F64 && !skip_unless(runtime().has_fp64(), "float64 cases: the device has no float64")) continue;
      CAPTURE(to_string(p));
      SystemConfig c = tiny_config(48, 4);
      c.sensor_pitch_m = 10e-6;
      const Map2D h = smooth_heights(c, 11);
      Simulator sim(runtime(), c, p);
      sim.set_heights(h);
      sim.compute_psf();
      const RealStack gs = uniform_stack(c.bands, sim.sensor_size(), sim.sensor_size(), 12);
      const Map2D got = sim.psf_sensor_vjp(gs);
      const Map2D want = ref::psf_sensor_vjp(c, h, gs);
      const auto d = diff(got.data, want.data);
      // The gradient sums bands x M² terms of both signs: relative L2 within 2e3 eps (f32: 2.4e-4).
      CAPTURE(d.rel_l2);
      CHECK(d.rel_l2 <= 2e3 * eps(p));
      const RealStack gn = uniform_stack(c.bands, c.n, c.n, 13);
      const auto dn = diff(sim.psf_native_vjp(gn).data, ref::psf_native_vjp(c, h, gn).data);
      CAPTURE(dn.rel_l2);
      CHECK(dn.rel_l2 <= 2e3 * eps(p));
    }
  }

  TEST_CASE("convolution and sensor adjoints: OpenCL vs CPU (float32, float64; linear, circular)") {
    SystemConfig c = tiny_config(32, 3);
    const std::size_t s = c.sensor_size_px();
    for (Precision p : {Precision::F32, Precision::F64}) {
      if (p == Precision::F64 && !skip_unless(runtime().has_fp64(), "float64 cases: the device has no float64")) continue;
      for (ConvolutionMode mode : {ConvolutionMode::Linear, ConvolutionMode::Circular}) {
        CAPTURE(to_string(p));
        CAPTURE(int(mode));
        SystemConfig cm = c;
        cm.convolution = mode;
        cm.read_noise_sigma = 0.01;  // additive: no effect on gradients
        Simulator sim(runtime(), cm, p);
        const Map2D h = smooth_heights(cm, 26);
        sim.set_heights(h);
        sim.compute_psf();
        const std::vector<RealStack> cubes = {uniform_stack(cm.bands, 20, 18, 27, 0, 1), uniform_stack(cm.bands, 20, 18, 28, 0, 1)};
        Camera cam(sim);
        cam.images(cubes, no_skipping());
        const std::vector<RealStack> g = {uniform_stack(3, 20, 18, 29), uniform_stack(3, 20, 18, 30)};
        const RealStack got = cam.vjp(g, false).psf;
        RealStack want(cm.bands, s, s);
        for (std::size_t k = 0; k < 2; ++k) {
          const RealStack part = ref::convolve_vjp_psf(cubes[k], ref::sensor_integrate_vjp(g[k], sim.srf()), s, mode);
          for (std::size_t i = 0; i < want.size(); ++i) want.data[i] += part.data[i];
        }
        const auto d = diff(got.data, want.data);
        CAPTURE(d.rel_l2);
        CHECK(d.rel_l2 <= 1e3 * eps(p));
      }
    }
  }
}
