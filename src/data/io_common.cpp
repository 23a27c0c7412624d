// Shared helpers of the file readers and writers (declared in io_internal.hpp): the
// "file '<file>': <what>: <problem>" InputError, shapes and element counts, and the check that
// a file can hold the data it declares.
#include <algorithm>
#include <cmath>
#include <filesystem>

#include "data/io_internal.hpp"

namespace qdo::io_detail {

namespace fs = std::filesystem;

// "<file>: <what>: <problem>"
[[noreturn]] void fail(const std::string& file, const std::string& what, const std::string& problem) {
  throw InputError("file '" + file + "'" + (what.empty() ? "" : ": " + what) + ": " + problem);
}

std::string shape_str(const std::vector<std::size_t>& shape) {
  std::string s = "[";
  for (std::size_t i = 0; i < shape.size(); ++i) s += (i ? " x " : "") + std::to_string(shape[i]);
  return s + "]";
}

// Product of dims; returns false when it overflows or exceeds max_elements.
bool element_count(const std::vector<std::size_t>& shape, std::size_t max_elements, std::size_t& n) {
  n = 1;
  for (std::size_t d : shape) {
    if (d != 0 && n > max_elements / d) return false;
    n *= d;
  }
  return n <= max_elements;
}

void check_declared_bytes(const std::string& path, const std::string& what, const std::vector<std::size_t>& shape,
                          std::size_t elements, std::size_t bytes_per_element, bool compressed) {
  std::error_code ec;
  const std::uintmax_t file = fs::file_size(path, ec);
  if (ec) fail(path, what, "cannot read the file size: " + ec.message());
  const std::uintmax_t limit = compressed ? file * kMaxExpansion + kSlackBytes : file;
  const std::uintmax_t bpe = std::max<std::size_t>(bytes_per_element, 1);
  if (elements > limit / bpe)
    fail(path, what,
         "declares shape " + shape_str(shape) + " (" + std::to_string(elements) + " elements of " + std::to_string(bpe) +
             " bytes) but the file holds only " + std::to_string(file) + " bytes" +
             (compressed ? " (more than any compression could expand to)" : " (uncompressed)") +
             ": truncated or corrupt file");
}

std::size_t count_nonfinite(const std::vector<double>& v) {
  return static_cast<std::size_t>(std::count_if(v.begin(), v.end(), [](double x) { return !std::isfinite(x); }));
}

void require_file(const std::string& path) {
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) fail(path, "", "no such file");
}

}  // namespace qdo::io_detail
