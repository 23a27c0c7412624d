// RGB sensor integration (Eq. 7) with reproducible noise.

// Philox4x32-10: bit-identical to qdo::philox4x32 in include/qdo/rng.hpp.
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

// rgb[k][c][p] = sum_b srf[c][b] * cube[k][b][p] (+ noise) for scenes k. cube: scenes x bands x HW
// real, srf: 3 x bands (rows normalised to unit sum), rgb: scenes x 3 x HW. Noise for element
// (k, c, p) uses counter (k*HW + p)*3 + c:
// Poisson shot noise with full_well photons at 1.0 (skipped when full_well <= 0), then
// Gaussian read noise of `sigma`. Exact inversion below a mean of 64, rounded normal above.
__kernel void sensor_integrate(__global const real* cube, __constant real* srf, __global real* rgb, const int hw,
                               const int bands, const real sigma, const real full_well, const uint seed_lo,
                               const uint seed_hi, const int scenes) {
  const size_t gid = get_global_id(0);
  if (gid >= (size_t)hw * 3 * scenes) return;
  const int k = (int)(gid / ((size_t)hw * 3));
  const int rem = (int)(gid - (size_t)k * hw * 3);
  const int c = rem / hw;
  const int p = rem - c * hw;
  __global const real* scene = cube + (size_t)k * bands * hw;
  real v = R(0.0);
  for (int b = 0; b < bands; ++b) v += srf[c * bands + b] * scene[(size_t)b * hw + p];
  if (sigma > R(0.0) || full_well > R(0.0)) {
    const ulong idx = ((ulong)k * hw + p) * 3 + c;
    const uint4 r = philox4x32((uint4)((uint)idx, (uint)(idx >> 32), 0x51ed27u, 0u), (uint2)(seed_lo, seed_hi));
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
    v += sigma * rad * cos(ang);
  }
  rgb[gid] = v;
}
