// The release's image formation (include/qdo/physics/release.hpp, kernels/release.cl): its geometry as the
// release computes it, the CPU reference against closed forms (a point PSF gives the half-pixel
// shift's 2 x 2 average with mirrored edges, a constant scene stays constant, TF's bilinear
// resize on hand-computed values), and the device path against the reference in float32 and
// float64 on seeded random inputs.
#include <cmath>
#include <random>

#include "common.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/physics/release.hpp"
#include "qdo/physics/release_reference.hpp"

using namespace qdo;
using namespace qdo::test;

namespace {

RealStack random_stack(std::size_t planes, std::size_t rows, std::size_t cols, unsigned seed, bool normalise) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  RealStack s(planes, rows, cols);
  for (double& v : s.data) v = u(rng);
  if (normalise)
    for (std::size_t b = 0; b < planes; ++b) {
      double sum = 0;
      for (std::size_t i = 0; i < s.plane_size(); ++i) sum += s.plane(b)[i];
      for (std::size_t i = 0; i < s.plane_size(); ++i) s.plane(b)[i] /= sum;
    }
  return s;
}

}  // namespace

TEST_SUITE("release") {
  TEST_CASE("geometry: the release's padding, psf2otf placement and shift; refusals") {
    const ReleaseGeometry p = release_geometry(512, 1024);  // the paper's patch and PSF
    CHECK(p.g == 1536);
    CHECK(p.before == 256);
    CHECK(p.after == 256);
    CHECK(p.psf_before == 257);
    CHECK(p.psf_after == 255);
    CHECK(p.split == 768);
    // The PSF's axis (N/2) lands one sample past the origin: (512 + 257 - 768) mod 1536 = 1.
    CHECK((p.n / 2 + p.psf_before + p.g - p.split) % p.g == 1);
    const ReleaseGeometry o = release_geometry(7, 16);  // odd N - S: ceil before, floor after
    CHECK(o.before == 5);
    CHECK(o.after == 4);
    CHECK(o.g == 25);
    CHECK(o.psf_before == 5);
    CHECK(o.psf_after == 4);
    CHECK(o.split == 12);
    CHECK_THROWS_WITH_AS(release_geometry(8, 9), doctest::Contains("PSF size N"), InputError);
    CHECK_THROWS_WITH_AS(release_geometry(0, 9), doctest::Contains("scene size S"), InputError);
  }

  TEST_CASE("bilinear resize: TF2's half-pixel centres and edge clamp, by hand") {
    RealStack x(1, 1, 2);
    x.data = {1.0, 5.0};
    const RealStack up = ref::resize_bilinear(x, 1, 4);  // t = -0.25, 0.25, 0.75, 1.25
    CHECK(up.data[0] == 1.0);                              // clamped
    CHECK(up.data[1] == doctest::Approx(0.75 * 1 + 0.25 * 5).epsilon(1e-15));
    CHECK(up.data[2] == doctest::Approx(0.25 * 1 + 0.75 * 5).epsilon(1e-15));
    CHECK(up.data[3] == 5.0);
    const RealStack down = ref::resize_bilinear(up, 1, 2);  // t = 0.5, 2.5: pair averages
    CHECK(down.data[0] == doctest::Approx((up.data[0] + up.data[1]) / 2).epsilon(1e-15));
    CHECK(down.data[1] == doctest::Approx((up.data[2] + up.data[3]) / 2).epsilon(1e-15));
  }

  TEST_CASE("reference closed forms: a point PSF shifts by half a sensor pixel; constants stay constant") {
    const std::size_t s = 8, n = 16, bands = 2;
    const RealStack cube = random_stack(bands, s, s, 5, false);
    RealStack point(bands, n, n, 0.0);
    for (std::size_t b = 0; b < bands; ++b) point(b, n / 2, n / 2) = 1.0;
    const RealStack got = ref::release_blur(cube, point);
    // Up, a one-sample shift on the DOE grid, down: out(i, j) = mean of x over rows {i-1, i} and
    // columns {j-1, j}, index -1 mirrored to 0 (the symmetric padding).
    double worst = 0;
    for (std::size_t b = 0; b < bands; ++b)
      for (std::size_t i = 0; i < s; ++i)
        for (std::size_t j = 0; j < s; ++j) {
          const std::size_t i0 = i ? i - 1 : 0, j0 = j ? j - 1 : 0;
          const double want = (cube(b, i0, j0) + cube(b, i0, j) + cube(b, i, j0) + cube(b, i, j)) / 4;
          worst = std::max(worst, std::fabs(got(b, i, j) - want));
        }
    CHECK(worst <= 1e-13);
    // A constant scene through any unit-sum PSF (wide, so light crosses the mirrored seam).
    RealStack flat(bands, s, s, 0.37);
    const RealStack blurred = ref::release_blur(flat, random_stack(bands, n, n, 9, true));
    for (double v : blurred.data) CHECK(v == doctest::Approx(0.37).epsilon(1e-12));
  }

  TEST_CASE("a release grid clFFT cannot plan is refused before any work, naming S and G; FFTW takes it") {
    // S = 9, N = 20: G = 2N - S = 31, a prime.
    Runtime cl(std::string(""), FftBackend::ClFFT);
    CHECK_THROWS_WITH_AS(ReleaseImager(cl, Precision::F32, 2, 9, 20), doctest::Contains("G = 2N - S = 31"), InputError);
    CHECK_NOTHROW(ReleaseImager(cl, Precision::F32, 2, 8, 20));  // G = 32
    if (cl.info().type == "CPU") {
      Runtime fw(std::string(""), FftBackend::FFTW);
      const RealStack cube = random_stack(2, 9, 9, 3, false), psf = random_stack(2, 20, 20, 4, true);
      ReleaseImager im(fw, Precision::F32, 2, 9, 20);
      im.set_psf(psf);
      const RealStack got = im.blur(cube), want = ref::release_blur(cube, psf);
      double worst = 0;
      for (std::size_t i = 0; i < got.size(); ++i) worst = std::max(worst, std::fabs(got.data[i] - want.data[i]));
      CHECK(worst < 1e-5);
    }
  }

  TEST_CASE("device release imager equals the reference (float32, float64; even and odd N - S)") {
    struct Size {
      std::size_t s, n;
    };
    for (const Size sz : {Size{12, 24}, Size{7, 16}}) {
      const std::size_t bands = 3;
      const RealStack cube = random_stack(bands, sz.s, sz.s, 21, false);
      const RealStack psf = random_stack(bands, sz.n, sz.n, 22, true);
      const RealStack want = ref::release_blur(cube, psf);
      const ReleaseGeometry g = release_geometry(sz.s, sz.n);
      for (Precision p : device_precisions(runtime())) {
        CAPTURE(sz.s);
        CAPTURE(sz.n);
        CAPTURE(to_string(p));
        ReleaseImager imager(runtime(), p, bands, sz.s, sz.n);
        CHECK_THROWS_WITH_AS(imager.blur(cube), doctest::Contains("set_psf"), Error);
        imager.set_psf(psf);
        const RealStack got = imager.blur(cube);
        // Rounding of the inputs, the two G² transforms (log2 G² stages) and the resizes.
        const double tol = 8 * eps(p) * std::log2(double(g.g * g.g));
        const auto d = diff(got.data, want.data);
        CAPTURE(d.worst);
        CHECK(d.rel_l2 <= tol);
        // Refusals name the argument.
        CHECK_THROWS_WITH_AS(imager.blur(RealStack(bands, sz.s + 1, sz.s)), doctest::Contains("cube"), InputError);
        CHECK_THROWS_WITH_AS(imager.set_psf(RealStack(bands, sz.n, sz.n, NAN)), doctest::Contains("psf_native"), InputError);
      }
    }
  }
}
