// The OpenCL devices and FFT backends as text (runtime.hpp: devices_report, backends_report).
#include "qdo/runtime/runtime.hpp"

#include <clFFT.h>
#include <fftw3.h>

#include <exception>

#include "qdo/runtime/fft.hpp"
#include "qdo/runtime/strprintf.hpp"

namespace qdo {

std::string devices_report() {
  std::string s;
  for (const auto& d : list_devices())
    s +=
        strprintf("%zu:%zu  %s / %s  [%s]  driver %s  %s  fp64 %s  %u CUs  %.1f GiB\n", d.platform_index,
                  d.device_index, d.platform.c_str(), d.name.c_str(), d.type.c_str(), d.driver_version.c_str(),
                  d.version.c_str(), d.fp64 ? "yes" : "no", d.compute_units, double(d.global_mem_bytes) / 1073741824.0);
  return s;
}

std::string backends_report() {
  std::string s;
  try {
    const auto devs = list_devices();
    s += strprintf("OpenCL devices: %zu\n", devs.size());
    for (const auto& d : devs)
      s += strprintf("  %zu:%zu  %s / %s  [%s]  %s  driver %s\n", d.platform_index, d.device_index, d.platform.c_str(),
                     d.name.c_str(), d.type.c_str(), d.version.c_str(), d.driver_version.c_str());
  } catch (const std::exception& e) {
    s += strprintf("OpenCL devices: none (%s)\n", e.what());
  }
  cl_uint ma = 0, mi = 0, pa = 0;
  clfftGetVersion(&ma, &mi, &pa);
  return s + strprintf(
                 "FFT backends: clFFT %u.%u.%u and VkFFT %s (OpenCL device; QDO_FFT=clfft|vkfft); FFTW (%s, host "
                 "reference)\n",
                 ma, mi, pa, vkfft_version().c_str(), fftw_version);
}

}  // namespace qdo
