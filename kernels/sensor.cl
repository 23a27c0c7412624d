// RGB sensor integration (Eq. 7) with reproducible noise.

// rgb[k][c][p] = sum_b srf[c][b] * cube[k][b][p] (+ noise) for scenes k. cube: scenes x bands x HW
// real, srf: 3 x bands (rows normalised to unit sum), rgb: scenes x 3 x HW. Noise for element
// (k, c, p) uses counter (k*HW + p)*3 + c:
// Poisson shot noise with full_well photons at 1.0 (skipped when full_well <= 0), then
// Gaussian read noise of `sigma`. Exact inversion below a mean of 64, rounded normal above.
__kernel void sensor_integrate(__global const real* cube, __constant real* srf, __global real* rgb, const int hw,
                               const int bands, const real sigma, const real full_well, const uint seed_lo,
                               const uint seed_hi, const int scenes) {
  const size_t gid = get_global_id(0);
  if (gid >= (size_t)hw * 3 * scenes) return;
  const int k = (int)(gid / ((size_t)hw * 3));
  const int rem = (int)(gid - (size_t)k * hw * 3);
  const int c = rem / hw;
  const int p = rem - c * hw;
  __global const real* scene = cube + (size_t)k * bands * hw;
  real v = R(0.0);
  for (int b = 0; b < bands; ++b) v += srf[c * bands + b] * scene[(size_t)b * hw + p];
  v = sensor_noise(v, ((ulong)k * hw + p) * 3 + c, 0x51ed27u, sigma, full_well, seed_lo, seed_hi);
  rgb[gid] = v;
}
