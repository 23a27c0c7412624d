// Small helpers every layer uses: elapsed time, and a string cut at a separator.
#pragma once
#include <chrono>
#include <string>
#include <vector>

namespace qdo {

// Seconds elapsed on the steady clock since t0.
inline double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// The fields of s between the separators, empty ones kept, as a CSV row has them ("a,,b," -> {"a",
// "", "b", ""}; "" -> {}).
inline std::vector<std::string> split_fields(const std::string& s, char sep) {
  std::vector<std::string> out;
  std::string cur;
  for (char c : s) {
    if (c == sep) {
      out.push_back(cur);
      cur.clear();
    } else {
      cur += c;
    }
  }
  if (!s.empty()) out.push_back(cur);
  return out;
}

// The items of a list option ("a,,b," -> {"a", "b"}): the fields without the empty ones.
inline std::vector<std::string> split_items(const std::string& s, char sep = ',') {
  std::vector<std::string> out;
  for (std::string& f : split_fields(s, sep))
    if (!f.empty()) out.push_back(std::move(f));
  return out;
}

}  // namespace qdo
