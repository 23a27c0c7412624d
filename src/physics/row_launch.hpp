// Row kernels: a 2-D NDRange of `cols` (rounded up to a multiple of kRowLocalSize) x `rows` work
// items in work-groups of kRowLocalSize x 1; get_global_id(0) is the column (each kernel checks
// it against its width), get_global_id(1) the row. A kernel whose index arithmetic (divisions,
// plane and slot of a row) depends on the row alone keeps it out of the column loop that a CPU
// device compiles a work-group into, and its column loop reads memory contiguously.
#pragma once
#include <CL/opencl.hpp>

#include <cstddef>

#include "qdo/runtime/runtime.hpp"

namespace qdo {

constexpr std::size_t kRowLocalSize = 64;

template <typename... A>
void launch_rows(Runtime& rt, cl::Kernel& k, std::size_t cols, std::size_t rows, Precision p, const A&... args) {
  set_args(k, p, args...);
  const std::size_t gc = (cols + kRowLocalSize - 1) / kRowLocalSize * kRowLocalSize;
  rt.queue().enqueueNDRangeKernel(k, cl::NullRange, cl::NDRange(gc, rows), cl::NDRange(kRowLocalSize, 1));
}

}  // namespace qdo
