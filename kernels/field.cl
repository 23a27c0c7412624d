// The field just after the DOE, for all bands and object points in one launch.
//
// doe_field: out[p][y][x], shape planes x M x M complex (row-major), written in full: the DOE
// samples (i, j) of the N x N height map land at (offset + i, offset + j) (FieldStage passes
// offset 0: see PropagationStage::plan); everything else,
// and everything outside the circular aperture, is zero (so the buffer needs no clearing).
// height_m: designs x N x N real, row-major. k_per_m[p] = 2π/λ, dn[p] = n(λ) - 1 per plane (planes reals).
// Object points (include/qdo/data/config.hpp ObjectPoint): point_tab, points x 4 reals per point
// (x0, y0, d, R0): the point at (x0, y0) at distance d (metres), R0 = sqrt(x0² + y0² + d²);
// d <= 0 is a plane wave whose direction cosines (α, β) sit in the (x0, y0) slots.
// Source phase k·src (point_source below), the exact spherical phase minus the constant k·R0:
//   on-axis:  src = r²/(sqrt(r² + d²) + d) (the expression qdo used before object points: bit-identical)
//   off-axis: src = (r² - 2 (x x0 + y y0)) / (sqrt((x-x0)² + (y-y0)² + d²) + R0), the same difference
//             sqrt(..) - R0 written without cancellation, so float32 keeps ~1e-4 rad where k·R0
//             (1.6e7 rad at 1 m) would lose everything (REFERENCE §1)
//   plane wave: src = -(x α + y β).
// The aperture: with use_amp = 0 the test compares the integer pixel radius² with r_ap2_px, half an
// integer computed in double on the host (SystemConfig::aperture_inside_px2: r <= R or r < R as
// aperture_edge), so boundary samples agree in every precision; with use_amp = 1 (aperture_edge
// "area") sample (i, j) is weighted by amp[i * n + j] (N x N reals, aperture_transmission in
// optics.hpp: the fraction of its cell inside the circle, whose centre may sit off the grid's centre)
// and is inside when that is > 0. amp is a one-element buffer, never read, when use_amp = 0.
// Groups: designs x points, design-major (group g uses height map g / points and point g % points);
// plane b (of `planes` in all) belongs to group b / bands_per_group. planes = designs x points x bands.
// NDRange (columns rounded up to the work-group size, rows, groups): each work item computes its
// sample's aperture test, source term and height once and writes the sample of every band of its
// group (the band loop inside: 31 bands share one square root and one height read).

// The source term src (metres) of sample (x, y), r2 = x² + y², for the point at pt[0..3] (above).
inline real point_source(const real x, const real y, const real r2, __global const real* pt) {
  const real x0 = pt[0], y0 = pt[1], d = pt[2];
  if (x0 == R(0.0) && y0 == R(0.0)) return d > R(0.0) ? r2 / (sqrt(r2 + d * d) + d) : R(0.0);
  if (d > R(0.0)) {
    const real dx = x - x0, dy = y - y0;
    return (r2 - R(2.0) * (x * x0 + y * y0)) / (sqrt(dx * dx + dy * dy + d * d) + pt[3]);
  }
  return -(x * x0 + y * y0);
}

__kernel void doe_field(__global const real* height_m, __global const real* k_per_m, __global const real* dn,
                        __global real2* out, const int bands_per_group, const int n, const int m, const int offset,
                        const int bands, const real pitch_m, __global const real* point_tab, const int points,
                        const real r_ap2_px, __global const real* amp, const int use_amp) {
  const int wx = (int)get_global_id(0), wy = (int)get_global_id(1), g = (int)get_global_id(2);
  if (wx >= m || wy >= m || g * bands_per_group >= bands) return;
  const int d = g / points, pt = g - d * points;
  const int i = wy - offset, j = wx - offset;
  bool inside = false;
  real src = R(0.0), h = R(0.0), a = R(1.0);
  if (i >= 0 && i < n && j >= 0 && j < n) {
    const int di = i - n / 2, dj = j - n / 2;
    const real y = (real)di * pitch_m, x = (real)dj * pitch_m;
    const real r2 = x * x + y * y;
    if (use_amp) a = amp[i * n + j];
    if (use_amp ? a > R(0.0) : (real)(di * di + dj * dj) <= r_ap2_px) {  // integer pixel radius²: exact in float too
      inside = true;
      src = point_source(x, y, r2, point_tab + 4 * pt);
      h = height_m[(size_t)d * n * n + i * n + j];
    }
  }
  for (int b = g * bands_per_group; b < (g + 1) * bands_per_group; ++b) {
    real2 v = (real2)(R(0.0), R(0.0));
    if (inside) v = cexpi(k_per_m[b] * (src + dn[b] * h));
    if (use_amp) v *= a;
    out[((size_t)b * m + wy) * m + wx] = v;
  }
}

#if QDO_PHASE_FP64 && !QDO_FP64
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
// doe_field with the phase in double on a float32 field ("float32 with float64 phase"): same
// layout and arguments as doe_field, but k_per_m, dn, pitch_m, point_tab and r_ap2_px are
// double, and the phase and its sine/cosine are evaluated in double before rounding the field
// to float. Built only with -DQDO_PHASE_FP64=1 on devices with cl_khr_fp64.
inline double point_source_d(const double x, const double y, const double r2, __global const double* pt) {
  const double x0 = pt[0], y0 = pt[1], d = pt[2];
  if (x0 == 0.0 && y0 == 0.0) return d > 0.0 ? r2 / (sqrt(r2 + d * d) + d) : 0.0;
  if (d > 0.0) {
    const double dx = x - x0, dy = y - y0;
    return (r2 - 2.0 * (x * x0 + y * y0)) / (sqrt(dx * dx + dy * dy + d * d) + pt[3]);
  }
  return -(x * x0 + y * y0);
}
__kernel void doe_field_p64(__global const real* height_m, __global const double* k_per_m, __global const double* dn,
                            __global real2* out, const int bands_per_group, const int n, const int m, const int offset,
                            const int bands, const double pitch_m, __global const double* point_tab, const int points,
                            const double r_ap2_px, __global const real* amp, const int use_amp) {
  const int wx = (int)get_global_id(0), wy = (int)get_global_id(1), g = (int)get_global_id(2);
  if (wx >= m || wy >= m || g * bands_per_group >= bands) return;
  const int d = g / points, pt = g - d * points;
  const int i = wy - offset, j = wx - offset;
  bool inside = false;
  double src = 0.0, h = 0.0;
  real a = 1.0f;
  if (i >= 0 && i < n && j >= 0 && j < n) {
    const int di = i - n / 2, dj = j - n / 2;
    const double y = (double)di * pitch_m, x = (double)dj * pitch_m;
    const double r2 = x * x + y * y;
    if (use_amp) a = amp[i * n + j];
    if (use_amp ? a > 0.0f : (double)(di * di + dj * dj) <= r_ap2_px) {
      inside = true;
      src = point_source_d(x, y, r2, point_tab + 4 * pt);
      h = (double)height_m[(size_t)d * n * n + i * n + j];
    }
  }
  for (int b = g * bands_per_group; b < (g + 1) * bands_per_group; ++b) {
    real2 v = (real2)(0.0f, 0.0f);
    if (inside) {
      double c;
      const double s = sincos(k_per_m[b] * (src + dn[b] * h), &c);
      v = (real2)((float)c, (float)s);
      if (use_amp) v *= a;
    }
    out[((size_t)b * m + wy) * m + wx] = v;
  }
}
#endif

// --- Adjoints (vector-Jacobian products; gradient convention of include/qdo/physics/adjoint.hpp:
// complex gradients g = dL/dRe + i dL/dIm) ---

// VJP of the DOE phase of one design: dH[i][j] = sum_p k_p dn_p Re(conj(gU1) i U1) over all
// planes p (U1 with its aperture weight amp when use_amp) (points x bands, point-major: the gradients of all object points add up), U1
// recomputed exactly as doe_field does. gu: planes x M x M; dh: N x N; point_tab as doe_field.
__kernel void phase_vjp(__global const real* height_m, __global const real* k_per_m, __global const real* dn,
                        __global const real2* gu, __global real* dh, const int n, const int m, const int offset,
                        const int bands, const real pitch_m, __global const real* point_tab, const int points,
                        const real r_ap2_px, __global const real* amp, const int use_amp) {
  const size_t gid = get_global_id(0);
  if (gid >= (size_t)n * n) return;
  const int i = (int)(gid / n), j = (int)(gid - (size_t)i * n);
  const int di = i - n / 2, dj = j - n / 2;
  const real y = (real)di * pitch_m, x = (real)dj * pitch_m;
  const real r2 = x * x + y * y;
  const real a = use_amp ? amp[gid] : R(1.0);
  real acc = R(0.0);
  if (use_amp ? a > R(0.0) : (real)(di * di + dj * dj) <= r_ap2_px) {  // integer pixel radius²: exact in float too
    const real h = height_m[gid];
    const int per_point = bands / points;
    for (int pt = 0; pt < points; ++pt) {
      const real src = point_source(x, y, r2, point_tab + 4 * pt);
      for (int b = pt * per_point; b < (pt + 1) * per_point; ++b) {
        const real2 u = cexpi(k_per_m[b] * (src + dn[b] * h));
        const real2 g = gu[(size_t)b * m * m + (size_t)(offset + i) * m + (offset + j)];
        acc += k_per_m[b] * dn[b] * (g.y * u.x - g.x * u.y);
      }
    }
  }
  dh[gid] = use_amp ? a * acc : acc;
}
