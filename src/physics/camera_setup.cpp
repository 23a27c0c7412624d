// The Camera's construction and state (include/qdo/physics/camera.hpp): its kernels, the PSF it follows
// (its own stack or a PsfSource), buffer growth, the per-generation ring energies and OTFs, and
// the checks of a batch. The passes themselves are camera.cpp.
#include "qdo/physics/camera.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>

#include "qdo/runtime/error.hpp"
#include "qdo/runtime/fft.hpp"
#include "qdo/physics/optics.hpp"
#include "row_launch.hpp"

namespace qdo {

Camera::Camera(const PsfSource& source)
    : rt_(source.runtime()), source_(&source), cfg_(source.config()), prec_(source.precision()), s_(source.sensor_size()),
      rsz_(real_size(source.precision())), srf_(sensor_response(source.config())) {
  if (source.psf_planes() != cfg_.bands)
    reject("PSF source planes", source.psf_planes(), "one design: the configuration's " + to_str(cfg_.bands) + " bands (" + source.describe() + ")");
  init();
}

Camera::Camera(Runtime& rt, const SystemConfig& cfg, Precision p)
    : rt_(rt), cfg_(cfg), prec_(p), rsz_(real_size(p)) {
  cfg_.validate();
  rt_.require(p);
  s_ = cfg_.sensor_size_px();
  srf_ = sensor_response(cfg_);
  init();
}

void Camera::init() {
  k_rings_ = rt_.kernel("camera.cl", "ring_energy", prec_);
  k_place_psf_ = rt_.kernel("camera.cl", "place_psf_pairs", prec_);
  k_place_ = rt_.kernel("camera.cl", "place_windows", prec_);
  k_combine_ = rt_.kernel("camera.cl", "combine_channels", prec_);
  k_gather_ = rt_.kernel("camera.cl", "gather_windows", prec_);
  k_noise_ = rt_.kernel("sensor.cl", "sensor_integrate", prec_);
  k_multiply_ = rt_.kernel("camera.cl", "multiply_pairs", prec_);
  k_gather_pairs_ = rt_.kernel("camera.cl", "gather_pairs", prec_);
  k_vjp_spectra_ = rt_.kernel("camera.cl", "camera_vjp_spectra", prec_);
  k_gather_psf_ = rt_.kernel("camera.cl", "gather_psf_pairs", prec_);
  // Identity response for sensor.cl's noise stage applied to finished RGB images: the sum
  // 0 + 1*v + 0*u + 0*w reproduces v exactly, so only the noise is added.
  std::vector<double> eye{1, 0, 0, 0, 1, 0, 0, 0, 1};
  const cl_mem_flags flags = CL_MEM_READ_ONLY | CL_MEM_COPY_HOST_PTR;
  if (prec_ == Precision::F64) {
    eye_ = cl::Buffer(rt_.context(), flags, eye.size() * sizeof(double), eye.data());
  } else {
    std::vector<float> f(eye.begin(), eye.end());
    eye_ = cl::Buffer(rt_.context(), flags, f.size() * sizeof(float), f.data());
  }
}

void Camera::set_psf(const RealStack& psf_sensor) {
  if (source_) reject("set_psf", "(camera bound to a PSF source)", "a standalone Camera (a bound camera follows its source: " + source_->describe() + ")");
  if (psf_sensor.planes != cfg_.bands || psf_sensor.rows != s_ || psf_sensor.cols != s_)
    reject("psf_sensor", to_str(psf_sensor.planes) + " x " + to_str(psf_sensor.rows) + " x " + to_str(psf_sensor.cols),
           "bands x S x S = " + to_str(cfg_.bands) + " x " + to_str(s_) + " x " + to_str(s_));
  for (std::size_t i = 0; i < psf_sensor.size(); ++i)
    if (!std::isfinite(psf_sensor.data[i])) reject("psf_sensor[" + to_str(i) + "]", psf_sensor.data[i], "finite values");
  const std::size_t bytes = psf_sensor.size() * rsz_;
  own_psf_ = cl::Buffer(rt_.context(), CL_MEM_READ_ONLY, bytes);
  rt_.write_reals(own_psf_, psf_sensor.data.data(), psf_sensor.size(), prec_);
  ++own_generation_;
}

const cl::Buffer& Camera::psf_buffer() const {
  if (source_ && !source_->psf_ready()) throw Error("Camera: its PSF source has no stack yet (" + source_->describe() + ")");
  return source_ ? source_->psf_sensor_buffer() : own_psf_;
}
std::uint64_t Camera::current_generation() const { return source_ ? source_->psf_generation() : own_generation_; }

cl::Buffer& Camera::grow(cl::Buffer& b, std::size_t& cap, std::size_t bytes, cl_mem_flags flags) {
  bytes = std::max<std::size_t>(bytes, 8);
  if (!b() || cap < bytes) {
    b = cl::Buffer(rt_.context(), flags, bytes);
    cap = bytes;
  }
  return b;
}

// Per-band ring energies of the current PSF (once per generation; the only read-back besides
// the images).
void Camera::ensure_rings() {
  const std::uint64_t gen = current_generation();
  if (rings_valid_ && rings_gen_ == gen) return;
  const std::size_t bands = cfg_.bands, nr = s_ / 2 + 1;
  grow(rings_buf_, rings_cap_, bands * nr * rsz_);
  rt_.launch_1d(k_rings_, bands * nr, prec_, psf_buffer(), rings_buf_, int(s_), int(bands));
  rings_.assign(bands * nr, 0.0);
  rt_.read_reals(rings_buf_, rings_.data(), rings_.size(), prec_);
  rings_gen_ = gen;
  rings_valid_ = true;
  otf_valid_ = false;
}

// Pair-packed OTFs of the kept bands cropped at radius r on the gy x gx grid.
void Camera::ensure_otf(std::size_t r, std::size_t gy, std::size_t gx, const std::vector<std::size_t>& kept) {
  const std::uint64_t gen = current_generation();
  if (otf_valid_ && otf_gen_ == gen && otf_r_ == r && otf_gy_ == gy && otf_gx_ == gx && otf_kept_ == kept) {
    report_.otf_reused = true;
    return;
  }
  report_.otf_reused = false;
  const std::size_t pairs = (kept.size() + 1) / 2, g = gy * gx;
  std::vector<int> band_of(kept.begin(), kept.end());
  band_of.resize(std::max<std::size_t>(band_of.size(), 1), 0);
  grow(band_of_, band_of_cap_, band_of.size() * sizeof(int), CL_MEM_READ_ONLY);
  rt_.queue().enqueueWriteBuffer(band_of_, CL_TRUE, 0, band_of.size() * sizeof(int), band_of.data());
  grow(otf_, otf_cap_, pairs * g * 2 * rsz_);
  launch_rows(rt_, k_place_psf_, gx, pairs * gy, prec_, psf_buffer(), band_of_, otf_, int(s_), int(gy), int(gx), int(r),
                int(kept.size()));
  rt_.fft(gy, gx, pairs, prec_).forward(otf_);
  otf_gen_ = gen;
  otf_r_ = r;
  otf_gy_ = gy;
  otf_gx_ = gx;
  otf_kept_ = kept;
  otf_valid_ = true;
  ++otf_builds_;
}

void Camera::check_batch(const std::vector<RealStack>& cubes, bool values) const {
  if (cubes.empty()) reject("cubes", 0, "at least one scene");
  const std::size_t bands = cfg_.bands, h = cubes[0].rows, w = cubes[0].cols, scenes = cubes.size();
  if (h < 1 || w < 1) reject("cube", to_str(h) + " x " + to_str(w), "at least 1 x 1 pixels");
  // One branch-free pass flags a value with every exponent bit set (an infinity or a NaN); only
  // then the slow scan below looks for it.
  constexpr std::uint64_t kExponent = 0x7ff0000000000000ull;
  std::uint64_t nonfinite = 0;
  for (std::size_t k = 0; k < (values ? scenes : 0); ++k) {
    const double* p = cubes[k].data.data();
    const std::size_t n = cubes[k].data.size();
    for (std::size_t i = 0; i < n; ++i) {
      std::uint64_t bits;
      std::memcpy(&bits, p + i, sizeof bits);
      nonfinite |= std::uint64_t((bits & kExponent) == kExponent);
    }
  }
  for (std::size_t k = 0; k < scenes; ++k) {
    if (cubes[k].planes != bands)
      reject("cubes[" + to_str(k) + "] bands", cubes[k].planes, "the configuration's band count (" + to_str(bands) + ")");
    if (cubes[k].rows != h || cubes[k].cols != w)
      reject("cubes[" + to_str(k) + "]", to_str(cubes[k].rows) + " x " + to_str(cubes[k].cols), "the shape of the first scene in the batch");
    for (std::size_t i = 0; nonfinite && i < cubes[k].size(); ++i)
      if (!std::isfinite(cubes[k].data[i])) {
        const std::size_t b = i / (h * w), y = (i / w) % h, x = i % w;
        reject("cubes[" + to_str(k) + "](" + to_str(b) + ", " + to_str(y) + ", " + to_str(x) + ")", cubes[k].data[i], "finite values");
      }
  }
  if (cfg_.convolution == ConvolutionMode::Circular && (fast_fft_size(h) != h || fast_fft_size(w) != w))
    reject("cube", to_str(h) + " x " + to_str(w),
           "sizes made of the factors 2, 3, 5 and 7 in circular convolution mode (the FFT runs on the scene grid)");
  if (source_ ? !source_->psf_ready() : current_generation() == 0)
    throw Error(source_ ? "Camera: its PSF source has no stack yet (" + source_->describe() + "; a simulator's compute_psf() must run before images())"
                        : std::string("Camera: set_psf() must be called before images()"));
}

}  // namespace qdo
