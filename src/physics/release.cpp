// The release's image formation (include/qdo/physics/release.hpp): geometry and the device path
// (kernels/release.cl); its CPU reference in double is release_reference.cpp.
#include "qdo/physics/release.hpp"

#include <algorithm>
#include <string>

#include "qdo/runtime/error.hpp"
#include "qdo/runtime/fft.hpp"

namespace qdo {

ReleaseGeometry release_geometry(std::size_t s, std::size_t n) {
  if (s < 1) reject("scene size S", s, "at least 1 pixel");
  if (n < s + 2)
    reject("PSF size N", n, "at least S + 2 = " + to_str(s + 2) + " (the release pads the up-sampled scene by (N - S)/2 per side and crops [before : -after])");
  ReleaseGeometry g;
  g.s = s;
  g.n = n;
  const std::size_t d = n - s;
  g.before = (d + 1) / 2;  // ceil
  g.after = d / 2;         // floor
  g.g = n + g.before + g.after;
  const std::size_t dp = g.g - n;  // psf2otf's padding
  if (dp % 2) {
    g.psf_before = (dp + 1) / 2;
    g.psf_after = dp / 2;
  } else {
    g.psf_before = dp / 2 + 1;
    g.psf_after = dp / 2 - 1;
  }
  g.split = g.g - (g.g + 1) / 2;
  return g;
}

ReleaseImager::ReleaseImager(Runtime& rt, Precision p, std::size_t bands, std::size_t s, std::size_t n)
    : rt_(rt), prec_(p), bands_(bands), geo_(release_geometry(s, n)) {
  if (bands < 1) reject("bands", bands, "at least 1");
  rt_.require(p);
  // clFFT plans only lengths whose prime factors are at most 13: refuse others here, naming the
  // sizes, rather than when the plan is baked (FFTW and VkFFT take any length).
  if (rt_.fft_backend() == FftBackend::ClFFT) {
    std::size_t g = geo_.g, largest = 1;
    for (std::size_t f = 2; f * f <= g; ++f)
      while (g % f == 0) {
        largest = f;
        g /= f;
      }
    largest = std::max(largest, g);
    if (largest > 13)
      reject("s", s, "a scene size S whose release grid G = 2N - S = " + to_str(geo_.g) + " (N = " + to_str(n) +
                         ") has no prime factor above 13 on the clFFT backend (it has " + to_str(largest) +
                         "); QDO_FFT=fftw or vkfft take any size");
  }
  k_up_pad_ = rt_.kernel("release.cl", "release_up_pad", p);
  k_place_ = rt_.kernel("release.cl", "release_place_psf", p);
  k_cmul_ = rt_.kernel("release.cl", "release_cmul", p);
  k_crop_down_ = rt_.kernel("release.cl", "release_crop_down", p);
  const std::size_t rsz = real_size(p), gg = geo_.g;
  psf_ = cl::Buffer(rt_.context(), CL_MEM_READ_ONLY, bands * n * n * rsz);
  otf_ = cl::Buffer(rt_.context(), CL_MEM_READ_WRITE, bands * gg * gg * 2 * rsz);
  scene_ = cl::Buffer(rt_.context(), CL_MEM_READ_ONLY, bands * s * s * rsz);
  work_ = cl::Buffer(rt_.context(), CL_MEM_READ_WRITE, bands * gg * gg * 2 * rsz);
  out_ = cl::Buffer(rt_.context(), CL_MEM_READ_WRITE, bands * s * s * rsz);
  rt_.fft(gg, gg, bands, p);  // bake the plan now, not inside the first blur
}

void ReleaseImager::set_psf(const RealStack& psf_native) {
  const std::size_t n = geo_.n, gg = geo_.g;
  if (psf_native.planes != bands_ || psf_native.rows != n || psf_native.cols != n)
    reject("psf_native", to_str(psf_native.planes) + " x " + to_str(psf_native.rows) + " x " + to_str(psf_native.cols),
           "bands x N x N = " + to_str(bands_) + " x " + to_str(n) + " x " + to_str(n));
  for (double v : psf_native.data)
    if (!std::isfinite(v)) reject("psf_native", v, "finite values");
  rt_.write_reals(psf_, psf_native.data.data(), psf_native.size(), prec_);
  rt_.launch_1d(k_place_, bands_ * gg * gg, prec_, psf_, otf_, int(n), int(gg), int(geo_.psf_before), int(geo_.split),
                int(bands_));
  rt_.fft(gg, gg, bands_, prec_).forward(otf_);
  have_psf_ = true;
}

RealStack ReleaseImager::blur(const RealStack& cube) {
  const std::size_t s = geo_.s, n = geo_.n, gg = geo_.g;
  if (!have_psf_) throw Error("ReleaseImager: set_psf() must be called before blur()");
  if (cube.planes != bands_ || cube.rows != s || cube.cols != s)
    reject("cube", to_str(cube.planes) + " x " + to_str(cube.rows) + " x " + to_str(cube.cols),
           "bands x S x S = " + to_str(bands_) + " x " + to_str(s) + " x " + to_str(s));
  for (double v : cube.data)
    if (!std::isfinite(v)) reject("cube", v, "finite values");
  rt_.write_reals(scene_, cube.data.data(), cube.size(), prec_);
  rt_.launch_1d(k_up_pad_, bands_ * gg * gg, prec_, scene_, work_, int(s), int(n), int(gg), int(geo_.before), int(bands_));
  FftPlan& fft = rt_.fft(gg, gg, bands_, prec_);
  fft.forward(work_);
  rt_.launch_1d(k_cmul_, bands_ * gg * gg, prec_, work_, otf_, int(bands_ * gg * gg));
  fft.inverse(work_);
  rt_.launch_1d(k_crop_down_, bands_ * s * s, prec_, work_, out_, int(s), int(n), int(gg), int(geo_.before), int(bands_));
  RealStack out(bands_, s, s);
  rt_.read_reals(out_, out.data.data(), out.size(), prec_);
  return out;
}

}  // namespace qdo
