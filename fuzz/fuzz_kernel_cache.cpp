// Fuzz target: one kernel-cache entry (kernel_cache.hpp), the bytes Runtime reads from its
// disk cache before handing a binary to OpenCL. Any input is either accepted (then its binary
// re-encodes to exactly the input, which decodes again to the same binary) or refused with a
// problem string, never an exception; no device is needed.
#include <cstring>
#include <vector>

#include "fuzz_util.hpp"
#include "qdo/runtime/kernel_cache.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace qdo;
  const KernelCacheEntry e = decode_kernel_cache_entry(data, size);
  if (!e.problem.empty()) {
    if (!e.binary.empty()) fuzz::fail("a refused kernel cache entry came with a binary");
    if (size >= kKernelCacheHeaderBytes && std::memcmp(data, "QDOKBIN1", 8) == 0 &&
        e.problem.rfind("not a qdo cache entry", 0) == 0)
      fuzz::fail("an entry with the magic was called headerless: " + e.problem);
    return 0;
  }
  if (e.binary.size() + kKernelCacheHeaderBytes != size) fuzz::fail("accepted entry's binary does not fill the entry");
  if (e.binary.size() && std::memcmp(e.binary.data(), data + kKernelCacheHeaderBytes, e.binary.size()) != 0)
    fuzz::fail("accepted entry's binary is not the bytes after the header");
  const std::vector<unsigned char> again = encode_kernel_cache_entry(e.binary.data(), e.binary.size());
  if (again.size() != size || std::memcmp(again.data(), data, size) != 0)
    fuzz::fail("re-encoding an accepted entry's binary does not give the entry back");
  const KernelCacheEntry twice = decode_kernel_cache_entry(again.data(), again.size());
  if (!twice.problem.empty() || twice.binary != e.binary) fuzz::fail("a re-encoded entry does not round-trip: " + twice.problem);
  return 0;
}
