// Helpers shared by the tests of the file I/O layer (doctest suite "io", tests/test_io_*.cpp).
#pragma once
#include <unistd.h>

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <sstream>
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

// A PNG chunk (length, type, data, CRC-32 of type and data; PNG spec section 5.3) inserted right
// after the IHDR chunk of the file at `path`, as other tools write ancillary chunks (ImageMagick:
// gAMA, cHRM; most cameras' software: sRGB or iCCP).
inline void add_png_chunk(const std::string& path, const std::string& type, const std::string& data) {
  std::string b;
  {
    std::ifstream in(path, std::ios::binary);
    std::stringstream ss;
    ss << in.rdbuf();
    b = ss.str();
  }
  auto crc32 = [](const std::string& s) {
    std::uint32_t c = 0xffffffffu;
    for (unsigned char ch : s) {
      c ^= ch;
      for (int k = 0; k < 8; ++k) c = (c >> 1) ^ (0xedb88320u & (0u - (c & 1u)));
    }
    return c ^ 0xffffffffu;
  };
  auto be32 = [](std::uint32_t v) {
    std::string o(4, '\0');
    for (int i = 0; i < 4; ++i) o[std::size_t(i)] = static_cast<char>((v >> (24 - 8 * i)) & 0xffu);
    return o;
  };
  const std::string chunk = be32(static_cast<std::uint32_t>(data.size())) + type + data + be32(crc32(type + data));
  b.insert(33, chunk);  // 8-byte signature + IHDR (4 length, 4 type, 13 data, 4 CRC)
  std::ofstream(path, std::ios::binary | std::ios::trunc) << b;
}
// gAMA with gamma 1/2.2 (45455 in units of 1e-5): what ImageMagick writes by default.
inline std::string gama_2_2() { return std::string("\x00\x00\xb1\x8f", 4); }

}  // namespace qdo::test::io_suite
