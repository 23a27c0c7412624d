// Transfer-function multiplication in the frequency domain, all bands in one launch.
// spec: bands x M x M complex (row-major, FFT order on both axes), multiplied in place.

// Fresnel: exp(-iπλz(fx² + fy²)) = t[b][ky] * t[b][kx] with t[b][k] = exp(-iπλz f_k²),
// a bands x M complex table computed in double on the host (separable, so the float32 path
// never evaluates a phase of thousands of radians).
__kernel void tf_separable(__global real2* spec, __global const real2* t, const int m, const int bands) {
  const size_t gid = get_global_id(0);
  const size_t mm = (size_t)m * m;
  if (gid >= mm * bands) return;
  const int b = (int)(gid / mm);
  const int rem = (int)(gid - (size_t)b * mm);
  const int ky = rem / m, kx = rem - ky * m;
  spec[gid] = cmul(spec[gid], cmul(t[(size_t)b * m + ky], t[(size_t)b * m + kx]));
}

// Any transfer function given as a full bands x M x M complex table (the band-limited
// angular spectrum; zeros beyond its band limit), computed in double on the host.
__kernel void tf_table(__global real2* spec, __global const real2* table, const int count) {
  const size_t gid = get_global_id(0);
  if (gid >= (size_t)count) return;
  spec[gid] = cmul(spec[gid], table[gid]);
}

// Sampling check: per work-group partial sums of |spec|², total and beyond the per-band
// frequency limit (index |k| > klim[b] on either axis, klim in bins).
// partial: bands x groups_per_band x 2 (total, beyond). One band per group row.
__kernel void spectrum_energy(__global const real2* spec, __global const int* klim, __global real* partial,
                              const int m, const int groups_per_band, __local real* scratch) {
  const int b = get_group_id(1);
  const int g = get_group_id(0);
  const int lid = get_local_id(0);
  const int ls = get_local_size(0);
  const size_t mm = (size_t)m * m;
  real tot = R(0.0), beyond = R(0.0);
  for (size_t e = (size_t)g * ls + lid; e < mm; e += (size_t)groups_per_band * ls) {
    const int ky = (int)(e / m), kx = (int)(e - (size_t)ky * m);
    const int fy = ky < (m + 1) / 2 ? ky : ky - m, fx = kx < (m + 1) / 2 ? kx : kx - m;
    const real2 v = spec[(size_t)b * mm + e];
    const real p = v.x * v.x + v.y * v.y;
    tot += p;
    if (abs(fy) > klim[b] || abs(fx) > klim[b]) beyond += p;
  }
  scratch[2 * lid] = tot;
  scratch[2 * lid + 1] = beyond;
  barrier(CLK_LOCAL_MEM_FENCE);
  for (int s = ls / 2; s > 0; s >>= 1) {
    if (lid < s) {
      scratch[2 * lid] += scratch[2 * (lid + s)];
      scratch[2 * lid + 1] += scratch[2 * (lid + s) + 1];
    }
    barrier(CLK_LOCAL_MEM_FENCE);
  }
  if (lid == 0) {
    partial[((size_t)b * groups_per_band + g) * 2] = scratch[0];
    partial[((size_t)b * groups_per_band + g) * 2 + 1] = scratch[1];
  }
}
