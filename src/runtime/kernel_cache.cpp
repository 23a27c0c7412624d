#include "qdo/runtime/kernel_cache.hpp"

#include <cstdint>
#include <cstring>

#include "qdo/runtime/hash.hpp"

namespace qdo {

namespace {

constexpr char kMagic[8] = {'Q', 'D', 'O', 'K', 'B', 'I', 'N', '1'};

std::uint64_t le64(const unsigned char* b) {
  std::uint64_t v = 0;
  for (int i = 7; i >= 0; --i) v = (v << 8) | b[i];
  return v;
}

std::uint64_t hash_bytes(const unsigned char* b, std::size_t n) { return Fnv1a64{}.add(b, n).h; }

}  // namespace

std::vector<unsigned char> encode_kernel_cache_entry(const unsigned char* binary, std::size_t size) {
  std::vector<unsigned char> e(kKernelCacheHeaderBytes + size);
  std::memcpy(e.data(), kMagic, sizeof kMagic);
  const std::uint64_t fields[2] = {size, hash_bytes(binary, size)};
  for (int f = 0; f < 2; ++f)
    for (int i = 0; i < 8; ++i) e[8 + 8 * std::size_t(f) + std::size_t(i)] = static_cast<unsigned char>(fields[f] >> (8 * i));
  if (size) std::memcpy(e.data() + kKernelCacheHeaderBytes, binary, size);
  return e;
}

KernelCacheEntry decode_kernel_cache_entry(const unsigned char* bytes, std::size_t size) {
  KernelCacheEntry r;
  constexpr std::size_t kHead = kKernelCacheHeaderBytes;
  if (size < kHead || std::memcmp(bytes, kMagic, sizeof kMagic) != 0)
    r.problem = "not a qdo cache entry (" + std::to_string(size) + " bytes, no header)";
  else if (le64(bytes + 8) != size - kHead)
    r.problem = "truncated or padded (header says " + std::to_string(le64(bytes + 8)) + " bytes, holds " +
                std::to_string(size - kHead) + ")";
  else if (le64(bytes + 16) != hash_bytes(bytes + kHead, size - kHead))
    r.problem = "corrupt (hash mismatch)";
  else
    r.binary.assign(bytes + kHead, bytes + size);
  return r;
}

}  // namespace qdo
