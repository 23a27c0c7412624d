// The on-disk format of one kernel-cache entry (Runtime's disk cache of program binaries,
// runtime.hpp), without OpenCL, so it can be checked and fuzzed on its own. An entry is the
// 8-byte magic "QDOKBIN1", the binary's size and its FNV-1a-64 hash (uint64 each,
// little-endian), then the binary. The cache is untrusted: anything else is a problem the
// runtime reports in a one-line note before rebuilding the program from source.
#pragma once
#include <cstddef>
#include <string>
#include <vector>

namespace qdo {

constexpr std::size_t kKernelCacheHeaderBytes = 24;

// The entry holding `binary` (size bytes).
std::vector<unsigned char> encode_kernel_cache_entry(const unsigned char* binary, std::size_t size);

struct KernelCacheEntry {
  std::vector<unsigned char> binary;  // the program binary, when problem is empty
  std::string problem;                // empty: a whole, intact entry
};
// Checks an entry's bytes. problem is "" (and binary the entry's binary) when the header's magic,
// size and hash match the bytes; else it says what is wrong, as the runtime's note prints it:
// "not a qdo cache entry (N bytes, no header)", "truncated or padded (header says A bytes, holds
// B)" or "corrupt (hash mismatch)", and binary is empty. Never throws (but std::bad_alloc).
KernelCacheEntry decode_kernel_cache_entry(const unsigned char* bytes, std::size_t size);

}  // namespace qdo
