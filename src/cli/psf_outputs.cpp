// The --save option of `qdo psf` and `qdo simulate` (psf_outputs.hpp).
#include "psf_outputs.hpp"

#include "qdo/runtime/error.hpp"
#include "qdo/runtime/util.hpp"

namespace qdo::cli {

bool save_native(const Args& a) {
  bool native = false;
  for (const auto& s : split_items(a.get("save"))) {
    if (s == "native") native = true;
    else reject("--save", s, "a comma-separated list of: native");
  }
  return native;
}

}  // namespace qdo::cli
