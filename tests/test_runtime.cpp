#include <cstdlib>

#include "common.hpp"
#include "qdo/error.hpp"
#include "qdo/fft.hpp"
#include "qdo/runtime.hpp"

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
