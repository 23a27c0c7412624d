// The qdo tool's network decoder, loaded on demand: the LibTorch Res-UNet (src/net) is built as
// the plugin module libqdo-net.so, which the tool dlopen()s the first time a network decoder is
// asked for (register_network_loader, network_decoder.hpp). Every other command starts without
// LibTorch (loading it costs ~0.5 s of static initialisers on a 2-core machine; BENCHMARKS.md
// "CPU speed"). The plugin resolves qdo_core's symbols against this executable (linked with
// --export-dynamic and the whole of qdo_core), so there is one registry, one kernel cache and one
// set of exception types.
//
// Where the plugin is looked for, first found wins:
//   1. $QDO_NET_PLUGIN (a path; when set and it does not load, that is the error: no fallback);
//   2. beside the executable (the build tree: build/qdo and build/libqdo-net.so);
//   3. <executable's folder>/QDO_NET_PLUGIN_RELDIR (the install: bin/../lib/qdo).
#include "cli.hpp"

#include <dlfcn.h>
#include <unistd.h>

#include <climits>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include "qdo/decode/network_decoder.hpp"

#ifndef QDO_NET_PLUGIN_FILE
#define QDO_NET_PLUGIN_FILE "libqdo-net.so"
#endif
#ifndef QDO_NET_PLUGIN_RELDIR
#define QDO_NET_PLUGIN_RELDIR "../lib/qdo"
#endif

namespace qdo::cli {
namespace {

std::filesystem::path executable_dir() {
  std::vector<char> buf(PATH_MAX + 1, '\0');
  const ssize_t len = ::readlink("/proc/self/exe", buf.data(), buf.size() - 1);
  if (len <= 0) return {};
  return std::filesystem::path(std::string(buf.data(), std::size_t(len))).parent_path();
}

// dlopen + the registration entry point; "" on success, else the reason.
std::string load(const std::filesystem::path& file) {
  void* h = ::dlopen(file.c_str(), RTLD_NOW | RTLD_LOCAL);
  if (!h) {
    const char* e = ::dlerror();
    return file.string() + ": " + (e ? e : "dlopen failed");
  }
  using Entry = void (*)();
  auto entry = reinterpret_cast<Entry>(::dlsym(h, "qdo_net_plugin_register"));
  if (!entry) return file.string() + ": no qdo_net_plugin_register symbol (not a qdo network plugin)";
  entry();  // registers the factory; the module stays loaded for the process's lifetime
  return "";
}

std::string load_plugin() {
  if (const char* env = std::getenv("QDO_NET_PLUGIN"); env && *env) return load(env);
  const std::filesystem::path dir = executable_dir();
  std::vector<std::filesystem::path> candidates{dir / QDO_NET_PLUGIN_FILE, dir / QDO_NET_PLUGIN_RELDIR / QDO_NET_PLUGIN_FILE};
  std::string tried;
  for (const auto& c : candidates) {
    std::error_code ec;
    if (!std::filesystem::exists(c, ec)) {
      tried += (tried.empty() ? "" : ", ") + c.string();
      continue;
    }
    return load(c);
  }
  return std::string(QDO_NET_PLUGIN_FILE) + " not found (looked in " + tried +
         "; set QDO_NET_PLUGIN to its path, or rebuild with -DQDO_TORCH=ON)";
}

}  // namespace

void register_net_plugin_loader() { register_network_loader(load_plugin); }

}  // namespace qdo::cli
