// The radial PSF engine (include/qdo/physics/radial.hpp): N/2 rings, K transform frequencies, J output radii,
// U distinct sensor values, S x S sensor, `bands` planes. Complex values are real2, arrays row-major
// with the band index outermost. 1-D kernels use the fixed work-group size and check their index.

#define RADIAL_BC 8  // bands per work-item in radial_matmul (kBandChunk in src/physics/radial.cpp)
#ifndef RADIAL_TILE
#define RADIAL_TILE 128  // columns per local-memory tile: the work-group size (-D from the host)
#endif

// c[b][r] = source[b][r] * exp(i kdn[b] h[r]): source bands x N/2 real2 (the point source's phase at
// the ring middle, computed in double on the host, 0 outside the aperture); kdn: bands; h: N/2 ring
// heights (m); c: bands x N/2 real2. The DOE phase is at most a few 2 pi, so float32 keeps ~1e-6 rad.
__kernel void radial_field(__global const real2* source, __global const real* kdn, __global const real* h,
                           __global real2* c, const int rings, const int bands) {
  const size_t gid = get_global_id(0);
  if (gid >= (size_t)rings * bands) return;
  const int b = (int)(gid / rings), r = (int)(gid - (size_t)b * rings);
  c[gid] = cmul(source[gid], cexpi(kdn[b] * h[r]));
}

// y[b][r] = sum_c M[r][c] x[b][c] for a real matrix M (rows x cols) given column-major,
// mt[c * rows + r], and complex x (bands x cols), y (bands x rows). NDRange
// (global_for(rows), ceil(bands / RADIAL_BC)), local (RADIAL_TILE, 1): work-item (r, chunk) keeps
// RADIAL_BC complex accumulators; x is staged through local memory one tile of columns at a time.
__kernel void radial_matmul(__global const real* mt, __global const real2* x, __global real2* y, const int rows,
                            const int cols, const int bands) {
  __local real2 xs[RADIAL_BC][RADIAL_TILE];
  const int r = get_global_id(0), lid = get_local_id(0);
  const int b0 = get_global_id(1) * RADIAL_BC;
  real2 acc[RADIAL_BC];
  for (int q = 0; q < RADIAL_BC; ++q) acc[q] = (real2)(R(0.0), R(0.0));
  for (int c0 = 0; c0 < cols; c0 += RADIAL_TILE) {
    const int c = c0 + lid;
    for (int q = 0; q < RADIAL_BC; ++q)
      xs[q][lid] = (c < cols && b0 + q < bands) ? x[(size_t)(b0 + q) * cols + c] : (real2)(R(0.0), R(0.0));
    barrier(CLK_LOCAL_MEM_FENCE);
    const int len = min(RADIAL_TILE, cols - c0);
    if (r < rows) {
      for (int cc = 0; cc < len; ++cc) {
        const real m = mt[(size_t)(c0 + cc) * rows + r];
        for (int q = 0; q < RADIAL_BC; ++q) acc[q] += m * xs[q][cc];
      }
    }
    barrier(CLK_LOCAL_MEM_FENCE);
  }
  if (r >= rows) return;
  for (int q = 0; q < RADIAL_BC; ++q)
    if (b0 + q < bands) y[(size_t)(b0 + q) * rows + r] = acc[q];
}

// out[e] = x[e] * t[e] (conj_t = 0) or x[e] * conj(t[e]) (conj_t = 1); x, t, out: len real2
// (out may alias x). t is the bands x K transfer function.
__kernel void radial_cmul_table(__global const real2* x, __global const real2* t, __global real2* out, const int len,
                                const int conj_t) {
  const size_t gid = get_global_id(0);
  if (gid >= (size_t)len) return;
  real2 tv = t[gid];
  if (conj_t) tv.y = -tv.y;
  out[gid] = cmul(x[gid], tv);
}

// i[e] = |u[e]|²; u: len real2, i: len real (bands x J).
__kernel void radial_intensity(__global const real2* u, __global real* i, const int len) {
  const size_t gid = get_global_id(0);
  if (gid >= (size_t)len) return;
  const real2 v = u[gid];
  i[gid] = v.x * v.x + v.y * v.y;
}

// g_u[e] = 2 g_i[e] u[e] (adjoint of the intensity); len elements (bands x J).
__kernel void radial_intensity_vjp(__global const real* g_i, __global const real2* u, __global real2* g_u, const int len) {
  const size_t gid = get_global_id(0);
  if (gid >= (size_t)len) return;
  g_u[gid] = R(2.0) * g_i[gid] * u[gid];
}

// Sparse rows: y[b][r] = sum_{e in [start[r], start[r+1])} val[e] x[b][col[e]], for every band.
// start: rows + 1, col/val: nnz, x: bands x cols, y: bands x rows. The render matrix A (U x J) and
// its transpose (J x U) both go through here.
__kernel void radial_csr_apply(__global const int* start, __global const int* col, __global const real* val,
                               __global const real* x, __global real* y, const int rows, const int cols,
                               const int bands) {
  const size_t gid = get_global_id(0);
  if (gid >= (size_t)rows * bands) return;
  const int b = (int)(gid / rows), r = (int)(gid - (size_t)b * rows);
  __global const real* xb = x + (size_t)b * cols;
  real acc = R(0.0);
  for (int e = start[r]; e < start[r + 1]; ++e) acc += val[e] * xb[col[e]];
  y[gid] = acc;
}

// out[b] = sum_e x[b][e] * y[b * y_band_stride + e] over len elements (y_band_stride 0: one y for
// all bands). One work-group per band: NDRange (local, bands), local (local, 1).
__kernel void radial_band_dot(__global const real* x, __global const real* y, const int y_band_stride, const int len,
                              __global real* out, __local real* scratch) {
  const int b = get_group_id(1), lid = get_local_id(0), ls = get_local_size(0);
  real acc = R(0.0);
  for (int e = lid; e < len; e += ls) acc += x[(size_t)b * len + e] * y[(size_t)b * y_band_stride + e];
  scratch[lid] = acc;
  barrier(CLK_LOCAL_MEM_FENCE);
  for (int s = ls / 2; s > 0; s >>= 1) {
    if (lid < s) scratch[lid] += scratch[lid + s];
    barrier(CLK_LOCAL_MEM_FENCE);
  }
  if (lid == 0) out[b] = scratch[0];
}

inline int radial_pair(int cy, int cx) {
  const int hi = max(cy, cx), lo = min(cy, cx);
  return hi * (hi + 1) / 2 + lo;
}

// psf[b][oy][ox] = v[b][pair(cls[oy], cls[ox])] / sums[b]; v: bands x U, cls: S, psf: bands x S x S.
__kernel void radial_expand(__global const real* v, __global const real* sums, __global const int* cls,
                            __global real* psf, const int s, const int unique, const int bands) {
  const size_t gid = get_global_id(0);
  const size_t ss = (size_t)s * s;
  if (gid >= ss * bands) return;
  const int b = (int)(gid / ss);
  const int rem = (int)(gid - (size_t)b * ss);
  const int oy = rem / s, ox = rem - oy * s;
  const real sum = sums[b];
  const real val = v[(size_t)b * unique + radial_pair(cls[oy], cls[ox])];
  psf[gid] = sum > R(0.0) ? val / sum : val;
}

// Adjoint of radial_expand's gather (before the normalisation): g_u[b][u] = sum of g[b][oy][ox]
// over the sensor pixels of pair u = (py[u], px[u]) (py <= px): rows of class py x columns of
// class px, and the transposed set when py != px. g: bands x S x S; class_start: classes + 1,
// members: S (CSR); g_u: bands x U.
__kernel void radial_fold(__global const real* g, __global const int* class_start, __global const int* members,
                          __global const int* py, __global const int* px, __global real* g_u, const int s,
                          const int unique, const int bands) {
  const size_t gid = get_global_id(0);
  if (gid >= (size_t)unique * bands) return;
  const int b = (int)(gid / unique), u = (int)(gid - (size_t)b * unique);
  const int cy = py[u], cx = px[u];
  __global const real* gb = g + (size_t)b * s * s;
  real acc = R(0.0);
  for (int a = class_start[cy]; a < class_start[cy + 1]; ++a)
    for (int c = class_start[cx]; c < class_start[cx + 1]; ++c) {
      const int oy = members[a], ox = members[c];
      acc += gb[(size_t)oy * s + ox];
      if (cy != cx) acc += gb[(size_t)ox * s + oy];
    }
  g_u[gid] = acc;
}

// Adjoint of the normalisation p = v / sum_b, sum_b = sum_u mult[u] v[b][u]:
// g_v[b][u] = (g_u[b][u] - mult[u] dots[b] / sums[b]) / sums[b], dots[b] = sum_u g_u[b][u] v[b][u].
// g_u, g_v: bands x U; mult: U; dots, sums: bands.
__kernel void radial_normalize_vjp(__global const real* g_u, __global const real* mult, __global const real* dots,
                                   __global const real* sums, __global real* g_v, const int unique, const int bands) {
  const size_t gid = get_global_id(0);
  if (gid >= (size_t)unique * bands) return;
  const int b = (int)(gid / unique), u = (int)(gid - (size_t)b * unique);
  const real sum = sums[b];
  g_v[gid] = sum > R(0.0) ? (g_u[gid] - mult[u] * dots[b] / sum) / sum : R(0.0);
}

// dL/dh[r] = sum_b kdn[b] Re(conj(g_c[b][r]) i c[b][r]); g_c, c: bands x N/2 real2; kdn: bands; g_h: N/2.
__kernel void radial_phase_ring_vjp(__global const real2* g_c, __global const real2* c, __global const real* kdn,
                                    __global real* g_h, const int rings, const int bands) {
  const int r = get_global_id(0);
  if (r >= rings) return;
  real acc = R(0.0);
  for (int b = 0; b < bands; ++b) {
    const real2 g = g_c[(size_t)b * rings + r], u = c[(size_t)b * rings + r];
    acc += kdn[b] * (g.y * u.x - g.x * u.y);
  }
  g_h[r] = acc;
}
