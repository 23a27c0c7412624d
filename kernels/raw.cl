// The sensor as built (include/qdo/physics/raw.hpp): linear RGB -> raw code values in DN, and the
// adjoint of its differentiable part. CPU reference: ref::raw_forward (raw_reference.hpp).

// The colour channel (0 R, 1 G, 2 B) filtered at pixel (y, x): cfa_code holds the 2 x 2 cell,
// two bits per entry, entry (y & 1) * 2 + (x & 1); -1 means no mosaic.
inline int raw_channel(int cfa_code, int y, int x) { return (cfa_code >> (2 * ((y & 1) * 2 + (x & 1)))) & 3; }

// The linear signal of element (k, c, p) with noise (common.cl's sensor_noise), counter
// (k * hw + p) * 3 + c in the raw stream (rng.hpp kRawNoiseStream). Same draws as the host.
inline real raw_noisy(real v, int k, int c, int p, int hw, real sigma, real full_well, uint seed_lo, uint seed_hi) {
  return sensor_noise(v, ((ulong)k * hw + p) * 3 + c, 0x7a3b5eu, sigma, full_well, seed_lo, seed_hi);
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
