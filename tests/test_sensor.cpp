#include <cmath>
#include <fstream>

#include "common.hpp"
#include "qdo/physics/cpu_reference.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/rng.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/simulator.hpp"

using namespace qdo;
using namespace qdo::test;

TEST_SUITE("sensor") {
  TEST_CASE("sensor integration preserves a flat spectrum (CPU reference and kernel)") {
    SystemConfig c = preset_config("small");
    c.read_noise_sigma = 0;
    const Eigen::MatrixXd srf = sensor_response(c);
    CHECK(srf.rows() == 3);
    CHECK(srf.cols() == 31);
    RealStack cube(c.bands, 8, 8);
    for (std::size_t y = 0; y < 8; ++y)
      for (std::size_t x = 0; x < 8; ++x)
        for (std::size_t b = 0; b < c.bands; ++b) cube(b, y, x) = 0.1 * double(y * 8 + x) / 64.0 + 0.05;
    const RealStack rgb = ref::sensor_integrate(cube, srf);
    Simulator sim(runtime(), c, Precision::F32);
    const RealStack rgbk = sim.integrate(cube);
    for (std::size_t ch = 0; ch < 3; ++ch)
      for (std::size_t y = 0; y < 8; ++y)
        for (std::size_t x = 0; x < 8; ++x) {
          CHECK(rgb(ch, y, x) == doctest::Approx(cube(0, y, x)).epsilon(1e-12));
          CHECK(rgbk(ch, y, x) == doctest::Approx(cube(0, y, x)).epsilon(1e-6));
        }
  }

  TEST_CASE("noise: Gaussian and Poisson statistics, reproducible by seed") {
    RealStack zero(3, 64, 64, 0.0);
    RealStack a = zero;
    ref::add_noise(a, 0.01, 0, 7);
    double m = 0, v = 0;
    for (double x : a.data) m += x;
    m /= double(a.size());
    for (double x : a.data) v += (x - m) * (x - m);
    v /= double(a.size() - 1);
    CHECK(std::fabs(m) <= 4 * 0.01 / std::sqrt(double(a.size())));
    CHECK(std::sqrt(v) == doctest::Approx(0.01).epsilon(0.03));
    for (double mean_photons : {3.0, 30.0, 300.0}) {
      CAPTURE(mean_photons);
      RealStack s(3, 64, 64, 0.5);
      ref::add_noise(s, 0, 2 * mean_photons, 9);
      double sm = 0, sv = 0;
      for (double x : s.data) sm += x * 2 * mean_photons;
      sm /= double(s.size());
      for (double x : s.data) sv += (x * 2 * mean_photons - sm) * (x * 2 * mean_photons - sm);
      sv /= double(s.size() - 1);
      CHECK(sm == doctest::Approx(mean_photons).epsilon(0.02));
      CHECK(sv == doctest::Approx(mean_photons).epsilon(0.06));
      for (double x : s.data) CHECK(std::fabs(x * 2 * mean_photons - std::round(x * 2 * mean_photons)) < 1e-9);
    }
    RealStack b = zero, c2 = zero;
    ref::add_noise(b, 0.01, 0, 7);
    ref::add_noise(c2, 0.01, 0, 8);
    CHECK(b.data == a.data);
    CHECK(c2.data != a.data);
  }

  TEST_CASE("read noise alone: the values of the full draw, bit for bit, threaded or not") {
    // Below and above the size at which add_noise splits the pixels between two threads; with a
    // scene index so that the counters are offset as in a batch.
    for (std::size_t side : {std::size_t(17), std::size_t(160)}) {
      CAPTURE(side);
      RealStack got(3, side, side + 3, 0.25);
      const std::size_t hw = got.plane_size(), scene = 5;
      const unsigned long long seed = 0x1234abcd5678ull;
      ref::add_noise(got, 0.03, 0, seed, scene);
      std::size_t same = 0;
      for (std::size_t c = 0; c < 3; ++c)
        for (std::size_t p = 0; p < hw; ++p) {
          const double want = 0.25 + 0.03 * noise_draw(seed, (scene * hw + p) * 3 + c).gaussian;
          same += got.plane(c)[p] == want;
        }
      CHECK(same == got.size());
    }
  }

  TEST_CASE("an SRF on another band grid is rejected, naming the camera") {
    SystemConfig c = preset_config("small");
    c.wavelength_start_nm = 405;  // 405, 415, ... not in the 10 nm table
    c.bands = 30;
    CHECK_THROWS_WITH_AS(sensor_response(c), doctest::Contains("camera"), InputError);
    c.srf_interpolate = true;
    CHECK_NOTHROW(sensor_response(c));
    // A CSV camera table.
    const auto dir = temp_dir("srf");
    const auto path = (dir / "cam.csv").string();
    {
      std::ofstream f(path);
      f << "# test camera\nwavelength_nm,R,G,B\n400,1,0,0\n500,0,1,0\n600,0,0,1\n700,1,1,1\n";
    }
    SystemConfig d = preset_config("small");
    d.camera = path;
    CHECK_THROWS_WITH_AS(sensor_response(d), doctest::Contains("410"), InputError);
    d.srf_interpolate = true;
    const Eigen::MatrixXd s = sensor_response(d);
    CHECK(s.row(0).sum() == doctest::Approx(1.0));
    d.camera = "no_such_camera";
    CHECK_THROWS_WITH_AS(sensor_response(d), doctest::Contains("camera"), InputError);
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("sensor integration with noise matches the CPU reference") {
    for (Precision p : device_precisions(runtime())) {
      CAPTURE(to_string(p));
      SystemConfig c = tiny_config(32, 3);
      c.read_noise_sigma = 0.01;
      c.full_well_photons = 200;  // means from 0 to 200 photons: both Poisson branches
      c.noise_seed = 0x123456789ull;
      Simulator sim(runtime(), c, p);
      const RealStack cube = random_cube(c.bands, 16, 24, 16);
      const RealStack got = sim.integrate(cube);
      RealStack want = ref::sensor_integrate(cube, sim.srf());
      ref::add_noise(want, c.read_noise_sigma, c.full_well_photons, c.noise_seed);
      // Same counters give the same integer draws; in float32 a Poisson count may still land
      // one step off when the uniform sits within rounding of a CDF step: allow 1 % of pixels.
      std::size_t off = 0;
      for (std::size_t i = 0; i < got.size(); ++i)
        if (std::fabs(got.data[i] - want.data[i]) > 1e3 * eps(p)) ++off;
      CAPTURE(off);
      if (p == Precision::F64) CHECK(off == 0);
      else CHECK(double(off) <= 0.01 * double(got.size()));
    }
  }

}
