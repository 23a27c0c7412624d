// qdo config: the system configuration (--preset or --config) as JSON.
#include <iostream>

#include "cli.hpp"
#include "options.hpp"
#include "qdo/data/config.hpp"

namespace qdo::cli {

static int cmd_config(const Args& a) {
  std::cout << config_to_json_text(load_config(a)) << "\n";
  return 0;
}

namespace {
// qdo config: its entry in the command table (help order 20).
const RegisterCommand registered_config(20, [] {
  using namespace opts;
  CommandSpec c{"config", "print the system configuration as JSON", "", "", {preset(), config()}, cmd_config};
  return c;
});
}  // namespace

}  // namespace qdo::cli
