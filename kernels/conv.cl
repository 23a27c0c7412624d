// Per-band FFT convolution of a scene cube with the PSF stack.

// scene: bands x H x W real -> buf: bands x PY x PX complex, zero-padded (written in full).
__kernel void place_scene(__global const real* scene, __global real2* buf, const int h, const int w, const int py,
                          const int px, const int bands) {
  const size_t gid = get_global_id(0);
  const size_t pp = (size_t)py * px;
  if (gid >= pp * bands) return;
  const int b = (int)(gid / pp);
  const int rem = (int)(gid - (size_t)b * pp);
  const int y = rem / px, x = rem - y * px;
  buf[gid] = (y < h && x < w) ? (real2)(scene[((size_t)b * h + y) * w + x], R(0.0)) : (real2)(R(0.0), R(0.0));
}

// psf: bands x S x S real, optical axis at (S/2, S/2) -> buf: bands x PY x PX complex with the
// axis at (0, 0), wrapped; when PY < S (circular mode) the PSF folds (sum of all aliases).
__kernel void place_psf(__global const real* psf, __global real2* buf, const int s, const int py, const int px,
                        const int bands) {
  const size_t gid = get_global_id(0);
  const size_t pp = (size_t)py * px;
  if (gid >= pp * bands) return;
  const int b = (int)(gid / pp);
  const int rem = (int)(gid - (size_t)b * pp);
  const int u = rem / px, v = rem - u * px;
  const int c = s / 2;
  real acc = R(0.0);
  for (int y = (u + c) % py; y < s; y += py)
    for (int x = (v + c) % px; x < s; x += px) acc += psf[((size_t)b * s + y) * s + x];
  buf[gid] = (real2)(acc, R(0.0));
}

// a[e] *= b[e % period]: the OTF stack (period = bands*PY*PX) applied to a batch of scenes.
__kernel void cmul_inplace(__global real2* a, __global const real2* b, const int count, const int period) {
  const size_t gid = get_global_id(0);
  if (gid >= (size_t)count) return;
  a[gid] = cmul(a[gid], b[gid % (size_t)period]);
}

// buf: planes x PY x PX complex -> out: planes x H x W real part (top-left crop).
__kernel void crop_real(__global const real2* buf, __global real* out, const int h, const int w, const int py,
                        const int px, const int planes) {
  const size_t gid = get_global_id(0);
  const size_t hw = (size_t)h * w;
  if (gid >= hw * planes) return;
  const int b = (int)(gid / hw);
  const int rem = (int)(gid - (size_t)b * hw);
  const int y = rem / w, x = rem - y * w;
  out[gid] = buf[(size_t)b * py * px + (size_t)y * px + x].x;
}
