// Prepended to every kernel file. QDO_FP64 (0/1) picks the working precision `real`.
// Complex numbers are real2 (x = re, y = im), interleaved in memory as clFFT expects.
// Every 1-D kernel runs with the fixed work-group size Runtime::kLocalSize and a global size
// rounded up to it, so each kernel checks its index against the element count.
#if QDO_FP64
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double real;
typedef double2 real2;
#define R(x) (x)
#else
typedef float real;
typedef float2 real2;
#define R(x) (x##f)
#endif

inline real2 cmul(real2 a, real2 b) { return (real2)(a.x * b.x - a.y * b.y, a.x * b.y + a.y * b.x); }
#if QDO_FP64
inline __attribute__((always_inline)) real2 cexpi(real phase) {
  real c;
  real s = sincos(phase, &c);
  return (real2)(c, s);
}
#else
// e^{i phase} in float32 without a libm call: branch-free and always inlined (PoCL's inliner
// otherwise keeps it a call, which stops the work-group loop's vectorizer), 0.33 s -> 0.15 s of
// the paper-preset DOE field pass. Quadrant reduction
// r = phase - q·π/2 with π/2 split in three floats (Cody-Waite; q·PIO2_1 is exact for
// |q| < 2^15, i.e. |phase| < 5e4 rad, far beyond qdo's phases of at most a few hundred rad),
// then the minimax polynomials of Cephes' sinf/cosf on [-π/4, π/4] (error ~1 ulp there) and the
// quadrant's rotation by selects. The argument's own float rounding (eps·|phase|) dominates the
// result's error, as it did with sincos.
inline __attribute__((always_inline)) real2 cexpi(real phase) {
  const float q = rint(phase * 0.63661977236758134f);  // 2/π
  float r = fma(-q, 1.5703125f, phase);
  r = fma(-q, 4.837512969970703125e-4f, r);
  r = fma(-q, 7.549789948768648e-8f, r);
  const float r2 = r * r;
  const float sn = fma(r * r2, fma(r2, fma(r2, -1.9515295891e-4f, 8.3321608736e-3f), -1.6666654611e-1f), r);
  const float cs = fma(r2 * r2, fma(r2, fma(r2, 2.443315711809948e-5f, -1.388731625493765e-3f), 4.166664568298827e-2f),
                       fma(-0.5f, r2, 1.0f));
  const int k = ((int)q) & 3;  // e^{i(r + kπ/2)} = i^k e^{ir}
  const float c = k == 0 ? cs : k == 1 ? -sn : k == 2 ? -cs : sn;
  const float s = k == 0 ? sn : k == 1 ? cs : k == 2 ? -sn : -cs;
  return (real2)(c, s);
}
#endif

// Philox4x32-10: bit-identical to qdo::philox4x32 in include/qdo/runtime/rng.hpp.
inline uint4 philox4x32(uint4 c, uint2 k) {
  for (int r = 0; r < 10; ++r) {
    const uint hi0 = mul_hi(0xD2511F53u, c.x), lo0 = 0xD2511F53u * c.x;
    const uint hi1 = mul_hi(0xCD9E8D57u, c.z), lo1 = 0xCD9E8D57u * c.z;
    c = (uint4)(hi1 ^ c.y ^ k.x, lo1, hi0 ^ c.w ^ k.y, lo0);
    k += (uint2)(0x9E3779B9u, 0xBB67AE85u);
  }
  return c;
}
inline real uniform_open(uint x) { return ((real)x + R(0.5)) * R(2.3283064365386963e-10); }

// A linear sensor value v (1.0 = full well) with reproducible noise: shot noise (Poisson with
// full_well photons at 1.0, skipped when full_well <= 0; normal approximation from a mean of 64
// photons), then Gaussian read noise of `sigma`, both from Philox counter (idx, stream) under the
// key (seed_lo, seed_hi). Bit-identical to the host's noise_draw (rng.hpp) for the same stream:
// the sensor stage uses 0x51ed27 (kSensorNoiseStream), the raw stage 0x7a3b5e (kRawNoiseStream).
inline real sensor_noise(real v, ulong idx, uint stream, real sigma, real full_well, uint seed_lo, uint seed_hi) {
  if (!(sigma > R(0.0) || full_well > R(0.0))) return v;
  const uint4 r = philox4x32((uint4)((uint)idx, (uint)(idx >> 32), stream, 0u), (uint2)(seed_lo, seed_hi));
  const real u0 = uniform_open(r.x), u1 = uniform_open(r.y), u2 = uniform_open(r.z);
  const real rad = sqrt(R(-2.0) * log(u0));
  const real ang = R(6.283185307179586) * u1;
  if (full_well > R(0.0)) {
    const real mean = fmax(v, R(0.0)) * full_well;
    real cnt = R(0.0);
    if (mean > R(0.0) && mean < R(64.0)) {
      real pk = exp(-mean), cdf = pk;
      while (u2 > cdf && cnt < R(1000.0)) {
        cnt += R(1.0);
        pk *= mean / cnt;
        cdf += pk;
      }
    } else if (mean >= R(64.0)) {
      cnt = fmax(R(0.0), floor(mean + sqrt(mean) * rad * sin(ang) + R(0.5)));
    }
    v = cnt / full_well;
  }
  return v + sigma * rad * cos(ang);
}
