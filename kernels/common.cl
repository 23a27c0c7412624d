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
inline real2 cexpi(real phase) {
  real c;
  real s = sincos(phase, &c);
  return (real2)(c, s);
}
