// Host <-> device copies shared by the PSF chain's stages (doe, field, propagate, psf, sensor) and
// the Simulator that composes them (internal header). Reals travel as doubles on the host and as
// reals of the precision p on the device (float for F32); complex values interleaved (re, im).
#pragma once
#include <CL/opencl.hpp>

#include <cstddef>
#include <vector>

#include "qdo/runtime/runtime.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo::detail {

// A new buffer (flags | CL_MEM_COPY_HOST_PTR) holding a copy of `host` as given (one
// value-initialised element when `host` is empty: OpenCL refuses empty buffers).
template <typename T>
cl::Buffer upload(const Runtime& rt, const std::vector<T>& host, cl_mem_flags flags = CL_MEM_READ_ONLY) {
  std::vector<T> copy(host.empty() ? std::vector<T>(1) : host);
  return cl::Buffer(rt.context(), flags | CL_MEM_COPY_HOST_PTR, copy.size() * sizeof(T), copy.data());
}

// The same with the reals converted to the device precision p.
inline cl::Buffer upload_real(const Runtime& rt, const std::vector<double>& host, Precision p,
                              cl_mem_flags flags = CL_MEM_READ_ONLY) {
  if (p == Precision::F64) return upload(rt, host, flags);
  return upload(rt, std::vector<float>(host.begin(), host.end()), flags);
}

// Complex values as interleaved reals of precision p.
inline cl::Buffer upload_complex(const Runtime& rt, const std::vector<cdouble>& host, Precision p,
                                 cl_mem_flags flags = CL_MEM_READ_ONLY) {
  std::vector<double> flat(host.size() * 2);
  for (std::size_t i = 0; i < host.size(); ++i) {
    flat[2 * i] = host[i].real();
    flat[2 * i + 1] = host[i].imag();
  }
  return upload_real(rt, flat, p, flags);
}

// The first `count` reals of b (precision p), blocking.
inline std::vector<double> download_real(Runtime& rt, const cl::Buffer& b, std::size_t count, Precision p) {
  std::vector<double> out(count);
  rt.read_reals(b, out.data(), count, p);
  return out;
}

// The first `count` complex values of b (interleaved, precision p), blocking.
inline std::vector<cdouble> download_complex(Runtime& rt, const cl::Buffer& b, std::size_t count, Precision p) {
  const auto flat = download_real(rt, b, count * 2, p);
  std::vector<cdouble> out(count);
  for (std::size_t i = 0; i < count; ++i) out[i] = cdouble(flat[2 * i], flat[2 * i + 1]);
  return out;
}

}  // namespace qdo::detail
