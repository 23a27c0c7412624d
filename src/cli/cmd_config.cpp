// qdo config: the system configuration (--preset or --config) as JSON.
#include <iostream>

#include "cli.hpp"
#include "qdo/data/config.hpp"

namespace qdo::cli {

static int cmd_config(const Args& a) {
  std::cout << config_to_json_text(config_from_options(a)) << "\n";
  return 0;
}

// qdo config: its entry in the command table (help order 20).
const RegisterCommand registered_config(20, [] {
  using namespace opts;
  return CommandSpec{"config", "print the system configuration as JSON", "", "", {preset(), config()}, cmd_config};
});

}  // namespace qdo::cli
