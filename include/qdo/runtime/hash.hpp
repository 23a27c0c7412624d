// FNV-1a, 64 bit: the one content hash qdo uses, for kernel-cache keys and entries, checkpoint
// checksums and sweep provenance. Fast and stable across runs and machines; not cryptographic.
#pragma once
#include <cstdint>
#include <cstdio>
#include <string>

namespace qdo {

struct Fnv1a64 {
  std::uint64_t h = 1469598103934665603ull;

  // n raw bytes.
  Fnv1a64& add(const void* data, std::size_t n) {
    const auto* p = static_cast<const unsigned char*>(data);
    for (std::size_t i = 0; i < n; ++i) {
      h ^= p[i];
      h *= 1099511628211ull;
    }
    return *this;
  }
  // A string's bytes and a '\0' separator, so ("ab", "c") and ("a", "bc") differ.
  Fnv1a64& add(const std::string& s) {
    add(s.data(), s.size());
    const unsigned char zero = 0;
    return add(&zero, 1);
  }
  // v as 8 bytes, little-endian whatever the host.
  Fnv1a64& add_u64(std::uint64_t v) {
    unsigned char b[8];
    for (int i = 0; i < 8; ++i) b[i] = static_cast<unsigned char>(v >> (8 * i));
    return add(b, 8);
  }
  // "fnv1a64:<16 hex digits>".
  std::string hex() const {
    char b[32];
    std::snprintf(b, sizeof b, "fnv1a64:%016llx", static_cast<unsigned long long>(h));
    return b;
  }
};

}  // namespace qdo
