// Helpers shared by the tests of the file I/O layer (doctest suite "io", tests/test_io_*.cpp).
#pragma once
#include <unistd.h>

#include <filesystem>
#include <iterator>
#include <string>
#include <system_error>

namespace qdo::test::io_suite {

// A fresh directory under the temp dir, removed with everything in it at scope exit.
struct TmpDir {
  std::filesystem::path dir;
  TmpDir() {
    static int counter = 0;
    dir = std::filesystem::temp_directory_path() /
          ("qdo_io_test_" + std::to_string(static_cast<long>(::getpid())) + "_" + std::to_string(counter++));
    std::filesystem::remove_all(dir);
    std::filesystem::create_directories(dir);
  }
  ~TmpDir() {
    std::error_code ec;
    std::filesystem::remove_all(dir, ec);
  }
  std::string operator/(const std::string& name) const { return (dir / name).string(); }
  std::size_t entries() const {
    return static_cast<std::size_t>(
        std::distance(std::filesystem::directory_iterator(dir), std::filesystem::directory_iterator()));
  }
};

inline bool contains(const std::string& s, const std::string& part) { return s.find(part) != std::string::npos; }

}  // namespace qdo::test::io_suite
