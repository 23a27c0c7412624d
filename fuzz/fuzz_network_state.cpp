// Fuzz target: a network run's state file as `qdo design --resume` reads it (read_network_state,
// design/network_state.hpp): the checkpoint records the file's name and FNV-1a checksum. The input
// is the checksum the checkpoint recorded (its first line) and the file's bytes (the rest). The
// reader must return exactly the file's bytes, and only when they hash to the recorded checksum;
// otherwise an InputError naming the file.
#include "design/network_state.hpp"
#include "fuzz_util.hpp"
#include "qdo/runtime/hash.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace qdo;
  namespace fs = std::filesystem;
  const std::string in(reinterpret_cast<const char*>(data), size);
  const std::size_t eol = in.find('\n');
  const std::string recorded = eol == std::string::npos ? in : in.substr(0, eol);
  const std::string bytes = eol == std::string::npos ? std::string() : in.substr(eol + 1);
  const fs::path dir = fuzz::scratch().dir() / "netrun";
  fs::create_directories(dir / "network");
  const std::string name = "network/step_00000002.pt";
  const std::string path = fuzz::scratch().write("netrun/" + name, reinterpret_cast<const std::uint8_t*>(bytes.data()), bytes.size());
  DesignState s;
  s.network_file = name;
  s.network_checksum = recorded;
  Fnv1a64 h;
  h.add(bytes.data(), bytes.size());
  try {
    const std::string got = read_network_state(dir, s, (dir / "checkpoint.h5").string());
    if (got != bytes) fuzz::fail("read_network_state returned other bytes than the file's");
    if (h.hex() != recorded) fuzz::fail("read_network_state accepted a checksum mismatch");
  } catch (const InputError& e) {
    fuzz::expect_names(e, path);
    if (h.hex() == recorded) fuzz::fail("read_network_state refused a file with the recorded checksum");
  }
  return 0;
}
