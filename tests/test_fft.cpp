// The FFT backends (clFFT, VkFFT) against FFTW in double (qdo::fftw2) on seeded random data, FFTW's
// real transforms (rfftw2, irfftw2) against its complex one, the plan cache, backend selection and
// the zero-padding hint.
//
// Tolerances: a floating-point FFT of n = rows*cols points has a relative L2 error bounded by
// about c·ε·log2(n) (Cooley-Tukey error analysis); kTolC below is c, so
// tol(p, n) = kTolC·ε(p)·log2(n) with ε the machine epsilon of the precision (the measured
// errors sit 5-10x below it: about 1.5e-7 in f32 and 6e-16 in f64 at n = 384²). The reference is
// FFTW in double on the same (already rounded) input, so only the transform error is measured.
#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "common.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/fft.hpp"
#include "qdo/runtime/fftw2.hpp"
#include "qdo/runtime/runtime.hpp"

using namespace qdo;
using namespace qdo::test;

namespace {

constexpr double kTolC = 1.0;
// Every backend the test device runs: FFTW maps the buffers of CPU devices only.
std::vector<FftBackend> backends(const Runtime& rt) {
  std::vector<FftBackend> b{FftBackend::ClFFT, FftBackend::VkFFT};
  if (rt.info().type == "CPU") b.push_back(FftBackend::FFTW);
  return b;
}

double tol(Precision p, std::size_t rows, std::size_t cols) {
  return kTolC * eps(p) * std::log2(double(rows * cols));
}

std::vector<Precision> precisions(const Runtime& rt) { return device_precisions(rt); }

// planes x rows x cols complex values, re and im uniform in [-1, 1], rounded to precision p
// (so the FFTW reference sees exactly what the device sees).
ComplexStack random_field(std::size_t planes, std::size_t rows, std::size_t cols, Precision p, unsigned seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  ComplexStack s(planes, rows, cols);
  for (auto& v : s.data) {
    v = cdouble(u(rng), u(rng));
    if (p == Precision::F32) v = cdouble(double(float(v.real())), double(float(v.imag())));
  }
  return s;
}

// Complex stack -> device buffer of interleaved (re, im) in precision p, and back.
cl::Buffer upload(Runtime& rt, const ComplexStack& s, Precision p) {
  const std::size_t n = s.size();
  std::vector<char> bytes(n * 2 * real_size(p));
  for (std::size_t i = 0; i < n; ++i) {
    if (p == Precision::F64) {
      reinterpret_cast<double*>(bytes.data())[2 * i] = s.data[i].real();
      reinterpret_cast<double*>(bytes.data())[2 * i + 1] = s.data[i].imag();
    } else {
      reinterpret_cast<float*>(bytes.data())[2 * i] = float(s.data[i].real());
      reinterpret_cast<float*>(bytes.data())[2 * i + 1] = float(s.data[i].imag());
    }
  }
  return cl::Buffer(rt.context(), CL_MEM_READ_WRITE | CL_MEM_COPY_HOST_PTR, bytes.size(), bytes.data());
}

ComplexStack download(Runtime& rt, cl::Buffer& buf, std::size_t planes, std::size_t rows, std::size_t cols,
                      Precision p) {
  ComplexStack s(planes, rows, cols);
  std::vector<char> bytes(s.size() * 2 * real_size(p));
  rt.queue().enqueueReadBuffer(buf, CL_TRUE, 0, bytes.size(), bytes.data());
  for (std::size_t i = 0; i < s.size(); ++i) {
    if (p == Precision::F64)
      s.data[i] = cdouble(reinterpret_cast<double*>(bytes.data())[2 * i], reinterpret_cast<double*>(bytes.data())[2 * i + 1]);
    else
      s.data[i] = cdouble(reinterpret_cast<float*>(bytes.data())[2 * i], reinterpret_cast<float*>(bytes.data())[2 * i + 1]);
  }
  return s;
}

// One device transform of `in` (planes x rows x cols) with the given plan.
ComplexStack device_fft(Runtime& rt, FftPlan& plan, const ComplexStack& in, bool forward) {
  cl::Buffer buf = upload(rt, in, plan.precision());
  if (forward)
    plan.forward(buf);
  else
    plan.inverse(buf);
  return download(rt, buf, in.planes, in.rows, in.cols, plan.precision());
}

ComplexStack fftw_ref(ComplexStack s, bool forward) {
  fftw2(s, forward, true);
  return s;
}

struct Shape {
  std::size_t rows, cols, batch;
};

}  // namespace

// The shapes every accuracy test uses (few distinct plans, as each costs a kernel build on a
// cold PoCL cache): a power of two with batch 3, the PSF window M = 384 = 2^7·3 (N = 256) with
// batch 2, and a rectangle of 7-smooth non-powers with radices 5 and 7 (70 = 2·5·7) and 768 =
// 2^8·3 (the PSF window at N = 512).
const Shape kShapes[] = {{64, 64, 3}, {384, 384, 2}, {70, 768, 1}};

TEST_SUITE("fft") {
  TEST_CASE("both backends match FFTW forward and inverse, f32 and f64, within c·ε·log2(n); round trip") {
    Runtime& rt = runtime();
    unsigned seed = 11;
    for (FftBackend b : backends(rt))
      for (Precision p : precisions(rt))
        for (const Shape& s : kShapes) {
          CAPTURE(to_string(b));
          CAPTURE(to_string(p));
          CAPTURE(s.rows);
          CAPTURE(s.cols);
          CAPTURE(s.batch);
          FftPlan& plan = rt.fft(s.rows, s.cols, s.batch, p, b);
          REQUIRE(plan.backend() == b);
          const double t = tol(p, s.rows, s.cols);
          const ComplexStack x = random_field(s.batch, s.rows, s.cols, p, ++seed);
          const auto fwd = diff(device_fft(rt, plan, x, true).data, fftw_ref(x, true).data);
          CHECK(fwd.rel_l2 <= t);
          // The inverse of a random spectrum (not of the forward result, so errors cannot cancel).
          const ComplexStack y = random_field(s.batch, s.rows, s.cols, p, ++seed);
          const auto inv = diff(device_fft(rt, plan, y, false).data, fftw_ref(y, false).data);
          CHECK(inv.rel_l2 <= t);
          // Round trip in place on the device.
          cl::Buffer buf = upload(rt, x, p);
          plan.forward(buf);
          plan.inverse(buf);
          CHECK(diff(download(rt, buf, s.batch, s.rows, s.cols, p).data, x.data).rel_l2 <= 2 * t);
          MESSAGE(to_string(b) << " " << to_string(p) << " " << s.batch << "x" << s.rows << "x" << s.cols
                               << ": rel L2 error forward " << fwd.rel_l2 << ", inverse " << inv.rel_l2
                               << " (tolerance " << t << ")");
        }
  }

  TEST_CASE("the forward transform has the e^{-i2π...} sign and the inverse the 1/(rows·cols) scale") {
    // Plane t holds a complex exponential at (ky, kx) = (t + 1, 2t + 3): it transforms to
    // rows·cols at that bin only (a wrong sign puts the peak at (-ky, -kx)); the inverse of a
    // unit impulse at (0, 0) is 1/(rows·cols) everywhere (a wrong scale is off by rows·cols).
    Runtime& rt = runtime();
    const Shape s = kShapes[0];
    for (FftBackend b : backends(rt))
      for (Precision p : precisions(rt)) {
        CAPTURE(to_string(b));
        CAPTURE(to_string(p));
        FftPlan& plan = rt.fft(s.rows, s.cols, s.batch, p, b);
        const double n = double(s.rows * s.cols), t = tol(p, s.rows, s.cols);
        ComplexStack wave(s.batch, s.rows, s.cols), impulse(s.batch, s.rows, s.cols);
        for (std::size_t k = 0; k < s.batch; ++k) {
          for (std::size_t y = 0; y < s.rows; ++y)
            for (std::size_t x = 0; x < s.cols; ++x)
              wave(k, y, x) = std::polar(1.0, 2 * M_PI * (double((k + 1) * y) / double(s.rows) +
                                                          double((2 * k + 3) * x) / double(s.cols)));
          impulse(k, 0, 0) = 1.0;
        }
        const ComplexStack f = device_fft(rt, plan, wave, true);
        for (std::size_t k = 0; k < s.batch; ++k) {
          CHECK(std::abs(f(k, k + 1, 2 * k + 3) - cdouble(n, 0)) <= t * n);  // ||f_k|| = n: any bin within t·n
          CHECK(std::abs(f(k, s.rows - k - 1, s.cols - 2 * k - 3)) <= t * n);
        }
        const ComplexStack g = device_fft(rt, plan, impulse, false);
        for (const cdouble& v : g.data) REQUIRE(std::abs(v - 1.0 / n) <= t / n);
      }
  }

  TEST_CASE("rfftw2 is the first cols/2 + 1 columns of fftw2's spectrum; irfftw2 inverts it (even and odd sizes)") {
    std::mt19937_64 rng(41);
    std::normal_distribution<double> g(0.0, 1.0);
    for (const auto& [rows, cols] : {std::pair<std::size_t, std::size_t>{8, 6}, {7, 9}, {5, 1}}) {
      CAPTURE(rows);
      CAPTURE(cols);
      RealStack x(3, rows, cols);
      for (double& v : x.data) v = g(rng);
      ComplexStack full(3, rows, cols);
      for (std::size_t i = 0; i < x.size(); ++i) full.data[i] = x.data[i];
      fftw2(full, true);
      ComplexStack half = rfftw2(x);
      REQUIRE(half.cols == cols / 2 + 1);
      double worst = 0, scale = 0;
      for (std::size_t p = 0; p < 3; ++p)
        for (std::size_t r = 0; r < rows; ++r)
          for (std::size_t c = 0; c < half.cols; ++c) {
            worst = std::max(worst, std::abs(half(p, r, c) - full(p, r, c)));
            scale = std::max(scale, std::abs(full(p, r, c)));
          }
      CHECK(worst <= 1e-13 * scale);  // two FFTW plans of the same sums: rounding only
      const RealStack back = irfftw2(half, cols);
      double err = 0;
      for (std::size_t i = 0; i < x.size(); ++i) err = std::max(err, std::fabs(back.data[i] - x.data[i]));
      CHECK(err < 1e-13);
    }
  }

  TEST_CASE("the backends agree with each other") {
    Runtime& rt = runtime();
    unsigned seed = 201;
    for (Precision p : precisions(rt))
      for (const Shape& s : kShapes)
        for (FftBackend b : backends(rt)) {
          if (b == FftBackend::ClFFT) continue;
          CAPTURE(to_string(p));
          CAPTURE(to_string(b));
          CAPTURE(s.rows);
          const ComplexStack x = random_field(s.batch, s.rows, s.cols, p, ++seed);
          FftPlan& c = rt.fft(s.rows, s.cols, s.batch, p, FftBackend::ClFFT);
          FftPlan& v = rt.fft(s.rows, s.cols, s.batch, p, b);
          const double t = 2 * tol(p, s.rows, s.cols);  // each within tol of FFTW in double
          CHECK(diff(device_fft(rt, v, x, true).data, device_fft(rt, c, x, true).data).rel_l2 <= t);
          CHECK(diff(device_fft(rt, v, x, false).data, device_fft(rt, c, x, false).data).rel_l2 <= t);
        }
  }

  TEST_CASE("backend names: clfft, vkfft, fftw and auto accepted in any case, anything else rejected; auto picks FFTW on CPUs, VkFFT elsewhere") {
    CHECK(fft_backend_from_string("clfft") == FftBackend::ClFFT);
    CHECK(fft_backend_from_string("VkFFT") == FftBackend::VkFFT);
    CHECK(fft_backend_from_string("FFTW") == FftBackend::FFTW);
    CHECK(fft_backend_from_string("auto") == FftBackend::Auto);
    for (FftBackend b : {FftBackend::ClFFT, FftBackend::VkFFT, FftBackend::FFTW, FftBackend::Auto})
      CHECK(fft_backend_from_string(to_string(b)) == b);
    CHECK_THROWS_WITH_AS(fft_backend_from_string("cufft"), doctest::Contains("'fft backend' = cufft"), InputError);
    CHECK_THROWS_WITH_AS(fft_backend_from_string(""), doctest::Contains("clfft, vkfft, fftw or auto"), InputError);

    const char* old = std::getenv("QDO_FFT");
    const std::string saved = old ? old : "";
    setenv("QDO_FFT", "cufft", 1);
    CHECK_THROWS_WITH_AS(Runtime(), doctest::Contains("'QDO_FFT' = cufft"), InputError);
    setenv("QDO_FFT", "VKFFT", 1);
    {
      Runtime rt;
      CHECK(rt.fft_backend() == FftBackend::VkFFT);
      CHECK(rt.fft(64, 64, 3, Precision::F32).backend() == FftBackend::VkFFT);
      Runtime explicit_rt("", FftBackend::ClFFT);  // the constructor argument wins over QDO_FFT
      CHECK(explicit_rt.fft_backend() == FftBackend::ClFFT);
    }
    setenv("QDO_FFT", "clfft", 1);
    CHECK(Runtime().fft_backend() == FftBackend::ClFFT);
    unsetenv("QDO_FFT");  // the default: auto
    {
      Runtime rt;
      const FftBackend want = rt.info().type == "CPU" ? FftBackend::FFTW : FftBackend::VkFFT;
      CHECK(rt.fft_backend() == want);
      CHECK(Runtime("", FftBackend::Auto).fft_backend() == want);
      CHECK(rt.fft(64, 64, 3, Precision::F32, FftBackend::Auto).backend() == want);
    }
    if (old)
      setenv("QDO_FFT", saved.c_str(), 1);
  }

  TEST_CASE("the plan cache returns the same plan for the same key and a new one otherwise") {
    // Keys built from the shapes above, so that on a cold PoCL cache no extra kernels are built.
    Runtime rt("", FftBackend::ClFFT);
    FftPlan& a = rt.fft(64, 64, 3, Precision::F32);
    CHECK(a.backend() == FftBackend::ClFFT);
    CHECK(&rt.fft(64, 64, 3, Precision::F32) == &a);
    CHECK(&rt.fft(64, 64, 3, Precision::F32, FftBackend::ClFFT) == &a);
    CHECK(&rt.fft(64, 64, 3, Precision::F32, FftBackend::ClFFT, FftZeroPad{5, 5, 0, 0}) == &a);  // empty hint
    CHECK(rt.fft_plan_count() == 1);
    FftPlan& v = rt.fft(64, 64, 3, Precision::F32, FftBackend::VkFFT);
    CHECK(&v != &a);
    CHECK(v.backend() == FftBackend::VkFFT);
    rt.set_fft_backend(FftBackend::VkFFT);
    CHECK(&rt.fft(64, 64, 3, Precision::F32) == &v);
    CHECK(&rt.fft(384, 384, 2, Precision::F32) != &v);  // shape and batch
    CHECK(&rt.fft(64, 64, 3, Precision::F32, FftBackend::VkFFT, {40, 64, 40, 64}) != &v);  // hint
    if (rt.has_fp64()) CHECK(&rt.fft(64, 64, 3, Precision::F64) != &v);  // precision
    CHECK(rt.fft_plan_count() == (rt.has_fp64() ? 5u : 4u));
    if (rt.info().type == "CPU") {
      FftPlan& w = rt.fft(64, 64, 3, Precision::F32, FftBackend::FFTW);
      CHECK(w.backend() == FftBackend::FFTW);
      CHECK(&w != &a);
      CHECK(&rt.fft(64, 64, 3, Precision::F32, FftBackend::FFTW) == &w);
    }
    CHECK(rt.fft_bake_seconds() > 0);
    CHECK(v.bytes() == 3 * 64 * 64 * 2 * 4);
  }

  TEST_CASE("FFTW wisdom beside the kernel cache: written after planning, a damaged file is ignored and rewritten") {
    if (!skip_unless(runtime().info().type == "CPU", "FFTW backend: the test device is not a CPU")) return;
    const auto dir = temp_dir("fftw_wisdom");
    const char* old = std::getenv("QDO_CACHE_DIR");
    const std::string saved = old ? old : "";
    setenv("QDO_CACHE_DIR", dir.string().c_str(), 1);
    const auto wisdom = dir / "fftw-wisdom-f32.txt";
    {
      std::ofstream(wisdom) << "(fftw-3.3 garbage ((( not wisdom";
      Runtime rt("", FftBackend::FFTW);
      const ComplexStack x = random_field(2, 48, 40, Precision::F32, 7);
      FftPlan& plan = rt.fft(48, 40, 2, Precision::F32);
      CHECK(diff(device_fft(rt, plan, x, true).data, fftw_ref(x, true).data).rel_l2 <= tol(Precision::F32, 48, 40));
    }
    std::ifstream in(wisdom);
    std::string head;
    std::getline(in, head);
    CHECK(head.rfind("(fftw-3", 0) == 0);
    CHECK(head.find("garbage") == std::string::npos);  // rewritten by FFTW's exporter
    if (old)
      setenv("QDO_CACHE_DIR", saved.c_str(), 1);
    else
      unsetenv("QDO_CACHE_DIR");
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("bad sizes, hints and buffers are rejected before any work") {
    Runtime& rt = runtime();
    for (FftBackend b : backends(rt)) {
      CAPTURE(to_string(b));
      const std::size_t before = rt.fft_plan_count();
      CHECK_THROWS_WITH_AS(rt.fft(0, 8, 1, Precision::F32, b), doctest::Contains("'rows' = 0"), InputError);
      CHECK_THROWS_WITH_AS(rt.fft(8, 0, 1, Precision::F32, b), doctest::Contains("'cols' = 0"), InputError);
      CHECK_THROWS_WITH_AS(rt.fft(8, 8, 0, Precision::F32, b), doctest::Contains("'batch' = 0"), InputError);
      CHECK_THROWS_WITH_AS(rt.fft(8, 8, 1, Precision::F32, b, {4, 9, 0, 0}), doctest::Contains("zero_pad rows"),
                           InputError);
      CHECK_THROWS_WITH_AS(rt.fft(8, 8, 1, Precision::F32, b, {0, 0, 6, 2}), doctest::Contains("zero_pad cols"),
                           InputError);
      CHECK(rt.fft_plan_count() == before);
      FftPlan& plan = rt.fft(64, 64, 3, Precision::F32, b);
      cl::Buffer small(rt.context(), CL_MEM_READ_WRITE, plan.bytes() - 8);
      CHECK_THROWS_WITH_AS(plan.forward(small), doctest::Contains("'data'"), InputError);
      CHECK_THROWS_WITH_AS(plan.inverse(small), doctest::Contains("at least 98304 bytes"), InputError);
    }
  }

  TEST_CASE("zero-padding hint: forward exact for zero-padded input, inverse exact inside the data rectangle") {
    // Layouts of a zero-padded field: data in the top-left corner of the window (zero rows and
    // columns [40, 64)); data at the four corners (the PSF path's N = 256 field in its M = 384
    // window stored with the optical axis at index 0: zero block [N/2, M - N/2) on both axes);
    // a hint on the rows only.
    Runtime& rt = runtime();
    struct Case {
      std::size_t rows, cols, batch;
      FftZeroPad zp;
    };
    const Case cases[] = {{64, 64, 3, {40, 64, 40, 64}}, {384, 384, 2, {128, 256, 128, 256}}, {64, 64, 3, {16, 48, 0, 0}}};
    unsigned seed = 301;
    for (FftBackend b : backends(rt))
      for (Precision p : precisions(rt))
        for (const Case& c : cases) {
          CAPTURE(to_string(b));
          CAPTURE(to_string(p));
          CAPTURE(c.rows);
          CAPTURE(c.zp.row_begin);
          FftPlan& plan = rt.fft(c.rows, c.cols, c.batch, p, b, c.zp);
          REQUIRE(plan.zero_pad().any());
          auto in_block = [&](std::size_t y, std::size_t x) {
            return (y >= c.zp.row_begin && y < c.zp.row_end) || (x >= c.zp.col_begin && x < c.zp.col_end);
          };
          ComplexStack x = random_field(c.batch, c.rows, c.cols, p, ++seed);
          for (std::size_t t = 0; t < c.batch; ++t)
            for (std::size_t y = 0; y < c.rows; ++y)
              for (std::size_t xx = 0; xx < c.cols; ++xx)
                if (in_block(y, xx)) x(t, y, xx) = 0;
          const double t_fwd = tol(p, c.rows, c.cols);
          CHECK(diff(device_fft(rt, plan, x, true).data, fftw_ref(x, true).data).rel_l2 <= t_fwd);

          // Inverse of a full random spectrum: compare inside the data rectangle only.
          const ComplexStack y = random_field(c.batch, c.rows, c.cols, p, ++seed);
          const ComplexStack got = device_fft(rt, plan, y, false), want = fftw_ref(y, false);
          std::vector<cdouble> g, w;
          for (std::size_t t = 0; t < c.batch; ++t)
            for (std::size_t r = 0; r < c.rows; ++r)
              for (std::size_t xx = 0; xx < c.cols; ++xx)
                if (!in_block(r, xx)) {
                  g.push_back(got(t, r, xx));
                  w.push_back(want(t, r, xx));
                }
          CHECK(diff(g, w).rel_l2 <= t_fwd);

          if (b == FftBackend::VkFFT) {
            // VkFFT must not read the zero block at all: NaNs there leave the forward result exact
            // (a plan that ignored the hint would return NaNs).
            ComplexStack poisoned = x;
            const double nan = std::numeric_limits<double>::quiet_NaN();
            for (std::size_t t = 0; t < c.batch; ++t)
              for (std::size_t r = 0; r < c.rows; ++r)
                for (std::size_t xx = 0; xx < c.cols; ++xx)
                  if (in_block(r, xx)) poisoned(t, r, xx) = cdouble(nan, nan);
            CHECK(diff(device_fft(rt, plan, poisoned, true).data, fftw_ref(x, true).data).rel_l2 <= t_fwd);
          }
        }
  }
}
