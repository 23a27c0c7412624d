// Row kernels: a 2-D NDRange of `cols` (rounded up to a multiple of kRowLocalSize) x `rows` work
// items in work-groups of kRowLocalSize x 1; get_global_id(0) is the column (each kernel checks
// it against its width), get_global_id(1) the row. A kernel whose index arithmetic (divisions,
// plane and slot of a row) depends on the row alone keeps it out of the column loop that a CPU
// device compiles a work-group into, and its column loop reads memory contiguously.
// Rows go in launches of at most kMaxRowsPerLaunch, each with a global offset in dimension 1
// (get_global_id(1) still counts from the first row): some devices cap the work-groups of a
// dimension other than the first at 65,535.
#pragma once
#include <CL/opencl.hpp>

#include <algorithm>
#include <cstddef>

#include "qdo/runtime/runtime.hpp"

namespace qdo {

constexpr std::size_t kRowLocalSize = 64;
constexpr std::size_t kMaxRowsPerLaunch = 16384;

template <typename... A>
void launch_rows(Runtime& rt, cl::Kernel& k, std::size_t cols, std::size_t rows, Precision p, const A&... args) {
  set_args(k, p, args...);
  const std::size_t gc = (cols + kRowLocalSize - 1) / kRowLocalSize * kRowLocalSize;
  for (std::size_t r0 = 0; r0 < rows; r0 += kMaxRowsPerLaunch)
    rt.queue().enqueueNDRangeKernel(k, cl::NDRange(0, r0), cl::NDRange(gc, std::min(kMaxRowsPerLaunch, rows - r0)),
                                    cl::NDRange(kRowLocalSize, 1));
}

}  // namespace qdo
