// DOE height maps on the device: parameter expansion and the quantizer (REFERENCE §2).
// Heights: N x N real, row-major, metres; sample (i, j) relative to the axis (N/2, N/2).

// Exact integer floor(sqrt(r2)) (float sqrt can round up at large r2).
inline int isqrt_floor(int r2) {
  int k = (int)sqrt((real)r2);
  while (k * k > r2) --k;
  while ((k + 1) * (k + 1) <= r2) ++k;
  return k;
}

// Index of the parameter that drives sample (i, j): kind 0 full 2-D (N*N params, row-major),
// 1 radial (N/2 rings, ring k = floor(r) clamped to N/2 - 1), 2 quad ((N/2)^2 params, quarter
// (min(|i - N/2|, N/2 - 1), min(|j - N/2|, N/2 - 1)), row-major).
inline int param_index(int i, int j, int n, int kind) {
  const int hn = n / 2, di = i - hn, dj = j - hn;
  if (kind == 0) return i * n + j;
  if (kind == 1) return min(isqrt_floor(di * di + dj * dj), hn - 1);
  const int ai = di < 0 ? -di : di, aj = dj < 0 ? -dj : dj;  // abs() returns uint in OpenCL C
  return min(ai, hn - 1) * hn + min(aj, hn - 1);
}

// heights[i][j] = clamp(params[param_index(i, j)], 0, h_max).
__kernel void expand_params(__global const real* params, __global real* heights, const int n, const int kind,
                            const real h_max) {
  const size_t gid = get_global_id(0);
  if (gid >= (size_t)n * n) return;
  const int i = (int)(gid / n), j = (int)(gid - (size_t)i * n);
  heights[gid] = clamp(params[param_index(i, j, n, kind)], R(0.0), h_max);
}

// Alpha-blended quantization, in place on heights (count values):
// H = alpha * h_max * level(index(H / h_max)) + (1 - alpha) * H, with index = floor(u (L-1) + 0.5)
// (placement 0, inclusive) or floor(u L + 0.5) mod L (placement 1, wrapped), u clamped to [0, 1],
// and level_u[l] the normalised height of level l (L reals, from Quantizer::level_value on the
// host: uniform placement plus adaptive offsets, or an explicit level table).
__kernel void quantize_blend(__global real* heights, const int count, const real h_max, const int levels,
                             const int placement, __global const real* level_u, const real alpha) {
  const size_t gid = get_global_id(0);
  if (gid >= (size_t)count) return;
  const real hf = heights[gid];
  const real u = clamp(hf / h_max, R(0.0), R(1.0));
  const int l = placement == 0 ? min((int)floor(u * (real)(levels - 1) + R(0.5)), levels - 1)
                                : ((int)floor(u * (real)levels + R(0.5))) % levels;
  heights[gid] = alpha * h_max * level_u[l] + (R(1.0) - alpha) * hf;
}
