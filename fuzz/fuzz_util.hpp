// Shared pieces of the fuzz targets (fuzz/fuzz_*.cpp).
//
// Each target defines LLVMFuzzerTestOneInput. Built with -DQDO_FUZZ=ON (clang,
// -fsanitize=fuzzer,address,undefined) it is a libFuzzer binary; built normally, the same
// source is compiled with LLVMFuzzerTestOneInput renamed (see CMakeLists.txt) into
// qdo_fuzz_replay, which runs every file of fuzz/corpus/<target>/ through it (CTest
// "fuzz-regression"). A target accepts any input: the reader must either succeed or throw
// qdo::InputError whose message names the file. Anything else (another exception, a crash, a
// sanitizer report, an invariant below) is a finding.
#pragma once
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "qdo/runtime/error.hpp"

namespace qdo::fuzz {

// A violated expectation: thrown, never caught by the targets, so libFuzzer reports it as a
// crash (uncaught exception -> abort) and the replay driver names the input.
[[noreturn]] inline void fail(const std::string& what) { throw std::logic_error("fuzz invariant violated: " + what); }

// A private folder for this process (removed at exit), under /dev/shm when it exists.
class Scratch {
 public:
  Scratch() {
    namespace fs = std::filesystem;
    std::error_code ec;
    const fs::path base = fs::is_directory("/dev/shm", ec) ? fs::path("/dev/shm") : fs::temp_directory_path();
    dir_ = base / ("qdo_fuzz_" + std::to_string(static_cast<long>(::getpid())));
    fs::create_directories(dir_);
  }
  Scratch(const Scratch&) = delete;
  Scratch& operator=(const Scratch&) = delete;
  ~Scratch() {
    std::error_code ec;
    std::filesystem::remove_all(dir_, ec);
  }
  // Writes the input to <scratch>/<name> (replacing it) and returns the path.
  std::string write(const std::string& name, const std::uint8_t* data, std::size_t size) const {
    const std::string path = (dir_ / name).string();
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
    out.close();
    if (!out) fail("cannot write scratch file " + path);
    return path;
  }
  std::string path(const std::string& name) const { return (dir_ / name).string(); }
  const std::filesystem::path& dir() const { return dir_; }

 private:
  std::filesystem::path dir_;
};

inline Scratch& scratch() {
  static Scratch s;
  return s;
}

// An InputError must name the input (the file, folder or origin label).
inline void expect_names(const InputError& e, const std::string& name) {
  const std::string msg = e.what();
  if (msg.find(name) == std::string::npos) fail("InputError does not name '" + name + "': " + msg);
}

// One input holding several files: the parts between occurrences of kFileSeparator (a line of
// its own). Targets that read a folder write part k to their k-th file name; a file without a
// part is absent. Binary parts (HDF5) may hold anything but the separator.
inline const std::string kFileSeparator = "\n==qdo-fuzz-next-file==\n";
inline std::vector<std::string> split_files(const std::uint8_t* data, std::size_t size) {
  const std::string in(reinterpret_cast<const char*>(data), size);
  std::vector<std::string> parts;
  std::size_t from = 0;
  for (std::size_t at; (at = in.find(kFileSeparator, from)) != std::string::npos; from = at + kFileSeparator.size())
    parts.push_back(in.substr(from, at - from));
  parts.push_back(in.substr(from));
  return parts;
}

}  // namespace qdo::fuzz
