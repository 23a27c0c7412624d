// qdo devices and qdo config, two informational commands sharing one file: the OpenCL platforms
// and devices with the default choice, and the system configuration as JSON.
#include <cstdio>
#include <iostream>

#include "cli.hpp"
#include "qdo/data/config.hpp"
#include "qdo/runtime/runtime.hpp"

namespace qdo::cli {

int cmd_devices(const Args&) {
  const auto devs = list_devices();
  for (const auto& d : devs)
    std::printf("%zu:%zu  %s / %s  [%s]  driver %s  %s  fp64 %s  %u CUs  %.1f GiB\n", d.platform_index, d.device_index,
                d.platform.c_str(), d.name.c_str(), d.type.c_str(), d.driver_version.c_str(), d.version.c_str(),
                d.fp64 ? "yes" : "no", d.compute_units, double(d.global_mem_bytes) / 1073741824.0);
  Runtime rt;
  std::printf("default: %zu:%zu %s\n", rt.info().platform_index, rt.info().device_index, rt.info().name.c_str());
  return 0;
}

int cmd_config(const Args& a) {
  std::cout << config_to_json_text(load_config(a)) << "\n";
  return 0;
}

}  // namespace qdo::cli
