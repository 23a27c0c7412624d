// The field just after the DOE, for all bands in one launch.
//
// doe_field: out[b][y][x], shape bands x M x M complex (row-major), written in full: the DOE
// samples (i, j) of the N x N height map land at (offset + i, offset + j) (FieldStage passes
// offset 0: see PropagationStage::plan); everything else,
// and everything outside the circular aperture, is zero (so the buffer needs no clearing).
// height_m: N x N real, row-major. k_per_m[b] = 2π/λ_b, dn[b] = n(λ_b) - 1 (bands reals).
// Phase = k (r²/(sqrt(r² + d²) + d) + dn H): the source term is the exact spherical phase
// minus the constant k·d, written without cancellation, so float32 keeps ~1e-6 rad
// accuracy where k·d itself (1.6e7 rad) would lose everything. d <= 0 means a plane wave.
// The aperture test compares the integer pixel radius² with r_ap2_px, half an integer computed in
// double on the host (SystemConfig::aperture_inside_px2: r <= R or r < R as aperture_edge), so
// boundary samples agree in every precision.
// Several designs can share one launch: plane b (of `bands` planes in all) uses height map
// b / bands_per_design of height_m (designs x N x N).
// NDRange (columns rounded up to the work-group size, rows, designs): each work item computes its
// sample's aperture test, source term and height once and writes the sample of every band of its
// design (the band loop inside: 31 bands share one square root and one height read).
__kernel void doe_field(__global const real* height_m, __global const real* k_per_m, __global const real* dn,
                        __global real2* out, const int bands_per_design, const int n, const int m, const int offset,
                        const int bands,
                        const real pitch_m, const real distance_m, const real r_ap2_px) {
  const int wx = (int)get_global_id(0), wy = (int)get_global_id(1), d = (int)get_global_id(2);
  if (wx >= m || wy >= m || d * bands_per_design >= bands) return;
  const int i = wy - offset, j = wx - offset;
  bool inside = false;
  real src = R(0.0), h = R(0.0);
  if (i >= 0 && i < n && j >= 0 && j < n) {
    const int di = i - n / 2, dj = j - n / 2;
    const real y = (real)di * pitch_m, x = (real)dj * pitch_m;
    const real r2 = x * x + y * y;
    if ((real)(di * di + dj * dj) <= r_ap2_px) {  // integer pixel radius²: exact in float too
      inside = true;
      src = distance_m > R(0.0) ? r2 / (sqrt(r2 + distance_m * distance_m) + distance_m) : R(0.0);
      h = height_m[(size_t)d * n * n + i * n + j];
    }
  }
  for (int b = d * bands_per_design; b < (d + 1) * bands_per_design; ++b) {
    real2 v = (real2)(R(0.0), R(0.0));
    if (inside) v = cexpi(k_per_m[b] * (src + dn[b] * h));
    out[((size_t)b * m + wy) * m + wx] = v;
  }
}

#if QDO_PHASE_FP64 && !QDO_FP64
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
// doe_field with the phase in double on a float32 field ("float32 with float64 phase"): same
// layout and arguments as doe_field, but k_per_m, dn, pitch_m, distance_m and r_ap2_px are
// double, and the phase and its sine/cosine are evaluated in double before rounding the field
// to float. Built only with -DQDO_PHASE_FP64=1 on devices with cl_khr_fp64.
__kernel void doe_field_p64(__global const real* height_m, __global const double* k_per_m, __global const double* dn,
                            __global real2* out, const int bands_per_design, const int n, const int m, const int offset,
                            const int bands, const double pitch_m, const double distance_m, const double r_ap2_px) {
  const int wx = (int)get_global_id(0), wy = (int)get_global_id(1), d = (int)get_global_id(2);
  if (wx >= m || wy >= m || d * bands_per_design >= bands) return;
  const int i = wy - offset, j = wx - offset;
  bool inside = false;
  double src = 0.0, h = 0.0;
  if (i >= 0 && i < n && j >= 0 && j < n) {
    const int di = i - n / 2, dj = j - n / 2;
    const double y = (double)di * pitch_m, x = (double)dj * pitch_m;
    const double r2 = x * x + y * y;
    if ((double)(di * di + dj * dj) <= r_ap2_px) {
      inside = true;
      src = distance_m > 0.0 ? r2 / (sqrt(r2 + distance_m * distance_m) + distance_m) : 0.0;
      h = (double)height_m[(size_t)d * n * n + i * n + j];
    }
  }
  for (int b = d * bands_per_design; b < (d + 1) * bands_per_design; ++b) {
    real2 v = (real2)(0.0f, 0.0f);
    if (inside) {
      double c;
      const double s = sincos(k_per_m[b] * (src + dn[b] * h), &c);
      v = (real2)((float)c, (float)s);
    }
    out[((size_t)b * m + wy) * m + wx] = v;
  }
}
#endif

// --- Adjoints (vector-Jacobian products; gradient convention of include/qdo/adjoint.hpp:
// complex gradients g = dL/dRe + i dL/dIm) ---

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
