// Counter-based random numbers (Philox4x32-10, Salmon et al. SC'11). The same integer
// function runs in kernels/sensor.cl and kernels/raw.cl, so a (seed, counter) gives the same bits on the host
// and on every device: noise is reproducible and independent of work-group or batch size.
#pragma once
#include <array>
#include <cmath>
#include <cstdint>

namespace qdo {

inline std::array<std::uint32_t, 4> philox4x32(std::array<std::uint32_t, 4> ctr, std::array<std::uint32_t, 2> key) {
  for (int round = 0; round < 10; ++round) {
    const std::uint64_t p0 = std::uint64_t(0xD2511F53u) * ctr[0];
    const std::uint64_t p1 = std::uint64_t(0xCD9E8D57u) * ctr[2];
    const std::uint32_t hi0 = std::uint32_t(p0 >> 32), lo0 = std::uint32_t(p0);
    const std::uint32_t hi1 = std::uint32_t(p1 >> 32), lo1 = std::uint32_t(p1);
    ctr = {hi1 ^ ctr[1] ^ key[0], lo1, hi0 ^ ctr[3] ^ key[1], lo0};
    key[0] += 0x9E3779B9u;
    key[1] += 0xBB67AE85u;
  }
  return ctr;
}

// Uniform in (0, 1): never 0, so log() is safe.
inline double uniform_open(std::uint32_t x) { return (double(x) + 0.5) * (1.0 / 4294967296.0); }

// Noise draws for element `index` (pixel * 3 + channel) under `seed`: a standard normal for
// read noise and a Poisson count of mean `mean` (exact inversion below 64, a rounded normal
// approximation above, clamped at 0) for shot noise.
// Streams (the third counter word): the sensor stage's noise (kernels/sensor.cl) and the raw
// stage's (kernels/raw.cl) draw independent numbers for the same (seed, index).
constexpr std::uint32_t kSensorNoiseStream = 0x51ed27u;
constexpr std::uint32_t kRawNoiseStream = 0x7a3b5eu;
struct NoiseDraw {
  double gaussian;
  double uniform_poisson;
  double gaussian_poisson;
};
// noise_draw(seed, index, stream).gaussian alone, bit for bit (the same operations in the same
// order), without the second normal and the Poisson uniform: the read-noise-only path.
inline double noise_gaussian(std::uint64_t seed, std::uint64_t index, std::uint32_t stream = kSensorNoiseStream) {
  const auto r = philox4x32({std::uint32_t(index), std::uint32_t(index >> 32), stream, 0u},
                            {std::uint32_t(seed), std::uint32_t(seed >> 32)});
  const double u0 = uniform_open(r[0]), u1 = uniform_open(r[1]);
  const double rad = std::sqrt(-2.0 * std::log(u0));
  return rad * std::cos(2.0 * M_PI * u1);
}
inline NoiseDraw noise_draw(std::uint64_t seed, std::uint64_t index, std::uint32_t stream = kSensorNoiseStream) {
  const auto r = philox4x32({std::uint32_t(index), std::uint32_t(index >> 32), stream, 0u},
                            {std::uint32_t(seed), std::uint32_t(seed >> 32)});
  // Box-Muller on (r0, r1) gives two independent normals; r2 drives the Poisson inversion.
  const double u0 = uniform_open(r[0]), u1 = uniform_open(r[1]), u2 = uniform_open(r[2]);
  const double rad = std::sqrt(-2.0 * std::log(u0));
  return {rad * std::cos(2.0 * M_PI * u1), u2, rad * std::sin(2.0 * M_PI * u1)};
}

inline double poisson_from(double mean, const NoiseDraw& d) {
  if (mean <= 0) return 0.0;
  if (mean < 64.0) {
    double p = std::exp(-mean), cdf = p, k = 0;
    while (d.uniform_poisson > cdf && k < 1000) {
      k += 1;
      p *= mean / k;
      cdf += p;
    }
    return k;
  }
  return std::fmax(0.0, std::floor(mean + std::sqrt(mean) * d.gaussian_poisson + 0.5));
}

}  // namespace qdo
