// Transfer-function multiplication in the frequency domain, all bands in one launch.
// spec: bands x M x M complex (row-major, FFT order on both axes), multiplied in place.

// Fresnel: exp(-iπλz(fx² + fy²)) = t[b][ky] * t[b][kx] with t[b][k] = exp(-iπλz f_k²),
// a bands x M complex table computed in double on the host (separable, so the float32 path
// never evaluates a phase of thousands of radians).
// 3-D NDRange (columns rounded up to the work-group size, rows, bands): no integer division.
__kernel void tf_separable(__global real2* spec, __global const real2* t, const int m, const int bands) {
  const int kx = (int)get_global_id(0), ky = (int)get_global_id(1), b = (int)get_global_id(2);
  if (kx >= m || ky >= m || b >= bands) return;
  const size_t gid = ((size_t)b * m + ky) * m + kx;
  spec[gid] = cmul(spec[gid], cmul(t[(size_t)b * m + ky], t[(size_t)b * m + kx]));
}

// Any transfer function given as a full bands x M x M complex table (the band-limited
// angular spectrum; zeros beyond its band limit), computed in double on the host.
__kernel void tf_table(__global real2* spec, __global const real2* table, const int count) {
  const size_t gid = get_global_id(0);
  if (gid >= (size_t)count) return;
  spec[gid] = cmul(spec[gid], table[gid]);
}

// Fused transfer function + sampling check (the forward PSF pass): multiplies spec by the
// transfer function in place and accumulates, per work-group, three energies:
//   [0] Σ|spec|² before the TF (total), [1] the part beyond the per-band frequency limit
//   (index |k| > klim[b] on either axis: the aliased fraction), [2] Σ|spec · TF|² after it
//   (by Parseval, M² times the field energy after the inverse FFT, so no pass over the
//   propagated field is needed for it).
// spec: bands x M x M complex (FFT order), in place. Fresnel (TF_SEPARABLE = 1): t is the
// bands x M table of tf_separable; otherwise t is the full bands x M x M table of tf_table.
// NDRange (groups_per_band * local, bands), local (local, 1); partial: bands x groups x 3.
#define QDO_TF_ENERGY(NAME, TF_SEPARABLE)                                                             \
  __kernel void NAME(__global real2* spec, __global const real2* t, __global const int* klim,         \
                     __global real* partial, const int m, const int groups_per_band,                   \
                     __local real* scratch) {                                                          \
    const int b = get_group_id(1), g = get_group_id(0), lid = get_local_id(0), ls = get_local_size(0);\
    const size_t mm = (size_t)m * m;                                                                   \
    const int lim = klim[b];                                                                           \
    real tot = R(0.0), beyond = R(0.0), after = R(0.0);                                                \
    /* rows ky = g, g + G, ... of the band; the lanes of the group stride along the row (no     */ \
    /* integer division per element)                                                            */ \
    for (int ky = g; ky < m; ky += groups_per_band) {                                                  \
      const int fy = ky < (m + 1) / 2 ? ky : ky - m;                                                   \
      const bool row_beyond = abs(fy) > lim;                                                           \
      const real2 ty = t[(size_t)b * m + ky];                                                          \
      const size_t row = (size_t)b * mm + (size_t)ky * m;                                              \
      for (int kx = lid; kx < m; kx += ls) {                                                           \
        const int fx = kx < (m + 1) / 2 ? kx : kx - m;                                                 \
        const size_t idx = row + kx;                                                                   \
        const real2 v = spec[idx];                                                                     \
        const real p = v.x * v.x + v.y * v.y;                                                          \
        tot += p;                                                                                      \
        if (row_beyond || abs(fx) > lim) beyond += p;                                                  \
        const real2 tf = TF_SEPARABLE ? cmul(ty, t[(size_t)b * m + kx]) : t[idx];                      \
        const real2 w = cmul(v, tf);                                                                   \
        after += w.x * w.x + w.y * w.y;                                                                \
        spec[idx] = w;                                                                                 \
      }                                                                                                \
    }                                                                                                  \
    scratch[3 * lid] = tot;                                                                            \
    scratch[3 * lid + 1] = beyond;                                                                     \
    scratch[3 * lid + 2] = after;                                                                      \
    barrier(CLK_LOCAL_MEM_FENCE);                                                                      \
    for (int s = ls / 2; s > 0; s >>= 1) {                                                             \
      if (lid < s)                                                                                     \
        for (int c = 0; c < 3; ++c) scratch[3 * lid + c] += scratch[3 * (lid + s) + c];               \
      barrier(CLK_LOCAL_MEM_FENCE);                                                                    \
    }                                                                                                  \
    if (lid == 0)                                                                                      \
      for (int c = 0; c < 3; ++c) partial[((size_t)b * groups_per_band + g) * 3 + c] = scratch[c];    \
  }
QDO_TF_ENERGY(tf_energy_separable, 1)
QDO_TF_ENERGY(tf_energy_table, 0)

// sums[b][c] = Σ_g partial[b][g][c] for c < 3 (one work-item per band); partial and sums as
// tf_energy_*: bands x groups x 3 and bands x 3.
__kernel void finalize_sums3(__global const real* partial, __global real* sums, const int groups_per_band,
                             const int bands) {
  const int b = get_global_id(0);
  if (b >= bands) return;
  real a0 = R(0.0), a1 = R(0.0), a2 = R(0.0);
  for (int g = 0; g < groups_per_band; ++g) {
    const size_t o = ((size_t)b * groups_per_band + g) * 3;
    a0 += partial[o];
    a1 += partial[o + 1];
    a2 += partial[o + 2];
  }
  sums[3 * b] = a0;
  sums[3 * b + 1] = a1;
  sums[3 * b + 2] = a2;
}
