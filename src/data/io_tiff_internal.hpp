// Private to src/data: what the libtiff readers and writers share (io_tiff.cpp, io_raw.cpp).
#pragma once
#include <tiffio.h>

#include <cstdarg>
#include <cstdio>
#include <memory>
#include <string>

namespace qdo::io_detail {

// libtiff reports through global handlers; the last message of this thread is kept for the error.
inline thread_local std::string tiff_message;
inline void tiff_handler(const char* module, const char* fmt, va_list ap) {
  char b[512];
  std::vsnprintf(b, sizeof b, fmt, ap);
  tiff_message = std::string(module ? module : "") + (module ? ": " : "") + b;
}

struct TiffCloser {
  void operator()(TIFF* t) const {
    if (t) TIFFClose(t);
  }
};
using TiffPtr = std::unique_ptr<TIFF, TiffCloser>;

}  // namespace qdo::io_detail
