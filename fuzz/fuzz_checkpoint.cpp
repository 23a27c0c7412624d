// Fuzz target: a design-run checkpoint (run.hpp) for a run with 16 weights and 4 levels.
#include <cmath>

#include "fuzz_util.hpp"
#include "qdo/design/run.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace qdo;
  const std::string path = fuzz::scratch().write("checkpoint.h5", data, size);
  try {
    const DesignState s = load_checkpoint(path, 16, 4);
    if (s.w.size() != 16 || s.offsets.size() != 4) fuzz::fail("load_checkpoint accepted wrong sizes");
    if ((!s.adam_w.m.empty() && s.adam_w.m.size() != 16) || (!s.adam_a.v.empty() && s.adam_a.v.size() != 4))
      fuzz::fail("load_checkpoint accepted wrong optimiser sizes");
    for (double w : s.w)
      if (!(w >= -1 && w <= 1)) fuzz::fail("load_checkpoint accepted a weight outside [-1, 1]");
    for (double v : s.adam_w.v)
      if (!(v >= 0) || !std::isfinite(v)) fuzz::fail("load_checkpoint accepted a negative or non-finite second moment");
    if (s.step < 0 || s.adam_w.t < 0 || s.adam_a.t < 0) fuzz::fail("load_checkpoint accepted a negative counter");
  } catch (const InputError& e) {
    fuzz::expect_names(e, path);
  }
  return 0;
}
