// qdo devices: the OpenCL platforms and devices with the default choice.
#include <cstdio>

#include "cli.hpp"
#include "qdo/runtime/runtime.hpp"

namespace qdo::cli {

static int cmd_devices(const Args&) {
  std::fputs(devices_report().c_str(), stdout);
  Runtime rt;
  std::printf("default: %zu:%zu %s\n", rt.info().platform_index, rt.info().device_index, rt.info().name.c_str());
  return 0;
}

// qdo devices: its entry in the command table (help order 10).
const RegisterCommand registered_devices(10, [] {
  return CommandSpec{"devices", "list the OpenCL platforms and devices and the default choice", "", "", {}, cmd_devices};
});

}  // namespace qdo::cli
