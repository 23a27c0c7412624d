// Stability suite (doctest suite "stress", STABILITY.md): device faults become clear
// messages (a kernel that does not build, an unknown kernel, an allocation beyond the device,
// no such device type, no float64), through the library and through the qdo binary.
#include <cstdlib>
#include <string>

#include "stress_common.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/physics/simulator.hpp"

using namespace qdo;
using namespace qdo::test;
using namespace qdo::test::stress_suite;
namespace fs = std::filesystem;

TEST_SUITE("stress") {
  TEST_CASE("device faults become clear messages: build failure, unknown kernel, allocation beyond the device") {
    Runtime& rt = runtime();
    for (Precision p : {Precision::F32, Precision::F64}) {
      CAPTURE(to_string(p));
      try {
        rt.kernel_from_source("stress_broken.cl", "__kernel void k(__global real* x) { x[0] = undefined_thing; }", "k", p);
        FAIL("expected a build failure");
      } catch (const DeviceError& e) {
        const std::string msg = e.what();
        CHECK(has(msg, rt.info().name));
        CHECK(has(msg, "stress_broken.cl"));
        CHECK(has(msg, "undefined_thing"));  // the build log
      }
      CHECK_THROWS_WITH_AS(rt.kernel("psf.cl", "no_such_kernel", p), doctest::Contains("no_such_kernel"), DeviceError);
    }
    // A configuration whose padded field exceeds the device's largest allocation is refused by
    // the Simulator before any allocation or kernel build, naming n, the size and the limit.
    SystemConfig big = tiny_config(32, 3);
    big.n = 16384;
    big.padding_px = 4 * big.n;
    big.pitch_m = 1e-6;
    big.sensor_pitch_m = 1e-6;
    big.sensor_distance_m = 1e-3;
    big.bands = 31;
    big.wavelength_start_nm = 400;
    big.wavelength_step_nm = 10;
    big.validate();
    CHECK_THROWS_WITH_AS(Simulator(rt, big, Precision::F32), doctest::Contains("largest allocation"), InputError);
    // The same through the CLI: exit code 2 and the message.
    const auto dir = temp_dir("stress_cli");
    write_text_atomic((dir / "big.json").string(), config_to_json_text(big));
    const std::string log = (dir / "log.txt").string();
    Child c({QDO_QDO_BINARY, "psf", "--config", (dir / "big.json").string(), "--design", "flat", "--out", (dir / "o").string()}, log);
    CHECK(c.exit_code() == 2);
    CHECK(has(slurp(log), "largest allocation"));
    // No such device type: an InputError listing the devices there are.
    bool have_gpu = false;
    for (const auto& d : list_devices()) have_gpu = have_gpu || d.type == "GPU";
    if (!have_gpu) CHECK_THROWS_WITH_AS(Runtime("gpu"), doctest::Contains("'device'"), InputError);
    fs::remove_all(dir);
  }

  TEST_CASE("a device without fp64 refuses float64 with the device named") {
    // Runtime honours QDO_DISABLE_FP64=1 (clears DeviceInfo::fp64), so this path runs anywhere:
    //   Runtime::require(F64) -> DeviceError "device '<name>' (<platform>) has no double precision
    //   (cl_khr_fp64); use --precision f32 or another device"; CLI exit code 4.
    setenv("QDO_DISABLE_FP64", "1", 1);
    Runtime rt;
    unsetenv("QDO_DISABLE_FP64");
    CHECK_FALSE(rt.has_fp64());
    CHECK_THROWS_WITH_AS(Simulator(rt, tiny_config(32, 3), Precision::F64), doctest::Contains("cl_khr_fp64"), DeviceError);
  }
}
