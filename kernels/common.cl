// Prepended to every kernel file. QDO_FP64 (0/1) picks the working precision `real`.
// Complex numbers are real2 (x = re, y = im), interleaved in memory as clFFT expects.
// Every 1-D kernel runs with the fixed work-group size Runtime::kLocalSize and a global size
// rounded up to it, so each kernel checks its index against the element count.
#if QDO_FP64
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double real;
typedef double2 real2;
#define R(x) (x)
#else
typedef float real;
typedef float2 real2;
#define R(x) (x##f)
#endif

inline real2 cmul(real2 a, real2 b) { return (real2)(a.x * b.x - a.y * b.y, a.x * b.y + a.y * b.x); }
#if QDO_FP64
inline __attribute__((always_inline)) real2 cexpi(real phase) {
  real c;
  real s = sincos(phase, &c);
  return (real2)(c, s);
}
#else
// e^{i phase} in float32 without a libm call: branch-free and always inlined (PoCL's inliner
// otherwise keeps it a call, which stops the work-group loop's vectorizer), 0.33 s -> 0.15 s of
// the paper-preset DOE field pass. Quadrant reduction
// r = phase - q·π/2 with π/2 split in three floats (Cody-Waite; q·PIO2_1 is exact for
// |q| < 2^15, i.e. |phase| < 5e4 rad, far beyond qdo's phases of at most a few hundred rad),
// then the minimax polynomials of Cephes' sinf/cosf on [-π/4, π/4] (error ~1 ulp there) and the
// quadrant's rotation by selects. The argument's own float rounding (eps·|phase|) dominates the
// result's error, as it did with sincos.
inline __attribute__((always_inline)) real2 cexpi(real phase) {
  const float q = rint(phase * 0.63661977236758134f);  // 2/π
  float r = fma(-q, 1.5703125f, phase);
  r = fma(-q, 4.837512969970703125e-4f, r);
  r = fma(-q, 7.549789948768648e-8f, r);
  const float r2 = r * r;
  const float sn = fma(r * r2, fma(r2, fma(r2, -1.9515295891e-4f, 8.3321608736e-3f), -1.6666654611e-1f), r);
  const float cs = fma(r2 * r2, fma(r2, fma(r2, 2.443315711809948e-5f, -1.388731625493765e-3f), 4.166664568298827e-2f),
                       fma(-0.5f, r2, 1.0f));
  const int k = ((int)q) & 3;  // e^{i(r + kπ/2)} = i^k e^{ir}
  const float c = k == 0 ? cs : k == 1 ? -sn : k == 2 ? -cs : sn;
  const float s = k == 0 ? sn : k == 1 ? cs : k == 2 ? -sn : -cs;
  return (real2)(c, s);
}
#endif
