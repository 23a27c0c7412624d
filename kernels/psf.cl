// Intensity, per-band sums, normalisation and area resampling of the PSF stack.

// Per-band partial sums. NDRange (groups_per_band * local, bands), local (local, 1).
// x: bands x len real (band_sums) or complex (band_energy: sums |x|²).
// partial: bands x groups_per_band.
#define QDO_BAND_REDUCE(NAME, TYPE, EXPR)                                                             \
  __kernel void NAME(__global const TYPE* x, const int len, __global real* partial, const int groups_per_band, \
                     __local real* scratch) {                                                           \
    const int b = get_group_id(1), g = get_group_id(0), lid = get_local_id(0), ls = get_local_size(0); \
    real acc = R(0.0);                                                                                  \
    for (size_t e = (size_t)g * ls + lid; e < (size_t)len; e += (size_t)groups_per_band * ls) {        \
      const TYPE v = x[(size_t)b * len + e];                                                            \
      acc += EXPR;                                                                                      \
    }                                                                                                   \
    scratch[lid] = acc;                                                                                 \
    barrier(CLK_LOCAL_MEM_FENCE);                                                                       \
    for (int s = ls / 2; s > 0; s >>= 1) {                                                              \
      if (lid < s) scratch[lid] += scratch[lid + s];                                                    \
      barrier(CLK_LOCAL_MEM_FENCE);                                                                     \
    }                                                                                                   \
    if (lid == 0) partial[(size_t)b * groups_per_band + g] = scratch[0];                                \
  }
QDO_BAND_REDUCE(band_sums, real, v)
QDO_BAND_REDUCE(band_energy, real2, v.x* v.x + v.y * v.y)

// sums[b] = sum_g partial[b][g] (one work-item per band).
__kernel void finalize_sums(__global const real* partial, __global real* sums, const int groups_per_band,
                            const int bands) {
  const int b = get_global_id(0);
  if (b >= bands) return;
  real acc = R(0.0);
  for (int g = 0; g < groups_per_band; ++g) acc += partial[(size_t)b * groups_per_band + g];
  sums[b] = acc;
}

// x[b][e] /= sums[b] where sums[b] > 0; x: bands x len.
__kernel void scale_by_sums(__global real* x, __global const real* sums, const int len, const int bands) {
  const size_t gid = get_global_id(0);
  if (gid >= (size_t)len * bands) return;
  const real s = sums[gid / len];
  if (s > R(0.0)) x[gid] /= s;
}

// Area resampling: out[b][oy][ox] = sum_{ty,tx} w[oy][ty] w[c][tx] in[b][start[oy]+ty][start[c]+tx],
// c = col_offset + ox. in: bands x N x N, out: bands x S x S, start: (col_offset + S) ints, w:
// (col_offset + S) x taps reals (zero where the tap falls outside the input: such taps are read
// clamped and add nothing); col_offset 0 (one table for both axes) or S (the columns' own table
// after the rows', AreaWeights::make_xy).
__kernel void resample_area(__global const real* in, __global real* out, __global const int* start,
                            __global const real* w, const int n, const int s, const int taps, const int bands,
                            const int col_offset) {
  const size_t gid = get_global_id(0);
  const size_t ss = (size_t)s * s;
  if (gid >= ss * bands) return;
  const int b = (int)(gid / ss);
  const int rem = (int)(gid - (size_t)b * ss);
  const int oy = rem / s, ox = rem - oy * s;
  // Branch-free (so the work-group loop vectorizes): a tap outside the input has weight 0
  // (AreaWeights::make), and its index is clamped into the input only to stay in bounds.
  real acc = R(0.0);
  for (int ty = 0; ty < taps; ++ty) {
    const real wy = w[oy * taps + ty];
    const int iy = clamp(start[oy] + ty, 0, n - 1);
    __global const real* row = in + ((size_t)b * n + iy) * n;
    real racc = R(0.0);
    const int cx = col_offset + ox;  // the columns' table entry (the rows' when col_offset = 0)
    for (int tx = 0; tx < taps; ++tx) racc += w[cx * taps + tx] * row[clamp(start[cx] + tx, 0, n - 1)];
    acc += wy * racc;
  }
  out[gid] = acc;
}

// Fused intensity + crop + per-band partial sums (the forward PSF pass after the inverse FFT):
// psf[b][i][j] = |field[b][offset + i][offset + j]|² (unnormalised) and partial[b][g] = the
// work-group's share of Σ_ij psf[b][i][j]. field: bands x M x M complex; psf: bands x N x N
// real (row-major); partial: bands x groups_per_band (finalize_sums completes the sums).
// NDRange (groups_per_band * local, bands), local (local, 1).
__kernel void intensity_crop_sums(__global const real2* field, __global real* psf, const int n, const int m,
                                  const int offset, __global real* partial, const int groups_per_band,
                                  __local real* scratch) {
  const int b = get_group_id(1), g = get_group_id(0), lid = get_local_id(0), ls = get_local_size(0);
  const size_t nn = (size_t)n * n;
  real acc = R(0.0);
  for (int i = g; i < n; i += groups_per_band) {  // rows i = g, g + G, ...; lanes along the row
    const size_t src = (size_t)b * m * m + (size_t)(offset + i) * m + offset, dst = (size_t)b * nn + (size_t)i * n;
    for (int j = lid; j < n; j += ls) {
      const real2 v = field[src + j];
      const real p = v.x * v.x + v.y * v.y;
      psf[dst + j] = p;
      acc += p;
    }
  }
  scratch[lid] = acc;
  barrier(CLK_LOCAL_MEM_FENCE);
  for (int s = ls / 2; s > 0; s >>= 1) {
    if (lid < s) scratch[lid] += scratch[lid + s];
    barrier(CLK_LOCAL_MEM_FENCE);
  }
  if (lid == 0) partial[(size_t)b * groups_per_band + g] = scratch[0];
}

// --- Adjoints (vector-Jacobian products; gradient convention of include/qdo/physics/adjoint.hpp:
// complex gradients g = dL/dRe + i dL/dIm) ---

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
