#include "qdo/runtime/embedded.hpp"
#include "qdo/runtime/error.hpp"

namespace qdo {
const std::string& embedded_file(const std::string& name) {
  const auto& files = embedded_files();
  auto it = files.find(name);
  if (it == files.end()) {
    std::string names;
    for (const auto& kv : files) names += (names.empty() ? "" : ", ") + kv.first;
    throw Error("no embedded file '" + name + "' (embedded: " + names + ")");
  }
  return it->second;
}
}  // namespace qdo
