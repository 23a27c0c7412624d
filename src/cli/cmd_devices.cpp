// qdo devices: the OpenCL platforms and devices with the default choice.
#include <cstdio>

#include "cli.hpp"
#include "options.hpp"
#include "qdo/runtime/runtime.hpp"

namespace qdo::cli {

static int cmd_devices(const Args&) {
  const auto devs = list_devices();
  for (const auto& d : devs)
    std::printf("%zu:%zu  %s / %s  [%s]  driver %s  %s  fp64 %s  %u CUs  %.1f GiB\n", d.platform_index, d.device_index,
                d.platform.c_str(), d.name.c_str(), d.type.c_str(), d.driver_version.c_str(), d.version.c_str(),
                d.fp64 ? "yes" : "no", d.compute_units, double(d.global_mem_bytes) / 1073741824.0);
  Runtime rt;
  std::printf("default: %zu:%zu %s\n", rt.info().platform_index, rt.info().device_index, rt.info().name.c_str());
  return 0;
}

namespace {
// qdo devices: its entry in the command table (help order 10).
const RegisterCommand registered_devices(10, [] {
  using namespace opts;
  CommandSpec c{"devices", "list the OpenCL platforms and devices and the default choice", "", "", {}, cmd_devices};
  return c;
});
}  // namespace

}  // namespace qdo::cli
