// The release's image formation (REFERENCE §1, as measured; include/qdo/physics/release.hpp): per band,
// bilinear up-sampling of the S x S scene to the N x N DOE grid, symmetric (mirror) padding to
// G x G, circular convolution with the PSF placed as the release's psf2otf places it, crop to
// N x N and bilinear down-sampling to S x S. Host code: src/physics/release.cpp; CPU reference
// (double): ref::release_blur (src/physics/release_reference.cpp).
//
// Bilinear resizing is TF2's tf.image.resize(BILINEAR): half-pixel centres, edge clamp, no
// antialias: output i samples the input at t = (i + 0.5) * in / out - 0.5, lo = max(floor(t), 0),
// hi = min(ceil(t), in - 1), value = x[lo] + (x[hi] - x[lo]) * (t - floor(t)).

inline void resize_tap(const int i, const int in, const int out, int* lo, int* hi, real* w) {
  const real t = ((real)i + R(0.5)) * (real)in / (real)out - R(0.5);
  const real f = floor(t);
  *lo = max((int)f, 0);
  *hi = min((int)ceil(t), in - 1);
  *w = t - f;
}

// Symmetric padding (tf.pad SYMMETRIC: the edge sample repeated): padded index k of a length-n
// signal padded by `before` -> source index. |k - before| stays below 2n (checked on the host).
inline int mirror_index(int k, const int before, const int n) {
  k -= before;
  if (k < 0) k = -k - 1;
  if (k >= n) k = 2 * n - 1 - k;
  return k;
}

// Scene (bands x S x S real) -> mirror-padded up-sampled scene (bands x G x G complex, imaginary
// part 0). One work-item per output sample; 1-D NDRange over bands * G * G.
__kernel void release_up_pad(__global const real* scene, __global real2* out, const int s, const int n, const int g,
                             const int before, const int bands) {
  const size_t gid = get_global_id(0);
  if (gid >= (size_t)bands * g * g) return;
  const int b = (int)(gid / ((size_t)g * g));
  const int rem = (int)(gid - (size_t)b * g * g);
  const int y = mirror_index(rem / g, before, n), x = mirror_index(rem % g, before, n);
  int y0, y1, x0, x1;
  real wy, wx;
  resize_tap(y, s, n, &y0, &y1, &wy);
  resize_tap(x, s, n, &x0, &x1, &wx);
  __global const real* p = scene + (size_t)b * s * s;
  const real top = p[y0 * s + x0] + (p[y0 * s + x1] - p[y0 * s + x0]) * wx;
  const real bot = p[y1 * s + x0] + (p[y1 * s + x1] - p[y1 * s + x0]) * wx;
  out[gid] = (real2)(top + (bot - top) * wy, R(0.0));
}

// PSF (bands x N x N real, axis at (N/2, N/2)) -> the release's OTF input (bands x G x G complex):
// zero-padded by psf_before rows/columns before, then circularly shifted so that padded index
// `split` lands at 0 (ifftshift). Gather form: every output sample is written.
__kernel void release_place_psf(__global const real* psf, __global real2* out, const int n, const int g,
                                const int psf_before, const int split, const int bands) {
  const size_t gid = get_global_id(0);
  if (gid >= (size_t)bands * g * g) return;
  const int b = (int)(gid / ((size_t)g * g));
  const int rem = (int)(gid - (size_t)b * g * g);
  const int y = (rem / g + split) % g - psf_before, x = (rem % g + split) % g - psf_before;
  real v = R(0.0);
  if (y >= 0 && y < n && x >= 0 && x < n) v = psf[((size_t)b * n + y) * n + x];
  out[gid] = (real2)(v, R(0.0));
}

// a *= b elementwise (complex), 1-D over count.
__kernel void release_cmul(__global real2* a, __global const real2* b, const int count) {
  const size_t gid = get_global_id(0);
  if (gid >= (size_t)count) return;
  const real2 u = a[gid], v = b[gid];
  a[gid] = (real2)(u.x * v.x - u.y * v.y, u.x * v.y + u.y * v.x);
}

// Convolved padded scene (bands x G x G complex; real part used) -> crop [before, before + N) in
// both axes -> bilinear N -> S (bands x S x S real). 1-D over bands * S * S.
__kernel void release_crop_down(__global const real2* conv, __global real* out, const int s, const int n, const int g,
                                const int before, const int bands) {
  const size_t gid = get_global_id(0);
  if (gid >= (size_t)bands * s * s) return;
  const int b = (int)(gid / ((size_t)s * s));
  const int rem = (int)(gid - (size_t)b * s * s);
  int y0, y1, x0, x1;
  real wy, wx;
  resize_tap(rem / s, n, s, &y0, &y1, &wy);
  resize_tap(rem % s, n, s, &x0, &x1, &wx);
  __global const real2* p = conv + (size_t)b * g * g + (size_t)before * g + before;
  const real top = p[y0 * g + x0].x + (p[y0 * g + x1].x - p[y0 * g + x0].x) * wx;
  const real bot = p[y1 * g + x0].x + (p[y1 * g + x1].x - p[y1 * g + x0].x) * wx;
  out[gid] = top + (bot - top) * wy;
}
