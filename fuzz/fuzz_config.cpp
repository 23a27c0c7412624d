// Fuzz target: JSON system configurations (config_from_json_text); an accepted configuration
// must survive a write / read round trip unchanged.
#include "fuzz_util.hpp"
#include "qdo/data/config.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace qdo;
  const std::string text(reinterpret_cast<const char*>(data), size);
  try {
    const SystemConfig c = config_from_json_text(text, "fuzz.json");
    const std::string out = config_to_json_text(c);
    try {
      if (config_to_json_text(config_from_json_text(out, "roundtrip.json")) != out) fuzz::fail("round trip changed the configuration");
    } catch (const InputError& e) {
      fuzz::fail(std::string("a configuration we wrote does not read back: ") + e.what());
    }
  } catch (const InputError& e) {
    fuzz::expect_names(e, "fuzz.json");
  }
  return 0;
}
