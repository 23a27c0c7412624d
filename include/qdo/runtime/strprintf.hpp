// printf into a std::string of any length (report lines of the library's commands).
#pragma once
#include <cstdarg>
#include <cstddef>
#include <cstdio>
#include <string>

namespace qdo {

// The text printf(f, ...) would print, whatever its length.
__attribute__((format(printf, 1, 2))) inline std::string strprintf(const char* f, ...) {
  va_list ap, ap2;
  va_start(ap, f);
  va_copy(ap2, ap);
  const int n = std::vsnprintf(nullptr, 0, f, ap);
  va_end(ap);
  std::string s(n > 0 ? std::size_t(n) : 0, '\0');
  if (n > 0) std::vsnprintf(&s[0], s.size() + 1, f, ap2);
  va_end(ap2);
  return s;
}

}  // namespace qdo
