#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <sstream>
#include <string>
#include <type_traits>
#include <vector>

#include "common.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/fft.hpp"
#include "qdo/runtime/kernel_cache.hpp"
#include "qdo/runtime/runtime.hpp"

using namespace qdo;
using namespace qdo::test;

TEST_SUITE("runtime") {
  TEST_CASE("devices are listed and selected by type, index and name") {
    const auto devs = list_devices();
    REQUIRE(!devs.empty());
    Runtime by_index(std::to_string(devs[0].platform_index) + ":" + std::to_string(devs[0].device_index));
    CHECK(by_index.info().name == devs[0].name);
    Runtime by_name(devs[0].name.substr(0, 6));
    CHECK(by_name.info().name == devs[0].name);
    CHECK_THROWS_WITH_AS(Runtime("no-such-device-xyz"), doctest::Contains("'device'"), InputError);
  }

  TEST_CASE("programs are cached on disk and reloaded by a fresh runtime") {
    const auto dir = temp_dir("kcache");
    setenv("QDO_CACHE_DIR", dir.c_str(), 1);
    {
      Runtime a;
      a.kernel("psf.cl", "band_sums", Precision::F32);
      CHECK(a.programs_built() == 1);
      CHECK(a.programs_loaded_from_disk() == 0);
      a.kernel("psf.cl", "finalize_sums", Precision::F32);  // same program: memory cache
      CHECK(a.programs_built() == 1);
    }
    {
      Runtime b;
      b.kernel("psf.cl", "band_sums", Precision::F32);
      CHECK(b.programs_built() == 0);
      CHECK(b.programs_loaded_from_disk() == 1);
      b.kernel("psf.cl", "band_sums", Precision::F32, "-DQDO_UNUSED_OPTION=1");  // options are part of the key
      CHECK(b.programs_built() == 1);
    }
    unsetenv("QDO_CACHE_DIR");
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("a truncated or corrupt kernel cache entry is rebuilt from source with a note, never fatal") {
    const auto dir = temp_dir("kcache_bad");
    setenv("QDO_CACHE_DIR", dir.c_str(), 1);
    {
      Runtime a;
      a.kernel("psf.cl", "band_sums", Precision::F32);
      CHECK(a.programs_built() == 1);
    }
    std::filesystem::path entry;
    for (const auto& e : std::filesystem::directory_iterator(dir))
      if (e.path().extension() == ".bin") entry = e.path();
    REQUIRE(!entry.empty());
    const auto full = std::filesystem::file_size(entry);
    auto slurp = [&] {
      std::ifstream in(entry, std::ios::binary);
      std::ostringstream os;
      os << in.rdbuf();
      return os.str();
    };
    const std::string good = slurp();
    auto spit = [&](const std::string& bytes) { std::ofstream(entry, std::ios::binary | std::ios::trunc) << bytes; };
    // Each damage: a fresh runtime rebuilds from source, says so in one line on stderr, and
    // rewrites the entry, which the next runtime loads again.
    const std::vector<std::string> damaged = {
        good.substr(0, full / 2), good.substr(0, 10), std::string(),
        [&] { std::string b = good; b[b.size() / 2] = static_cast<char>(b[b.size() / 2] ^ 0x40); return b; }(),
        [&] { std::string b = good; for (std::size_t i = 24; i < b.size(); i += 7) b[i] = 'x'; return b; }(),
        good.substr(24)};  // a bare binary without the header (as older qdo wrote)
    for (std::size_t k = 0; k < damaged.size(); ++k) {
      CAPTURE(k);
      spit(damaged[k]);
      std::ostringstream err;
      std::streambuf* old = std::cerr.rdbuf(err.rdbuf());
      int built = -1;
      try {
        Runtime b;
        b.kernel("psf.cl", "band_sums", Precision::F32);
        built = b.programs_built();
      } catch (...) {
        std::cerr.rdbuf(old);
        throw;
      }
      std::cerr.rdbuf(old);
      CHECK(built == 1);
      CHECK(err.str().find("kernel cache entry " + entry.string()) != std::string::npos);
      CHECK(err.str().find("rebuilding from source") != std::string::npos);
      CHECK(slurp().size() > 24);  // rewritten (PoCL binaries need not be byte-identical across builds)
      Runtime c;
      c.kernel("psf.cl", "band_sums", Precision::F32);
      CHECK(c.programs_loaded_from_disk() == 1);
      CHECK(c.programs_built() == 0);
    }
    unsetenv("QDO_CACHE_DIR");
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("kernel cache entries: encode/decode round trip; each damage is named, without a device") {
    std::string bin = "pretend program binary";
    bin += std::string(3, '\0') + "\x7f";  // any bytes, zeros included
    const auto* b = reinterpret_cast<const unsigned char*>(bin.data());
    const std::vector<unsigned char> e = encode_kernel_cache_entry(b, bin.size());
    REQUIRE(e.size() == kKernelCacheHeaderBytes + bin.size());
    CHECK(std::string(e.begin(), e.begin() + 8) == "QDOKBIN1");
    CHECK(e[8] == bin.size());  // size, little-endian
    const KernelCacheEntry ok = decode_kernel_cache_entry(e.data(), e.size());
    CHECK(ok.problem.empty());
    CHECK(std::string(ok.binary.begin(), ok.binary.end()) == bin);
    // An empty binary is a valid (if useless) entry; the runtime then fails to build from it.
    const auto empty = encode_kernel_cache_entry(nullptr, 0);
    CHECK(decode_kernel_cache_entry(empty.data(), empty.size()).problem.empty());
    auto problem = [](std::vector<unsigned char> v) {
      const KernelCacheEntry r = decode_kernel_cache_entry(v.data(), v.size());
      CHECK(r.binary.empty());
      return r.problem;
    };
    CHECK(problem({}) == "not a qdo cache entry (0 bytes, no header)");
    CHECK(problem(std::vector<unsigned char>(e.begin(), e.begin() + 23)) == "not a qdo cache entry (23 bytes, no header)");
    auto magic = e;
    magic[7] = '2';
    CHECK(problem(magic) == "not a qdo cache entry (" + std::to_string(e.size()) + " bytes, no header)");
    CHECK(problem(std::vector<unsigned char>(e.begin(), e.end() - 1)) ==
          "truncated or padded (header says " + std::to_string(bin.size()) + " bytes, holds " + std::to_string(bin.size() - 1) + ")");
    auto padded = e;
    padded.push_back(0);
    CHECK(problem(padded).rfind("truncated or padded", 0) == 0);
    auto flipped = e;
    flipped.back() ^= 1;
    CHECK(problem(flipped) == "corrupt (hash mismatch)");
    auto hash = e;
    hash[16] ^= 1;
    CHECK(problem(hash) == "corrupt (hash mismatch)");
  }

  TEST_CASE("Real maps to the device precision's real type") {
    static_assert(std::is_same<device_real_t<Precision::F32>, float>::value, "F32 real is float");
    static_assert(std::is_same<device_real_t<Precision::F64>, double>::value, "F64 real is double");
    CHECK(sizeof(device_real_t<Precision::F32>) == real_size(Precision::F32));
    CHECK(sizeof(device_real_t<Precision::F64>) == real_size(Precision::F64));
  }

  TEST_CASE("launch_1d sets the arguments in order, Real in the launch precision, over n items") {
    // expand_params(params, heights, n, kind, h_max): heights = clamp(params, 0, h_max) for kind 0;
    // n * n = 169 items, not a multiple of the work-group size. h_max = 0.1 is not a float, so
    // the clamped values tell which precision h_max arrived in.
    Runtime& rt = runtime();
    const int n = 13;
    const double h_max = 0.1;
    std::vector<double> x(std::size_t(n * n));
    for (std::size_t i = 0; i < x.size(); ++i) x[i] = 0.25 * std::sin(0.7 * double(i));
    for (Precision p : device_precisions(rt)) {
      CAPTURE(to_string(p));
      cl::Kernel k = rt.kernel("doe.cl", "expand_params", p);
      std::vector<char> bytes(x.size() * real_size(p));
      for (std::size_t i = 0; i < x.size(); ++i) {
        if (p == Precision::F64)
          reinterpret_cast<double*>(bytes.data())[i] = x[i];
        else
          reinterpret_cast<float*>(bytes.data())[i] = float(x[i]);
      }
      cl::Buffer in(rt.context(), CL_MEM_READ_ONLY | CL_MEM_COPY_HOST_PTR, bytes.size(), bytes.data());
      cl::Buffer out(rt.context(), CL_MEM_READ_WRITE, bytes.size());
      for (int pass = 0; pass < 2; ++pass) {  // the member and the static (explicit queue) form
        std::vector<char> zeros(bytes.size(), 0);
        rt.queue().enqueueWriteBuffer(out, CL_TRUE, 0, zeros.size(), zeros.data());
        if (pass == 0)
          rt.launch_1d(k, x.size(), p, in, out, n, 0, Real{h_max});
        else
          Runtime::launch_1d(rt.queue(), k, x.size(), p, in, out, n, 0, Real{h_max});
        std::vector<char> got(bytes.size());
        rt.queue().enqueueReadBuffer(out, CL_TRUE, 0, got.size(), got.data());
        int bad = 0;
        for (std::size_t i = 0; i < x.size(); ++i) {
          const double v = p == Precision::F64 ? reinterpret_cast<const double*>(got.data())[i]
                                               : double(reinterpret_cast<const float*>(got.data())[i]);
          const double want = p == Precision::F64 ? std::min(std::max(x[i], 0.0), h_max)
                                                  : double(std::min(std::max(float(x[i]), 0.0f), float(h_max)));
          if (v != want) ++bad;
        }
        CHECK(bad == 0);
      }
    }
  }

  TEST_CASE("a kernel build failure reports the device and the full build log") {
    Runtime& rt = runtime();
    try {
      rt.kernel_from_source("broken.cl", "__kernel void k(__global real* x) { x[0] = this_is_not_a_function(1); }", "k",
                            Precision::F32);
      FAIL("expected a build failure");
    } catch (const DeviceError& e) {
      const std::string msg = e.what();
      CHECK(msg.find(rt.info().name) != std::string::npos);
      CHECK(msg.find("Build log") != std::string::npos);
      CHECK(msg.find("this_is_not_a_function") != std::string::npos);
    }
  }

  TEST_CASE("the FFT plan matches a direct DFT, forward and inverse") {
    Runtime& rt = runtime();
    const std::size_t rows = 6, cols = 10, batch = 2;
    std::vector<double> x(rows * cols * batch * 2);
    for (std::size_t i = 0; i < x.size(); ++i) x[i] = std::sin(0.37 * double(i)) + 0.1 * double(i % 7);
    for (Precision p : {Precision::F32, Precision::F64}) {
      if (p == Precision::F64 && !skip_unless(rt.has_fp64(), "float64 cases: the device has no float64")) continue;
      CAPTURE(to_string(p));
      std::vector<char> bytes(x.size() * real_size(p));
      for (std::size_t i = 0; i < x.size(); ++i) {
        if (p == Precision::F64) reinterpret_cast<double*>(bytes.data())[i] = x[i];
        else reinterpret_cast<float*>(bytes.data())[i] = float(x[i]);
      }
      cl::Buffer buf(rt.context(), CL_MEM_READ_WRITE | CL_MEM_COPY_HOST_PTR, bytes.size(), bytes.data());
      FftPlan& plan = rt.fft(rows, cols, batch, p);
      plan.forward(buf);
      rt.queue().enqueueReadBuffer(buf, CL_TRUE, 0, bytes.size(), bytes.data());
      auto get = [&](std::size_t i) {
        return p == Precision::F64 ? reinterpret_cast<double*>(bytes.data())[i] : double(reinterpret_cast<float*>(bytes.data())[i]);
      };
      double max_err = 0;
      for (std::size_t t = 0; t < batch; ++t)
        for (std::size_t ky = 0; ky < rows; ++ky)
          for (std::size_t kx = 0; kx < cols; ++kx) {
            cdouble acc = 0;
            for (std::size_t y = 0; y < rows; ++y)
              for (std::size_t xx = 0; xx < cols; ++xx) {
                const std::size_t i = (t * rows + y) * cols + xx;
                acc += cdouble(x[2 * i], x[2 * i + 1]) *
                       std::polar(1.0, -2 * M_PI * (double(ky * y) / double(rows) + double(kx * xx) / double(cols)));
              }
            const std::size_t o = (t * rows + ky) * cols + kx;
            max_err = std::max(max_err, std::abs(cdouble(get(2 * o), get(2 * o + 1)) - acc));
          }
      CHECK(max_err <= 64 * eps(p) * 60);
      plan.inverse(buf);
      rt.queue().enqueueReadBuffer(buf, CL_TRUE, 0, bytes.size(), bytes.data());
      double back = 0;
      for (std::size_t i = 0; i < x.size(); ++i) back = std::max(back, std::fabs(get(i) - x[i]));
      CHECK(back <= 64 * eps(p));
    }
  }
}
