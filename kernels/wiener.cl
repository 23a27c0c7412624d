// The Wiener expected-error objective and its gradient with respect to the PSF stack, on the
// device (src/decode/wiener_device.cpp, include/qdo/decode/wiener_device.hpp). CPU reference:
// wiener::objective_psf(Loss::Expected, ...) in src/decode/wiener.cpp, whose conventions these
// kernels follow (include/qdo/decode/wiener.hpp): per DFT frequency f, A = srf · diag(OTF(f)) (C x B),
// M = A P A^H + σ² I (C x C), Kh = M⁻¹ A P, tr E = tr P − Re tr(Kh^H A P),
// G_A = −2c (Kh P − (Kh Kh^H) A P), G_OTF_b = Σ_c srf(c, b) G_A(c, b).
//
// Build options: -DNB=<bands> -DNC=<channels> (private arrays are sized by them) and
// -DQDO_ACC64=0/1: with 1 the C x C matrices (M, Kh Kh^H), the Cholesky solve and the value are
// in double also when `real` is float ("float32 with float64 accumulation"); it needs
// cl_khr_fp64.
//
// Layouts (row-major):
//   psf    NB x S x S real, optical axis at (S/2, S/2)
//   z, g   P x H x W complex, P = (NB + 1) / 2 band pairs: pair p holds band 2p in the real
//          part and band 2p + 1 in the imaginary part (zero when 2p + 1 = NB)
//   prior  bins x NB x NB real symmetric (wiener::SpectralPrior::cov)
//   factor bins x NB x NB real lower triangular F with F Fᵀ = P (the host's, in double)
//   srf    NC x NB real
//   bin_of H x WH int, WH = W / 2 + 1: the radial bin of half-spectrum index (ky, kx)
//   value  H x WH acc: weight · tr E at (ky, kx), weight 2 where −f lies outside the half
//
// Only the half spectrum kx <= W/2 is evaluated: the OTF of a real PSF is Hermitian
// (OTF(−f) = conj OTF(f)) and P(−f) = P(f), so tr E(−f) = tr E(f) and G(−f) = conj G(f).
#if QDO_ACC64 && !QDO_FP64
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
#endif
#if QDO_ACC64
typedef double acc;
typedef double2 acc2;
#else
typedef real acc;
typedef real2 acc2;
#endif

// a · conj(b)
inline real2 cmulc(real2 a, real2 b) { return (real2)(a.x * b.x + a.y * b.y, a.y * b.x - a.x * b.y); }
inline acc2 cmulc_acc(acc2 a, acc2 b) { return (acc2)(a.x * b.x + a.y * b.y, a.y * b.x - a.x * b.y); }
inline acc2 cmul_acc(acc2 a, acc2 b) { return (acc2)(a.x * b.x - a.y * b.y, a.x * b.y + a.y * b.x); }
inline acc2 to_acc2(real2 v) { return (acc2)((acc)v.x, (acc)v.y); }

// PSF stack -> pair-packed H x W grid with the axis at (0, 0): grid (ty, tx) of band b = sum of
// psf(b, y, x) over y ≡ ty + S/2 (mod H), x ≡ tx + S/2 (mod W) (a fold when S > H or S > W),
// exactly wiener::psf_to_otf's wrap. psf: NB x S x S; z: P x H x W complex (written in full).
__kernel void wiener_place_pairs(__global const real* psf, __global real2* z, const int s, const int h, const int w) {
  const size_t gid = get_global_id(0);
  const size_t n = (size_t)h * w;
  const int pairs = (NB + 1) / 2;
  if (gid >= n * pairs) return;
  const int p = (int)(gid / n);
  const int rem = (int)(gid - (size_t)p * n);
  const int ty = rem / w, tx = rem - ty * w;
  const int c = s / 2;
  const int y0 = (ty + c) % h, x0 = (tx + c) % w;
  real v[2] = {R(0.0), R(0.0)};
  for (int j = 0; j < 2; ++j) {
    const int b = 2 * p + j;
    if (b >= NB) break;
    __global const real* pb = psf + (size_t)b * s * s;
    for (int y = y0; y < s; y += h)
      for (int x = x0; x < s; x += w) v[j] += pb[y * s + x];
  }
  z[gid] = (real2)(v[0], v[1]);
}

// Per half-spectrum frequency: tr E and the OTF gradient of every band (scaled by gscale),
// written pair-packed to g at f and, where −f lies outside the half (0 < kx < W/2), at −f as
// its conjugate. Every entry of g is written exactly once. A singular M (σ = 0) gives NaN.
// z: P x H x W pair spectra of the wrapped PSF (forward DFT, unscaled); g: same layout.
__kernel void wiener_expected(__global const real2* z, __global const real* prior, __global const real* factor,
                              __global const real* srf,
                              __global const int* bin_of, __global real2* g, __global acc* value, const int h,
                              const int w, const real sigma2, const real gscale) {
  const int wh = w / 2 + 1;
  const size_t gid = get_global_id(0);
  if (gid >= (size_t)h * wh) return;
  const int ky = (int)(gid / wh), kx = (int)(gid - (size_t)ky * wh);
  const int my = ky == 0 ? 0 : h - ky, mx = kx == 0 ? 0 : w - kx;
  const size_t n = (size_t)h * w;
  const size_t f = (size_t)ky * w + kx, fm = (size_t)my * w + mx;
  const bool mirror = kx > 0 && 2 * kx < w;
  __global const real* pr = prior + (size_t)bin_of[gid] * NB * NB;
  __global const real* fr = factor + (size_t)bin_of[gid] * NB * NB;

  // A = srf · diag(OTF(f)); the OTFs of a pair from Z(f) and Z(−f).
  real2 ap[NC][NB];  // A, then A F (in place), then A P (in place)
  for (int b = 0; b < NB; ++b) {
    const real2 zf = z[(size_t)(b >> 1) * n + f], zm = z[(size_t)(b >> 1) * n + fm];
    const real2 o = (b & 1) ? (real2)(R(0.5) * (zf.y + zm.y), R(0.5) * (zm.x - zf.x))
                            : (real2)(R(0.5) * (zf.x + zm.x), R(0.5) * (zf.y - zm.y));
    for (int c = 0; c < NC; ++c) ap[c][b] = srf[c * NB + b] * o;
  }
  // With the prior's factor P = F Fᵀ (F lower triangular, per bin): BF = A F, then
  // M = BF BF^H + σ² I, a Gram matrix, so M stays Hermitian positive definite however A was
  // rounded (forming M from a float32 A P instead loses σ² and can turn M indefinite), and
  // AP = BF Fᵀ. BF overwrites A in place (column k of BF needs columns >= k of A), AP overwrites
  // BF in place (column j of AP needs columns <= j of BF).
  for (int k = 0; k < NB; ++k) {
    real2 s[NC];
    for (int c = 0; c < NC; ++c) s[c] = (real2)(R(0.0), R(0.0));
    for (int b = k; b < NB; ++b) {
      const real fbk = fr[b * NB + k];
      for (int c = 0; c < NC; ++c) s[c] += ap[c][b] * fbk;
    }
    for (int c = 0; c < NC; ++c) ap[c][k] = s[c];
  }
  // M = BF BF^H + σ² I (Hermitian; upper triangle), then its Cholesky factor L (M = L L^H).
  acc2 m[NC][NC];
  for (int c = 0; c < NC; ++c)
    for (int d = c; d < NC; ++d) {
      acc2 s = (acc2)(0.0, 0.0);
      for (int j = 0; j < NB; ++j) s += cmulc_acc(to_acc2(ap[c][j]), to_acc2(ap[d][j]));  // products in acc: an exact Gram matrix
      m[c][d] = s;
    }
  for (int c = 0; c < NC; ++c) m[c][c].x += (acc)sigma2;
  for (int j = NB - 1; j >= 0; --j) {
    real2 s[NC];
    for (int c = 0; c < NC; ++c) s[c] = (real2)(R(0.0), R(0.0));
    for (int k = 0; k <= j; ++k) {
      const real fjk = fr[j * NB + k];
      for (int c = 0; c < NC; ++c) s[c] += ap[c][k] * fjk;
    }
    for (int c = 0; c < NC; ++c) ap[c][j] = s[c];
  }
  acc2 l[NC][NC];
  acc ldiag[NC];
  bool ok = true;
  for (int j = 0; j < NC; ++j) {
    acc dj = m[j][j].x;
    for (int k = 0; k < j; ++k) dj -= l[j][k].x * l[j][k].x + l[j][k].y * l[j][k].y;
    ok = ok && dj > 0;
    ldiag[j] = sqrt(dj > 0 ? dj : (acc)1.0);
    for (int i = j + 1; i < NC; ++i) {
      acc2 s = (acc2)(m[j][i].x, -m[j][i].y);  // M(i, j) = conj M(j, i)
      for (int k = 0; k < j; ++k) s -= cmulc_acc(l[i][k], l[j][k]);
      l[i][j] = s / ldiag[j];
    }
  }
  // Kh = M⁻¹ AP, column by column: L y = ap_j, L^H x = y.
  real2 kh[NC][NB];
  acc te = 0;  // Re tr(Kh^H AP)
  for (int j = 0; j < NB; ++j) {
    acc2 y[NC];
    for (int i = 0; i < NC; ++i) {
      acc2 s = to_acc2(ap[i][j]);
      for (int k = 0; k < i; ++k) s -= cmul_acc(l[i][k], y[k]);
      y[i] = s / ldiag[i];
    }
    for (int i = NC - 1; i >= 0; --i) {
      acc2 s = y[i];
      for (int k = i + 1; k < NC; ++k) s -= cmulc_acc(y[k], l[k][i]);  // (L^H)(i, k) = conj L(k, i)
      y[i] = s / ldiag[i];
      te += (acc)ap[i][j].x * y[i].x + (acc)ap[i][j].y * y[i].y;
      kh[i][j] = (real2)((real)y[i].x, (real)y[i].y);
    }
  }
  acc trp = 0;
  for (int b = 0; b < NB; ++b) trp += (acc)pr[b * NB + b];
  value[gid] = ok ? (mirror ? (acc)2.0 : (acc)1.0) * (trp - te) : (acc)NAN;

  // Q = Kh Kh^H (Hermitian, full).
  acc2 q[NC][NC];
  for (int c = 0; c < NC; ++c)
    for (int d = c; d < NC; ++d) {
      acc2 s = (acc2)(0.0, 0.0);
      for (int j = 0; j < NB; ++j) s += cmulc_acc(to_acc2(kh[c][j]), to_acc2(kh[d][j]));
      q[c][d] = s;
      q[d][c] = (acc2)(s.x, -s.y);
    }
  // G_b = gscale · Σ_c srf(c, b) ((Kh P)(c, b) − (Q AP)(c, b)), pair-packed.
  real2 even = (real2)(R(0.0), R(0.0));
  for (int b = 0; b < NB; ++b) {
    real2 t[NC];
    for (int c = 0; c < NC; ++c) t[c] = (real2)(R(0.0), R(0.0));
    for (int j = 0; j < NB; ++j) {
      const real pjb = pr[j * NB + b];
      for (int c = 0; c < NC; ++c) t[c] += kh[c][j] * pjb;
    }
    acc2 gb = (acc2)(0.0, 0.0);
    for (int c = 0; c < NC; ++c) {
      acc2 u = to_acc2(t[c]);
      for (int d = 0; d < NC; ++d) u -= cmul_acc(q[c][d], to_acc2(ap[d][b]));
      gb += (acc)srf[c * NB + b] * u;
    }
    const real2 gr = (real2)((real)(gb.x * (acc)gscale), (real)(gb.y * (acc)gscale));
    const int p = b >> 1;
    if ((b & 1) == 0) {
      even = gr;
      if (b == NB - 1) {  // odd band count: the last pair has no imaginary band
        g[(size_t)p * n + f] = even;
        if (mirror) g[(size_t)p * n + fm] = (real2)(even.x, -even.y);
      }
    } else {
      // G_even + i G_odd at f; conj(G_even) + i conj(G_odd) at −f.
      g[(size_t)p * n + f] = (real2)(even.x - gr.y, even.y + gr.x);
      if (mirror) g[(size_t)p * n + fm] = (real2)(even.x + gr.y, gr.x - even.y);
    }
  }
}

// Pair-packed inverse transform -> PSF gradient: grad(b, y, x) = scale · (Re or Im of)
// g(b / 2, (y − S/2) mod H, (x − S/2) mod W), the adjoint of wiener_place_pairs.
// g: P x H x W complex; grad: NB x S x S real.
__kernel void wiener_gather_grad(__global const real2* g, __global real* grad, const int s, const int h, const int w,
                                 const real scale) {
  const size_t gid = get_global_id(0);
  const size_t ss = (size_t)s * s;
  if (gid >= ss * NB) return;
  const int b = (int)(gid / ss);
  const int rem = (int)(gid - (size_t)b * ss);
  const int y = rem / s, x = rem - y * s;
  const int c = s / 2;
  const int ty = ((y - c) % h + h) % h, tx = ((x - c) % w + w) % w;
  const real2 v = g[((size_t)(b >> 1) * h + ty) * w + tx];
  grad[gid] = scale * ((b & 1) ? v.y : v.x);
}
