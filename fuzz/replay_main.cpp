// qdo_fuzz_replay: runs every file of fuzz/corpus/<target>/ (the seeds and the regression
// inputs of crashes fuzzing found) through the target's entry point, without libFuzzer, so the
// normal build and CTest ("fuzz-regression") check them. Usage:
//   qdo_fuzz_replay CORPUS_DIR [TARGET]
// A target's entry point must return normally for every input (see fuzz_util.hpp); an
// exception escaping it is reported with the input's path and fails the run.
#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

// The entry points, renamed from LLVMFuzzerTestOneInput by the wrappers CMake generates.
extern "C" int qdo_fuzz_config(const std::uint8_t*, std::size_t);
extern "C" int qdo_fuzz_design_h5(const std::uint8_t*, std::size_t);
extern "C" int qdo_fuzz_cube_h5(const std::uint8_t*, std::size_t);
extern "C" int qdo_fuzz_mat(const std::uint8_t*, std::size_t);
extern "C" int qdo_fuzz_checkpoint(const std::uint8_t*, std::size_t);
extern "C" int qdo_fuzz_png(const std::uint8_t*, std::size_t);
extern "C" int qdo_fuzz_capture_png(const std::uint8_t*, std::size_t);
extern "C" int qdo_fuzz_capture_tiff(const std::uint8_t*, std::size_t);
extern "C" int qdo_fuzz_capture_raw(const std::uint8_t*, std::size_t);
extern "C" int qdo_fuzz_csv(const std::uint8_t*, std::size_t);
extern "C" int qdo_fuzz_kernel_cache(const std::uint8_t*, std::size_t);
extern "C" int qdo_fuzz_run_folder(const std::uint8_t*, std::size_t);
extern "C" int qdo_fuzz_sweep_cell(const std::uint8_t*, std::size_t);
extern "C" int qdo_fuzz_network_state(const std::uint8_t*, std::size_t);

namespace {

struct Target {
  const char* name;
  int (*entry)(const std::uint8_t*, std::size_t);
};
const Target kTargets[] = {{"config", qdo_fuzz_config},         {"design_h5", qdo_fuzz_design_h5},
                           {"cube_h5", qdo_fuzz_cube_h5},       {"mat", qdo_fuzz_mat},
                           {"checkpoint", qdo_fuzz_checkpoint}, {"png", qdo_fuzz_png},
                           {"capture_png", qdo_fuzz_capture_png}, {"capture_tiff", qdo_fuzz_capture_tiff}, {"capture_raw", qdo_fuzz_capture_raw},
                           {"csv", qdo_fuzz_csv},               {"kernel_cache", qdo_fuzz_kernel_cache},
                           {"run_folder", qdo_fuzz_run_folder},   {"sweep_cell", qdo_fuzz_sweep_cell},
                           {"network_state", qdo_fuzz_network_state}};

}  // namespace

int main(int argc, char** argv) {
  namespace fs = std::filesystem;
  if (argc < 2 || argc > 3) {
    std::fprintf(stderr, "usage: %s CORPUS_DIR [TARGET]\n", argv[0]);
    return 2;
  }
  const fs::path root = argv[1];
  const std::string only = argc == 3 ? argv[2] : "";
  int failures = 0;
  // Every corpus folder must belong to a target (a target added without registering it here).
  std::error_code ec;
  for (fs::directory_iterator it(root, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (it->is_directory() && std::none_of(std::begin(kTargets), std::end(kTargets), [&](const Target& t) { return name == t.name; })) {
      std::fprintf(stderr, "corpus folder '%s' has no target in replay_main.cpp\n", it->path().c_str());
      ++failures;
    }
  }
  if (ec) {
    std::fprintf(stderr, "cannot list '%s': %s\n", root.c_str(), ec.message().c_str());
    return 2;
  }
  for (const Target& t : kTargets) {
    if (!only.empty() && only != t.name) continue;
    const fs::path dir = root / t.name;
    std::vector<fs::path> files;
    for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec))
      if (it->is_regular_file()) files.push_back(it->path());
    if (ec || files.empty()) {
      std::fprintf(stderr, "%s: no corpus in '%s'\n", t.name, dir.c_str());
      ++failures;
      continue;
    }
    std::sort(files.begin(), files.end());
    int bad = 0;
    for (const fs::path& f : files) {
      std::ifstream in(f, std::ios::binary);
      const std::vector<char> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
      try {
        t.entry(reinterpret_cast<const std::uint8_t*>(bytes.data()), bytes.size());
      } catch (const std::exception& e) {
        std::fprintf(stderr, "FAIL %s %s: %s\n", t.name, f.c_str(), e.what());
        ++bad;
      }
    }
    std::printf("%-12s %3zu inputs, %d failed\n", t.name, files.size(), bad);
    failures += bad;
  }
  return failures == 0 ? 0 : 1;
}
