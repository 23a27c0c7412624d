// The sensor as built (include/qdo/raw.hpp): linear RGB -> raw code values in DN, and the
// adjoint of its differentiable part. CPU reference: ref::raw_forward (raw_reference.hpp).

// Philox4x32-10: bit-identical to qdo::philox4x32 in include/qdo/rng.hpp (and kernels/sensor.cl).
inline uint4 raw_philox4x32(uint4 c, uint2 k) {
  for (int r = 0; r < 10; ++r) {
    const uint hi0 = mul_hi(0xD2511F53u, c.x), lo0 = 0xD2511F53u * c.x;
    const uint hi1 = mul_hi(0xCD9E8D57u, c.z), lo1 = 0xCD9E8D57u * c.z;
    c = (uint4)(hi1 ^ c.y ^ k.x, lo1, hi0 ^ c.w ^ k.y, lo0);
    k += (uint2)(0x9E3779B9u, 0xBB67AE85u);
  }
  return c;
}
inline real raw_uniform_open(uint x) { return ((real)x + R(0.5)) * R(2.3283064365386963e-10); }

// The colour channel (0 R, 1 G, 2 B) filtered at pixel (y, x): cfa_code holds the 2 x 2 cell,
// two bits per entry, entry (y & 1) * 2 + (x & 1); -1 means no mosaic.
inline int raw_channel(int cfa_code, int y, int x) { return (cfa_code >> (2 * ((y & 1) * 2 + (x & 1)))) & 3; }

// The linear signal of element (k, c, p) with noise: shot noise (Poisson with full_well photons
// at 1.0, skipped when full_well <= 0) then Gaussian read noise of `sigma`, counter
// (k * hw + p) * 3 + c in the raw stream (rng.hpp kRawNoiseStream). Same draws as the host.
inline real raw_noisy(real v, int k, int c, int p, int hw, real sigma, real full_well, uint seed_lo, uint seed_hi) {
  if (!(sigma > R(0.0) || full_well > R(0.0))) return v;
  const ulong idx = ((ulong)k * hw + p) * 3 + c;
  const uint4 r = raw_philox4x32((uint4)((uint)idx, (uint)(idx >> 32), 0x7a3b5eu, 0u), (uint2)(seed_lo, seed_hi));
  const real u0 = raw_uniform_open(r.x), u1 = raw_uniform_open(r.y), u2 = raw_uniform_open(r.z);
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

// Forward. rgb: scenes x 3 x hw reals (linear, 1.0 = full well), raw: scenes x channels x hw
// (channels = 1 with a mosaic, cfa_code >= 0; 3 without, cfa_code = -1), pixel p = y * width + x.
// For raw element (k, o, p), c = the filtered channel (or o): v = noisy rgb[k][c][p];
// saturated when v > 1 (the full well) or the code black + gain * min(v, 1) * (white - black)
// exceeds white; the code is clipped to [0, white], rounded to an integer when quantize != 0.
// counts[0] += saturated elements, counts[1] += elements clipped at 0 (one atomic per group).
__kernel void raw_forward(__global const real* rgb, __global real* raw, __global uint* counts, const int hw,
                          const int width, const int channels, const int cfa_code, const real gain, const real black,
                          const real white, const int quantize, const real sigma, const real full_well,
                          const uint seed_lo, const uint seed_hi, const int scenes) {
  __local uint sat_l, floor_l;
  const size_t gid = get_global_id(0);
  if (get_local_id(0) == 0) {
    sat_l = 0;
    floor_l = 0;
  }
  barrier(CLK_LOCAL_MEM_FENCE);
  if (gid < (size_t)hw * channels * scenes) {
    const int k = (int)(gid / ((size_t)hw * channels));
    const int rem = (int)(gid - (size_t)k * hw * channels);
    const int o = rem / hw;
    const int p = rem - o * hw;
    const int c = cfa_code >= 0 ? raw_channel(cfa_code, p / width, p % width) : o;
    const real v = raw_noisy(rgb[((size_t)k * 3 + c) * hw + p], k, c, p, hw, sigma, full_well, seed_lo, seed_hi);
    real code = black + gain * fmin(v, R(1.0)) * (white - black);
    if (v > R(1.0) || code > white) {
      atomic_inc(&sat_l);
      code = white;
    } else if (code < R(0.0)) {
      atomic_inc(&floor_l);
      code = R(0.0);
    }
    if (quantize) code = floor(code + R(0.5));
    raw[gid] = code;
  }
  barrier(CLK_LOCAL_MEM_FENCE);
  if (get_local_id(0) == 0) {
    if (sat_l) atomic_add(&counts[0], sat_l);
    if (floor_l) atomic_add(&counts[1], floor_l);
  }
}

// Adjoint of the differentiable part (rounding straight-through, noise recomputed from the same
// counters): g_rgb[k][c][p] = gain * (white - black) * g_raw[k][o][p] where c is the channel the
// raw element (k, o, p) read and that element was clipped neither at saturation nor at 0; 0 for
// channels a mosaic does not sample. rgb, g_rgb: scenes x 3 x hw; g_raw: scenes x channels x hw.
__kernel void raw_adjoint(__global const real* rgb, __global const real* g_raw, __global real* g_rgb, const int hw,
                          const int width, const int channels, const int cfa_code, const real gain, const real black,
                          const real white, const real sigma, const real full_well, const uint seed_lo,
                          const uint seed_hi, const int scenes) {
  const size_t gid = get_global_id(0);
  if (gid >= (size_t)hw * 3 * scenes) return;
  const int k = (int)(gid / ((size_t)hw * 3));
  const int rem = (int)(gid - (size_t)k * hw * 3);
  const int c = rem / hw;
  const int p = rem - c * hw;
  real g = R(0.0);
  if (cfa_code < 0 || raw_channel(cfa_code, p / width, p % width) == c) {
    const real v = raw_noisy(rgb[gid], k, c, p, hw, sigma, full_well, seed_lo, seed_hi);
    const real code = black + gain * fmin(v, R(1.0)) * (white - black);
    if (!(v > R(1.0) || code > white || code < R(0.0)))
      g = gain * (white - black) * g_raw[((size_t)k * channels + (cfa_code >= 0 ? 0 : c)) * hw + p];
  }
  g_rgb[gid] = g;
}
