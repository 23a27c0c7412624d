// Adjoint (vector-Jacobian product) kernels of the PSF chain; see include/qdo/adjoint.hpp for
// the gradient convention (complex gradients g = dL/dRe + i dL/dIm).

// Per-band partial dot products <a_b, b_b>. NDRange (groups_per_band * local, bands).
// a, b: bands x len real; partial: bands x groups_per_band.
__kernel void band_dot(__global const real* a, __global const real* b, const int len, __global real* partial,
                       const int groups_per_band, __local real* scratch) {
  const int band = get_group_id(1), g = get_group_id(0), lid = get_local_id(0), ls = get_local_size(0);
  real acc = R(0.0);
  for (size_t e = (size_t)g * ls + lid; e < (size_t)len; e += (size_t)groups_per_band * ls)
    acc += a[(size_t)band * len + e] * b[(size_t)band * len + e];
  scratch[lid] = acc;
  barrier(CLK_LOCAL_MEM_FENCE);
  for (int s = ls / 2; s > 0; s >>= 1) {
    if (lid < s) scratch[lid] += scratch[lid + s];
    barrier(CLK_LOCAL_MEM_FENCE);
  }
  if (lid == 0) partial[(size_t)band * groups_per_band + g] = scratch[0];
}

// VJP of y = x / sum(x) per band: g_x = (g_y - <g_y, y>) / sum(x). g: bands x len, in place.
__kernel void normalize_vjp(__global real* g, __global const real* dots, __global const real* sums, const int len,
                            const int bands) {
  const size_t gid = get_global_id(0);
  if (gid >= (size_t)len * bands) return;
  const int b = (int)(gid / len);
  const real s = sums[b];
  g[gid] = s > R(0.0) ? (g[gid] - dots[b]) / s : R(0.0);
}

// VJP of P = |U2|² on the central N x N: gU (bands x M x M complex, written in full) =
// 2 g_P U2 inside the crop, 0 outside. g_p: bands x N x N; u2: bands x M x M.
__kernel void intensity_vjp(__global const real* g_p, __global const real2* u2, __global real2* gu, const int n,
                            const int m, const int offset, const int bands) {
  // 3-D NDRange (columns rounded up to the work-group size, rows, bands): no integer division.
  const int x = (int)get_global_id(0), y = (int)get_global_id(1), b = (int)get_global_id(2);
  if (x >= m || y >= m || b >= bands) return;
  const size_t gid = ((size_t)b * m + y) * m + x;
  const int i = y - offset, j = x - offset;
  real2 v = (real2)(R(0.0), R(0.0));
  if (i >= 0 && i < n && j >= 0 && j < n) v = R(2.0) * g_p[((size_t)b * n + i) * n + j] * u2[gid];
  gu[gid] = v;
}

// VJP of the DOE phase: dH[i][j] = sum_b k_b dn_b Re(conj(gU1) i U1), U1 recomputed exactly as
// doe_field does. gu: bands x M x M; dh: N x N.
__kernel void phase_vjp(__global const real* height_m, __global const real* k_per_m, __global const real* dn,
                        __global const real2* gu, __global real* dh, const int n, const int m, const int offset,
                        const int bands, const real pitch_m, const real distance_m, const real r_ap2_px) {
  const size_t gid = get_global_id(0);
  if (gid >= (size_t)n * n) return;
  const int i = (int)(gid / n), j = (int)(gid - (size_t)i * n);
  const int di = i - n / 2, dj = j - n / 2;
  const real y = (real)di * pitch_m, x = (real)dj * pitch_m;
  const real r2 = x * x + y * y;
  real acc = R(0.0);
  if ((real)(di * di + dj * dj) <= r_ap2_px) {  // integer pixel radius²: exact in float too
    const real src = distance_m > R(0.0) ? r2 / (sqrt(r2 + distance_m * distance_m) + distance_m) : R(0.0);
    const real h = height_m[gid];
    for (int b = 0; b < bands; ++b) {
      const real2 u = cexpi(k_per_m[b] * (src + dn[b] * h));
      const real2 g = gu[(size_t)b * m * m + (size_t)(offset + i) * m + (offset + j)];
      acc += k_per_m[b] * dn[b] * (g.y * u.x - g.x * u.y);
    }
  }
  dh[gid] = acc;
}

// VJP of the sensor integration: g_cube[k][b][p] = sum_c srf[c][b] g_rgb[k][c][p] (noise is
// additive and independent of the inputs: it passes no gradient). g_rgb: scenes x 3 x HW,
// g_cube: scenes x bands x HW.
__kernel void sensor_vjp(__global const real* g_rgb, __constant real* srf, __global real* g_cube, const int hw,
                         const int bands, const int scenes) {
  const size_t gid = get_global_id(0);
  if (gid >= (size_t)hw * bands * scenes) return;
  const int k = (int)(gid / ((size_t)hw * bands));
  const int rem = (int)(gid - (size_t)k * hw * bands);
  const int b = rem / hw, p = rem - b * hw;
  real acc = R(0.0);
  for (int c = 0; c < 3; ++c) acc += srf[c * bands + b] * g_rgb[((size_t)k * 3 + c) * hw + p];
  g_cube[gid] = acc;
}

// a[e] *= conj(b[e]) (same length).
__kernel void cmul_conj_inplace(__global real2* a, __global const real2* b, const int count) {
  const size_t gid = get_global_id(0);
  if (gid >= (size_t)count) return;
  const real2 x = a[gid], y = b[gid];
  a[gid] = (real2)(x.x * y.x + x.y * y.y, x.y * y.x - x.x * y.y);
}

// Adjoint of place_psf (wrap and fold): g_psf[b][y][x] = sum_k Re buf[k][b][(y - c) mod PY][(x - c) mod PX],
// c = S/2, summed over the scenes of the batch. buf: scenes x bands x PY x PX, g_psf: bands x S x S.
__kernel void gather_psf_grad(__global const real2* buf, __global real* g_psf, const int s, const int py, const int px,
                              const int bands, const int scenes) {
  const size_t gid = get_global_id(0);
  const size_t ss = (size_t)s * s;
  if (gid >= ss * bands) return;
  const int b = (int)(gid / ss);
  const int rem = (int)(gid - (size_t)b * ss);
  const int y = rem / s, x = rem - y * s;
  const int c = s / 2;
  const int u = ((y - c) % py + py) % py, v = ((x - c) % px + px) % px;
  real acc = R(0.0);
  for (int k = 0; k < scenes; ++k) acc += buf[(((size_t)k * bands + b) * py + u) * px + v].x;
  g_psf[gid] = acc;
}
