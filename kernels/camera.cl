// The camera: sensor images of scene batches, with skipping rules (src/physics/camera.cpp, include/qdo/physics/camera.hpp).
//
// Layout conventions shared by these kernels (all row-major):
//   psf     bands x S x S real, optical axis at (S/2, S/2), PSF offset t = index - S/2
//   cube    scenes x K x H x W real: the K kept bands of each scene, compacted
//   pairs   band pair p holds kept bands 2p (real part) and 2p+1 (imaginary part; zero when
//           2p+1 = K); one pair spectrum is a GY x GX complex grid
//   slots   one slot = one convolution window (a whole scene, or one tile of one scene):
//           tiles[3 * slot + 0..2] = (scene, y0, x0), the window's top-left scene pixel
//   spec    slots x P x GY x GX complex (pair spectra of the slots of one chunk)
//   otf     P x GY x GX complex (pair spectra of the cropped PSFs, same pairing)
//   rgbspec slots x 2 x GY x GX complex: (Y_R + i Y_G, Y_B) per slot
//   rgb     scenes x 3 x H x W real

// Energy of each PSF band on the Chebyshev rings around the axis: rings[b * (C + 1) + k] =
// sum of |psf(b, S/2 + ty, S/2 + tx)| over max(|ty|, |tx|) = k, k = 0..C, C = S/2 (offsets
// outside [-S/2, S - 1 - S/2] do not exist). psf: bands x S x S; rings: bands x (C + 1).
__kernel void ring_energy(__global const real* psf, __global real* rings, const int s, const int bands) {
  const int c = s / 2;
  const size_t gid = get_global_id(0);
  if (gid >= (size_t)bands * (c + 1)) return;
  const int b = (int)(gid / (size_t)(c + 1));
  const int k = (int)(gid - (size_t)b * (c + 1));
  const int lo = -c, hi = s - 1 - c;
  __global const real* p = psf + (size_t)b * s * s;
  real acc = R(0.0);
  for (int ty = -k; ty <= k; ++ty) {
    if (ty < lo || ty > hi) continue;
    const int row = (ty + c) * s + c;
    if (ty == -k || ty == k) {
      for (int tx = -k; tx <= k; ++tx)
        if (tx >= lo && tx <= hi) acc += fabs(p[row + tx]);
    } else {
      if (-k >= lo) acc += fabs(p[row - k]);
      if (k <= hi) acc += fabs(p[row + k]);
    }
  }
  rings[gid] = acc;
}

// t mod n in [0, n) for any int t (n > 0), without a division when |t| < n.
inline int wrap_index(int t, const int n) {
  if (t >= n || t < -n) t %= n;
  return t < 0 ? t + n : t;
}

// Cropped PSF of kept bands, pair-packed onto the GY x GX grid with the axis at (0, 0): grid
// (u, v) = sum of psf(b, S/2 + ty, S/2 + tx) over offsets ty = u (mod GY), tx = v (mod GX)
// with -min(r, S/2) <= ty, tx <= min(r, S - 1 - S/2) (more than one term only when the grid is
// smaller than the window: circular mode folds). band_of[k] = source band of kept band k.
// psf: bands x S x S; out: P x GY x GX complex (written in full).
// Row kernel: global (>= GX, P * GY); column v = id 0, row p * GY + u = id 1.
__kernel void place_psf_pairs(__global const real* psf, __global const int* band_of, __global real2* out,
                              const int s, const int gy, const int gx, const int r, const int kept) {
  const int v = (int)get_global_id(0);
  const int row = (int)get_global_id(1);
  const int pairs = (kept + 1) / 2;
  // The row's indices first, unconditionally: the compiler can then keep them out of the column loop.
  const int p = row / gy, u = row - p * gy;
  if (v >= gx || row >= pairs * gy) return;
  const int c = s / 2;
  const int lo = -min(r, c), hi = min(r, s - 1 - c);
  const int ty0 = lo + wrap_index(u - lo, gy);  // first offset >= lo congruent to u
  const int tx0 = lo + wrap_index(v - lo, gx);
  // Two named sums (a private array indexed in a loop lives on the stack of a CPU device).
  const bool odd = 2 * p + 1 < kept;
  __global const real* qa = psf + (size_t)band_of[2 * p] * s * s;
  __global const real* qb = psf + (size_t)band_of[odd ? 2 * p + 1 : 2 * p] * s * s;
  real acc_a = R(0.0), acc_b = R(0.0);
  for (int ty = ty0; ty <= hi; ty += gy)
    for (int tx = tx0; tx <= hi; tx += gx) {
      const int i = (ty + c) * s + tx + c;
      acc_a += qa[i];
      acc_b += qb[i];
    }
  out[(size_t)row * gx + v] = (real2)(acc_a, odd ? acc_b : R(0.0));
}

// Scene windows of one chunk, pair-packed: spec[slot][p](u, v) = cube(scene, 2p, y0 + u, x0 + v)
// + i cube(scene, 2p + 1, ...), zero outside the window (u >= th or v >= tw), outside the scene
// and for slots >= count (padding of the last chunk). Slot `slot` of this chunk is global slot
// base + slot. cube: scenes x K x H x W; spec: slots x P x GY x GX complex (written in full).
// Row kernel: global (>= GX, slots * P * GY); column v = id 0, row (slot * P + p) * GY + u = id 1.
__kernel void place_windows(__global const real* cube, __global const int* tiles, __global real2* spec,
                            const int h, const int w, const int kept, const int gy, const int gx, const int th,
                            const int tw, const int base, const int count, const int slots) {
  const int v = (int)get_global_id(0);
  const int row = (int)get_global_id(1);
  const int pairs = (kept + 1) / 2;
  const int plane = row / gy, u = row - plane * gy;  // before the bounds check: see place_psf_pairs
  const int slot = plane / pairs, p = plane - slot * pairs;
  if (v >= gx || row >= slots * pairs * gy) return;
  real2 val = (real2)(R(0.0), R(0.0));
  if (slot < count && u < th && v < tw) {
    const int t = base + slot;
    const int scene = tiles[3 * t], y = tiles[3 * t + 1] + u, x = tiles[3 * t + 2] + v;
    if (y < h && x < w) {
      const size_t hw = (size_t)h * w;
      __global const real* sc = cube + (size_t)scene * kept * hw + (size_t)y * w + x;
      val.x = sc[(size_t)(2 * p) * hw];
      if (2 * p + 1 < kept) val.y = sc[(size_t)(2 * p + 1) * hw];
    }
  }
  spec[(size_t)row * gx + v] = val;
}

// Unpacks the two real transforms held in a pair spectrum z: for real a, b with z = F(a + i b),
// F(a)(k) = (z(k) + conj z(-k)) / 2 and F(b)(k) = (z(k) - conj z(-k)) / (2 i).
inline void unpack_pair(real2 zk, real2 zn, real2* fa, real2* fb) {
  const real2 zc = (real2)(zn.x, -zn.y);
  const real2 s = zk + zc, d = zk - zc;
  *fa = R(0.5) * s;
  *fb = R(0.5) * (real2)(d.y, -d.x);
}

// Per-frequency sensor integration in the Fourier domain (linearity: sum over bands before the
// inverse transform): Y_c(k) = sum_k' wts[c][k'] F(scene_k')(k) OTF_k'(k), written as
// rgbspec[slot][0] = Y_R + i Y_G and rgbspec[slot][1] = Y_B (the R, G, B images are real, so
// one inverse transform of the first carries two channels). wts: 3 x (2P) (zero-padded).
// spec: slots x P x GY x GX; otf: P x GY x GX; rgbspec: slots x 2 x GY x GX complex.
// Row kernel: global (>= GX, slots * GY); column v = id 0, row slot * GY + u = id 1.
__kernel void combine_channels(__global const real2* restrict spec, __global const real2* restrict otf,
                               __global const real* restrict wts, __global real2* restrict rgbspec, const int gy,
                               const int gx, const int kept,
                               const int slots) {
  const int v = (int)get_global_id(0);
  const int row = (int)get_global_id(1);
  const int slot = row / gy, u = row - slot * gy;  // before the bounds check: see place_psf_pairs
  if (v >= gx || row >= slots * gy) return;
  const size_t g = (size_t)gy * gx;
  const int rem = u * gx + v;
  const int nrem = (u == 0 ? 0 : gy - u) * gx + (v == 0 ? 0 : gx - v);  // index of -k
  // The images are real, so Y_c(-k) = conj Y_c(k): the item of k writes both, that of -k nothing.
  if (rem > nrem) return;
  const int pairs = (kept + 1) / 2;
  const int wk = 2 * pairs;
  real2 yr = (real2)(R(0.0), R(0.0)), yg = yr, yb = yr;
  __global const real2* sp = spec + (size_t)slot * pairs * g;
  for (int p = 0; p < pairs; ++p) {
    real2 xa, xb, oa, ob;
    unpack_pair(sp[(size_t)p * g + rem], sp[(size_t)p * g + nrem], &xa, &xb);
    unpack_pair(otf[(size_t)p * g + rem], otf[(size_t)p * g + nrem], &oa, &ob);
    const real2 pa = cmul(xa, oa), pb = cmul(xb, ob);
    yr += wts[2 * p] * pa + wts[2 * p + 1] * pb;
    yg += wts[wk + 2 * p] * pa + wts[wk + 2 * p + 1] * pb;
    yb += wts[2 * wk + 2 * p] * pa + wts[2 * wk + 2 * p + 1] * pb;
  }
  __global real2* o = rgbspec + (size_t)slot * 2 * g;
  o[rem] = (real2)(yr.x - yg.y, yr.y + yg.x);
  o[g + rem] = yb;
  if (nrem != rem) {  // conj Y_R(k) + i conj Y_G(k), conj Y_B(k)
    o[nrem] = (real2)(yr.x + yg.y, yg.x - yr.y);
    o[g + nrem] = (real2)(yb.x, -yb.y);
  }
}

// Overlap-add of the inverse-transformed windows of one chunk into the RGB images: rgb(scene,
// c, y, x) += window value at grid ((y - y0) mod GY, (x - x0) mod GX) for every window of the
// chunk whose linear-convolution support [y0 - a, y0 + th - 1 + b] x [...] holds (y, x), with a =
// the PSF's negative extent and b its positive extent. Windows are on a regular grid of pitch
// (th, tw), ty = y0 / th; slot_of[(scene * nty + ty) * ntx + tx] = global slot (-1: skipped).
// Channels: R = re(rgbspec[slot][0]), G = im(rgbspec[slot][0]), B = re(rgbspec[slot][1]).
// rgbspec: slots x 2 x GY x GX complex; rgb: scenes x 3 x H x W real (accumulated).
__kernel void gather_windows(__global const real2* rgbspec, __global const int* slot_of, __global real* rgb,
                             const int h, const int w, const int gy, const int gx, const int th, const int tw,
                             const int nty, const int ntx, const int a, const int b, const int base,
                             const int count, const int scenes) {
  const size_t gid = get_global_id(0);
  const size_t hw = (size_t)h * w;
  if (gid >= hw * scenes) return;
  const int scene = (int)(gid / hw);
  const int rem = (int)(gid - (size_t)scene * hw);
  const int y = rem / w, x = rem - y * w;
  // Window rows ty with y0 - a <= y <= y0 + th - 1 + b, y0 = ty * th.
  const int ny = y - b - th + 1, nx = x - b - tw + 1;  // ty >= ceil(ny / th), clamped at 0
  const int ty_lo = ny <= 0 ? 0 : (ny + th - 1) / th, ty_hi = min(nty - 1, (y + a) / th);
  const int tx_lo = nx <= 0 ? 0 : (nx + tw - 1) / tw, tx_hi = min(ntx - 1, (x + a) / tw);
  const size_t g = (size_t)gy * gx;
  real sr = R(0.0), sg = R(0.0), sb = R(0.0);
  for (int ty = ty_lo; ty <= ty_hi; ++ty)
    for (int tx = tx_lo; tx <= tx_hi; ++tx) {
      const int slot = slot_of[((size_t)scene * nty + ty) * ntx + tx] - base;
      if (slot < 0 || slot >= count) continue;
      const int u = ((y - ty * th) % gy + gy) % gy, v = ((x - tx * tw) % gx + gx) % gx;
      __global const real2* o = rgbspec + (size_t)slot * 2 * g + (size_t)u * gx + v;
      sr += o[0].x;
      sg += o[0].y;
      sb += o[g].x;
    }
  __global real* out = rgb + (size_t)scene * 3 * hw + rem;
  out[0] += sr;
  out[hw] += sg;
  out[2 * hw] += sb;
}

inline real2 cconj(real2 a) { return (real2)(a.x, -a.y); }

// --- Per-band blur (no sensor integration) and the adjoints; untiled layouts only: one window
// per scene with its top-left pixel at grid (0, 0), slot = scene. ---

// Per-band product with the OTF, pair-packed: out[slot][p] = F(a) OTF_a + i F(b) OTF_b for the
// two bands a = 2p, b = 2p + 1 of pair p (their inverse transform holds blur(a) in the real part
// and blur(b) in the imaginary part). spec, out: slots x P x GY x GX; otf: P x GY x GX complex.
__kernel void multiply_pairs(__global const real2* spec, __global const real2* otf, __global real2* out, const int gy,
                             const int gx, const int pairs, const int slots) {
  const size_t gid = get_global_id(0);
  const size_t g = (size_t)gy * gx;
  if (gid >= g * pairs * slots) return;
  const size_t plane = gid / g;  // slot * pairs + p
  const int p = (int)(plane % pairs);
  const int rem = (int)(gid - plane * g);
  const int u = rem / gx, v = rem - u * gx;
  const int nrem = ((gy - u) % gy) * gx + (gx - v) % gx;
  real2 xa, xb, oa, ob;
  unpack_pair(spec[plane * g + rem], spec[plane * g + nrem], &xa, &xb);
  unpack_pair(otf[(size_t)p * g + rem], otf[(size_t)p * g + nrem], &oa, &ob);
  const real2 pa = cmul(xa, oa), pb = cmul(xb, ob);
  out[gid] = (real2)(pa.x - pb.y, pa.y + pb.x);
}

// Unpacks pair-packed real images from the inverse transforms: out(scene, k, y, x) = Re (k even)
// or Im (k odd) of buf[slot = scene - base][k / 2](y, x), for the `count` scenes base .. base +
// count - 1. buf: slots x P x GY x GX complex; out: scenes x K x H x W real (this chunk's part).
// The adjoint of place_windows for whole-scene windows, and the crop of the blur.
__kernel void gather_pairs(__global const real2* buf, __global real* out, const int h, const int w, const int kept,
                           const int gy, const int gx, const int base, const int count) {
  const size_t gid = get_global_id(0);
  const size_t hw = (size_t)h * w;
  if (gid >= hw * kept * count) return;
  const size_t plane = gid / hw;  // slot * K + k
  const int slot = (int)(plane / kept), k = (int)(plane - (size_t)slot * kept);
  const int rem = (int)(gid - plane * hw);
  const int y = rem / w, x = rem - y * w;
  const int pairs = (kept + 1) / 2;
  const real2 z = buf[((size_t)slot * pairs + k / 2) * gy * gx + (size_t)y * gx + x];
  out[((size_t)(base + slot) * kept + k) * hw + rem] = (k & 1) ? z.y : z.x;
}

// Adjoint spectra of the camera for one chunk of whole-scene windows. With the image gradients'
// spectra G_c (gspec[slot][0] = F(g_R + i g_G), gspec[slot][1] = F(g_B)) and per kept band j the
// back-projected gradient G_j = sum_c wts[c][j] G_c (the adjoint of the sensor integration):
//   scene gradient spectrum   gscene[slot][p] = conj(OTF_a) G_a + i conj(OTF_b) G_b
//   PSF gradient spectrum     gpsf[p] += sum over the chunk's slots of conj(X_a) G_a + i conj(X_b) G_b
// (a = 2p, b = 2p + 1; X = the scene spectra of spec). One work item per (p, frequency) loops over
// the slots, so gpsf needs no atomics. gspec: slots x 2 x GY x GX; spec, gscene: slots x P x GY x
// GX; otf, gpsf: P x GY x GX complex; wts: 3 x 2P.
// Row kernel: global (>= GX, P * GY); column v = id 0, row p * GY + u = id 1.
__kernel void camera_vjp_spectra(__global const real2* restrict gspec, __global const real2* restrict spec,
                                 __global const real2* restrict otf, __global const real* restrict wts,
                                 __global real2* restrict gscene, __global real2* restrict gpsf,
                                 const int gy, const int gx, const int kept, const int count,
                                 const int want_scene) {
  const int v = (int)get_global_id(0);
  const int row = (int)get_global_id(1);
  const int pairs = (kept + 1) / 2;
  const int p = row / gy, u = row - p * gy;  // before the bounds check: see place_psf_pairs
  if (v >= gx || row >= pairs * gy) return;
  const size_t g = (size_t)gy * gx;
  const int rem = u * gx + v;
  const int nrem = (u == 0 ? 0 : gy - u) * gx + (v == 0 ? 0 : gx - v);
  // Every spectrum here is that of a real image, so the values at -k are the conjugates of those
  // at k: the item of k writes both, that of -k nothing.
  if (rem > nrem) return;
  const int wk = 2 * pairs;
  real2 oa, ob;
  unpack_pair(otf[(size_t)p * g + rem], otf[(size_t)p * g + nrem], &oa, &ob);
  real2 acc_a = (real2)(R(0.0), R(0.0)), acc_b = acc_a;
  for (int slot = 0; slot < count; ++slot) {
    __global const real2* gs = gspec + (size_t)slot * 2 * g;
    real2 gr, gg, gb, unused;
    unpack_pair(gs[rem], gs[nrem], &gr, &gg);
    unpack_pair(gs[g + rem], gs[g + nrem], &gb, &unused);
    const real2 ga = wts[2 * p] * gr + wts[wk + 2 * p] * gg + wts[2 * wk + 2 * p] * gb;
    const real2 gbb = wts[2 * p + 1] * gr + wts[wk + 2 * p + 1] * gg + wts[2 * wk + 2 * p + 1] * gb;
    real2 xa, xb;
    const size_t plane = (size_t)slot * pairs + p;
    unpack_pair(spec[plane * g + rem], spec[plane * g + nrem], &xa, &xb);
    acc_a += cmul(cconj(xa), ga);
    acc_b += cmul(cconj(xb), gbb);
    if (want_scene) {
      const real2 sa = cmul(cconj(oa), ga), sb = cmul(cconj(ob), gbb);
      gscene[plane * g + rem] = (real2)(sa.x - sb.y, sa.y + sb.x);
      if (nrem != rem) gscene[plane * g + nrem] = (real2)(sa.x + sb.y, sb.x - sa.y);  // conj sa + i conj sb
    }
  }
  gpsf[(size_t)p * g + rem] += (real2)(acc_a.x - acc_b.y, acc_a.y + acc_b.x);
  if (nrem != rem) gpsf[(size_t)p * g + nrem] += (real2)(acc_a.x + acc_b.y, acc_b.x - acc_a.y);
}

// Adjoint of place_psf_pairs (wrap, fold and crop): g_psf(band_of[k], S/2 + ty, S/2 + tx) = Re
// (k even) or Im (k odd) of gpsf[k / 2] at grid (ty mod GY, tx mod GX) for offsets within the
// crop, -min(r, S/2) <= ty, tx <= min(r, S - 1 - S/2); 0 outside it. Bands that are not kept
// are not written (the caller zeroes them). gpsf: P x GY x GX complex; g_psf: bands x S x S.
// Row kernel: global (>= S, K * S); column = id 0, row k * S + y = id 1.
__kernel void gather_psf_pairs(__global const real2* gpsf, __global const int* band_of, __global real* g_psf,
                               const int s, const int gy, const int gx, const int r, const int kept) {
  const int col = (int)get_global_id(0);
  const int row = (int)get_global_id(1);
  const int k = row / s, y = row - k * s;  // before the bounds check: see place_psf_pairs
  if (col >= s || row >= kept * s) return;
  const int c = s / 2;
  const int ty = y - c, tx = col - c;
  const int lo = -min(r, c), hi = min(r, s - 1 - c);
  real val = R(0.0);
  if (ty >= lo && ty <= hi && tx >= lo && tx <= hi) {
    const int uu = wrap_index(ty, gy), vv = wrap_index(tx, gx);
    const real2 z = gpsf[(size_t)(k / 2) * gy * gx + (size_t)uu * gx + vv];
    val = (k & 1) ? z.y : z.x;
  }
  g_psf[((size_t)band_of[k] * s + y) * s + col] = val;
}
