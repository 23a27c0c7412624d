// Private to src/: what datasets_formats.cpp, datasets_index.cpp and datasets_synthetic.cpp
// share (the HDF5 and MATLAB handles and the "file '...'" failures come from io_internal.hpp).
// Not installed; the public API is include/qdo/data/datasets.hpp.
#pragma once

#include <cstdint>
#include <cstddef>
#include <filesystem>
#include <limits>
#include <random>
#include <string>

#include "data/io_internal.hpp"
#include "qdo/data/datasets.hpp"

namespace qdo::datasets_detail {

// "file '<file>': <problem>"
[[noreturn]] inline void fail(const std::string& file, const std::string& problem) {
  io_detail::fail(file, "", problem);
}
[[noreturn]] void fail_dir(const std::string& dir, const std::string& problem);

std::string lower_ext(const std::filesystem::path& p);
std::string shape_str(const SceneShape& s);
void check_format(const std::string& format);
std::string resolve_format(const std::string& path, const std::string& format);

// ---------------------------------------------------------------------------------------
// Random numbers: std::mt19937_64 (its output sequence is fixed by the standard) with our
// own integer -> range mappings, since the std distributions differ between libraries.
// ---------------------------------------------------------------------------------------

inline std::uint64_t splitmix64(std::uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}
inline std::uint64_t mix_seed(std::uint64_t seed, std::uint64_t stream) { return splitmix64(splitmix64(seed) ^ (stream * 0xD1B54A32D192ED03ull)); }

// Uniform in [0, 1).
inline double uniform01(std::mt19937_64& rng) { return static_cast<double>(rng() >> 11) * (1.0 / 9007199254740992.0); }
inline double uniform(std::mt19937_64& rng, double a, double b) { return a + (b - a) * uniform01(rng); }
// Uniform in 0 .. n-1 (n > 0), unbiased by rejection.
inline std::size_t uniform_below(std::mt19937_64& rng, std::size_t n) {
  const std::uint64_t un = n;
  const std::uint64_t limit = std::numeric_limits<std::uint64_t>::max() - std::numeric_limits<std::uint64_t>::max() % un;
  std::uint64_t r = rng();
  while (r >= limit) r = rng();
  return static_cast<std::size_t>(r % un);
}

}  // namespace qdo::datasets_detail
