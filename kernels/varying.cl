// Depth-layered and spatially varying imaging (src/physics/varying.cpp, include/qdo/physics/varying.hpp):
// K components, each a PSF stack and a per-pixel weight map, summed by FFT convolution on one
// GY x GX grid per scene (linear convolution, grid >= H + S/2 and >= S, so nothing folds).
//
// Layout conventions shared by these kernels (all row-major):
//   psf      (K * bands) x S x S real, component k's band b at plane k * bands + b, optical axis at
//            (S/2, S/2); component k is used shifted by whole pixels (dy, dx): its effective PSF is
//            eff(y, x) = psf(k * bands + b, y + dy, x + dx) inside the S x S window, 0 outside
//   planes   an image of `planes` real planes x H x W (a scene: bands planes; RGB: 3 planes)
//   pairs    plane pair p holds planes 2p (real part) and 2p + 1 (imaginary part; zero when
//            2p + 1 = planes); one pair spectrum is a GY x GX complex grid, P = (planes + 1) / 2
//   weights  K x H x W real, weights[k] the weight map of component k
//   otf      K x Pb x GY x GX complex (Pb = (bands + 1) / 2): component k's pair-packed OTFs
//   rgbspec  2 x GY x GX complex: (Y_R + i Y_G, Y_B)
//   wts      3 x 2Pb real: the sensor response of each band (zero-padded to 2Pb columns)

inline void v_unpack(real2 zk, real2 zn, real2* fa, real2* fb) {
  const real2 zc = (real2)(zn.x, -zn.y);
  const real2 s = zk + zc, d = zk - zc;
  *fa = R(0.5) * s;
  *fb = R(0.5) * (real2)(d.y, -d.x);
}
inline real2 v_conj(real2 a) { return (real2)(a.x, -a.y); }
inline real2 v_pack(real2 a, real2 b) { return (real2)(a.x - b.y, a.y + b.x); }  // a + i b

// One component's shifted PSF planes (plane0 .. plane0 + nplanes - 1 of psf), pair-packed onto the
// grid with the axis at (0, 0): out[p](u, v) = eff(2p)(S/2 + ty, S/2 + tx) + i eff(2p + 1)(...),
// ty = u (u <= S - 1 - S/2) or u - GY, likewise tx; 0 where the offset lies outside the S x S window
// or the shifted source pixel outside the stored plane. psf: planes x S x S; out: P x GY x GX
// complex (written in full). Requires GY, GX >= S.
__kernel void place_psf_shifted(__global const real* psf, __global real2* out, const int s, const int gy, const int gx,
                                const int plane0, const int nplanes, const int dy, const int dx) {
  const size_t gid = get_global_id(0);
  const size_t g = (size_t)gy * gx;
  const int pairs = (nplanes + 1) / 2;
  if (gid >= g * pairs) return;
  const int p = (int)(gid / g);
  const int rem = (int)(gid - (size_t)p * g);
  const int u = rem / gx, v = rem - u * gx;
  const int c = s / 2, hi = s - 1 - c;
  const int ty = u <= hi ? u : u - gy, tx = v <= hi ? v : v - gx;
  real acc[2] = {R(0.0), R(0.0)};
  const int y = ty + c + dy, x = tx + c + dx;
  if (ty >= -c && tx >= -c && y >= 0 && y < s && x >= 0 && x < s) {
    for (int j = 0; j < 2; ++j) {
      const int q = 2 * p + j;
      if (q >= nplanes) break;
      acc[j] = psf[((size_t)(plane0 + q) * s + y) * s + x];
    }
  }
  out[gid] = (real2)(acc[0], acc[1]);
}

// Adjoint of place_psf_shifted: g_psf(plane0 + j, y', x') = Re (j even) or Im (j odd) of gpsf[j / 2]
// at grid ((y' - dy - S/2) mod GY, (x' - dx - S/2) mod GX) when (y' - dy, x' - dx) lies in the
// S x S window, 0 otherwise. gpsf: P x GY x GX complex; g_psf: planes x S x S (planes plane0 ..
// plane0 + nplanes - 1 written in full).
__kernel void gather_psf_shifted(__global const real2* gpsf, __global real* g_psf, const int s, const int gy,
                                 const int gx, const int plane0, const int nplanes, const int dy, const int dx) {
  const size_t gid = get_global_id(0);
  const size_t ss = (size_t)s * s;
  if (gid >= ss * nplanes) return;
  const int j = (int)(gid / ss);
  const int rem = (int)(gid - (size_t)j * ss);
  const int y = rem / s - dy, x = rem % s - dx;
  const int c = s / 2;
  real val = R(0.0);
  if (y >= 0 && y < s && x >= 0 && x < s) {
    const int uu = ((y - c) % gy + gy) % gy, vv = ((x - c) % gx + gx) % gx;
    const real2 z = gpsf[(size_t)(j / 2) * gy * gx + (size_t)uu * gx + vv];
    val = (j & 1) ? z.y : z.x;
  }
  g_psf[(size_t)plane0 * ss + gid] = val;
}

// An image (planes x H x W), optionally times component comp's weight map, pair-packed onto the
// grid: spec[p](u, v) = wt(u, v) (img(2p, u, v) + i img(2p + 1, u, v)) for u < H, v < W, 0
// elsewhere; wt = weights[comp] when use_w, else 1. img: planes x H x W; weights: K x H x W;
// spec: P x GY x GX complex (written in full).
__kernel void place_weighted(__global const real* img, __global const real* weights, __global real2* spec,
                             const int h, const int w, const int planes, const int gy, const int gx, const int comp,
                             const int use_w) {
  const size_t gid = get_global_id(0);
  const size_t g = (size_t)gy * gx;
  const int pairs = (planes + 1) / 2;
  if (gid >= g * pairs) return;
  const int p = (int)(gid / g);
  const int rem = (int)(gid - (size_t)p * g);
  const int u = rem / gx, v = rem - u * gx;
  real2 val = (real2)(R(0.0), R(0.0));
  if (u < h && v < w) {
    const size_t hw = (size_t)h * w, px = (size_t)u * w + v;
    const real wt = use_w ? weights[(size_t)comp * hw + px] : R(1.0);
    val.x = wt * img[(size_t)(2 * p) * hw + px];
    if (2 * p + 1 < planes) val.y = wt * img[(size_t)(2 * p + 1) * hw + px];
  }
  spec[gid] = val;
}

// Unpacks pair-packed planes from inverse transforms, optionally times component comp's weight
// map: out(j, y, x) (+)= wt(y, x) * (Re (j even) or Im (j odd) of buf[j / 2](y, x)); wt =
// weights[comp] when use_w, else 1; added when accumulate, else written. buf: P x GY x GX complex;
// weights: K x H x W; out: planes x H x W real.
__kernel void gather_weighted(__global const real2* buf, __global const real* weights, __global real* out,
                              const int h, const int w, const int planes, const int gy, const int gx, const int comp,
                              const int use_w, const int accumulate) {
  const size_t gid = get_global_id(0);
  const size_t hw = (size_t)h * w;
  if (gid >= hw * planes) return;
  const int j = (int)(gid / hw);
  const int rem = (int)(gid - (size_t)j * hw);
  const int y = rem / w, x = rem - y * w;
  const real2 z = buf[(size_t)(j / 2) * gy * gx + (size_t)y * gx + x];
  const real wt = use_w ? weights[(size_t)comp * hw + rem] : R(1.0);
  const real val = wt * ((j & 1) ? z.y : z.x);
  out[gid] = accumulate ? out[gid] + val : val;
}

// Sensor integration per frequency of one component: Y_c(f) = sum_b wts[c][b] X_b(f) OTF_{comp,b}(f),
// written as rgbspec[0] = Y_R + i Y_G, rgbspec[1] = Y_B (added when accumulate, else written).
// spec: Pb x GY x GX (the band spectra, pair-packed); otf: K x Pb x GY x GX; wts: 3 x 2Pb;
// rgbspec: 2 x GY x GX complex.
__kernel void combine_component(__global const real2* spec, __global const real2* otf, __global const real* wts,
                                __global real2* rgbspec, const int gy, const int gx, const int bands, const int comp,
                                const int accumulate) {
  const size_t gid = get_global_id(0);
  const size_t g = (size_t)gy * gx;
  if (gid >= g) return;
  const int rem = (int)gid;
  const int u = rem / gx, v = rem - u * gx;
  const int nrem = ((gy - u) % gy) * gx + (gx - v) % gx;  // index of -f
  const int pairs = (bands + 1) / 2, wk = 2 * pairs;
  __global const real2* ot = otf + (size_t)comp * pairs * g;
  real2 yr = (real2)(R(0.0), R(0.0)), yg = yr, yb = yr;
  for (int p = 0; p < pairs; ++p) {
    real2 xa, xb, oa, ob;
    v_unpack(spec[(size_t)p * g + rem], spec[(size_t)p * g + nrem], &xa, &xb);
    v_unpack(ot[(size_t)p * g + rem], ot[(size_t)p * g + nrem], &oa, &ob);
    const real2 pa = cmul(xa, oa), pb = cmul(xb, ob);
    yr += wts[2 * p] * pa + wts[2 * p + 1] * pb;
    yg += wts[wk + 2 * p] * pa + wts[wk + 2 * p + 1] * pb;
    yb += wts[2 * wk + 2 * p] * pa + wts[2 * wk + 2 * p + 1] * pb;
  }
  const real2 o0 = v_pack(yr, yg);
  if (accumulate) {
    rgbspec[rem] += o0;
    rgbspec[g + rem] += yb;
  } else {
    rgbspec[rem] = o0;
    rgbspec[g + rem] = yb;
  }
}

// Adjoint spectra of one component. With the RGB gradient spectra G_c (gspec[0] = F(g_R + i g_G),
// gspec[1] = F(g_B)) and per band b the back-projected G_b = sum_c wts[c][b] G_c:
//   scene gradient  gscene[p] (+)= conj(OTF_{comp,a}) G_a + i conj(OTF_{comp,b}) G_b  (when want_scene;
//                   added when acc_scene, else written)
//   PSF gradient    gpsf[p] = conj(X_a) G_a + i conj(X_b) G_b                          (when want_psf)
// (a = 2p, b = 2p + 1; X = spec, the spectra of what the component convolved). gspec: 2 x GY x GX;
// spec, gscene, gpsf: Pb x GY x GX; otf: K x Pb x GY x GX complex; wts: 3 x 2Pb.
__kernel void component_vjp_spectra(__global const real2* gspec, __global const real2* spec,
                                    __global const real2* otf, __global const real* wts, __global real2* gscene,
                                    __global real2* gpsf, const int gy, const int gx, const int bands,
                                    const int comp, const int want_scene, const int acc_scene, const int want_psf) {
  const size_t gid = get_global_id(0);
  const size_t g = (size_t)gy * gx;
  const int pairs = (bands + 1) / 2, wk = 2 * pairs;
  if (gid >= g * pairs) return;
  const int p = (int)(gid / g);
  const int rem = (int)(gid - (size_t)p * g);
  const int u = rem / gx, v = rem - u * gx;
  const int nrem = ((gy - u) % gy) * gx + (gx - v) % gx;
  real2 gr, gg, gb, unused;
  v_unpack(gspec[rem], gspec[nrem], &gr, &gg);
  v_unpack(gspec[g + rem], gspec[g + nrem], &gb, &unused);
  const real2 ga = wts[2 * p] * gr + wts[wk + 2 * p] * gg + wts[2 * wk + 2 * p] * gb;
  const real2 gbb = wts[2 * p + 1] * gr + wts[wk + 2 * p + 1] * gg + wts[2 * wk + 2 * p + 1] * gb;
  if (want_scene) {
    __global const real2* ot = otf + (size_t)comp * pairs * g;
    real2 oa, ob;
    v_unpack(ot[(size_t)p * g + rem], ot[(size_t)p * g + nrem], &oa, &ob);
    const real2 val = v_pack(cmul(v_conj(oa), ga), cmul(v_conj(ob), gbb));
    gscene[gid] = acc_scene ? gscene[gid] + val : val;
  }
  if (want_psf) {
    real2 xa, xb;
    v_unpack(spec[(size_t)p * g + rem], spec[(size_t)p * g + nrem], &xa, &xb);
    gpsf[gid] = v_pack(cmul(v_conj(xa), ga), cmul(v_conj(xb), gbb));
  }
}

// Gradient on component comp's weight map: gw(comp, y, x) = sum_j img(j, y, x) * (Re (j even) or
// Im (j odd) of buf[j / 2](y, x)), with buf the inverse transforms of what multiplies the weight
// (source placement: the back-projected band gradients, img = the scene; output placement: the
// component's unweighted RGB image, img = the RGB gradient). buf: P x GY x GX complex; img: planes x
// H x W; gw: K x H x W real (plane comp written).
__kernel void weight_gradient(__global const real2* buf, __global const real* img, __global real* gw, const int h,
                              const int w, const int planes, const int gy, const int gx, const int comp) {
  const size_t gid = get_global_id(0);
  const size_t hw = (size_t)h * w;
  if (gid >= hw) return;
  const int y = (int)(gid / w), x = (int)(gid - (size_t)y * w);
  real acc = R(0.0);
  for (int j = 0; j < planes; ++j) {
    const real2 z = buf[(size_t)(j / 2) * gy * gx + (size_t)y * gx + x];
    acc += img[(size_t)j * hw + gid] * ((j & 1) ? z.y : z.x);
  }
  gw[(size_t)comp * hw + gid] = acc;
}
