// `qdo gradcheck` as a library call: every adjoint of a design run's configuration against
// central finite differences.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "qdo/design/design_run_options.hpp"
#include "qdo/runtime/runtime.hpp"

namespace qdo {

struct GradcheckRow {
  std::string group;
  double max_rel_error = 0, tolerance = 0;
  bool ok() const { return max_rel_error <= tolerance; }
};
// Compares every adjoint with central finite differences (double precision, OpenCL float64
// where the device has it) on random inputs of the configuration: the PSF chain (OpenCL vs CPU
// reference adjoint, and CPU adjoint vs differences), the parameterization and quantizer in
// `mode`, the objective with respect to the PSF. N is capped at 64 to keep it quick.
std::vector<GradcheckRow> gradcheck(Runtime& rt, const DesignRunOptions& o, std::uint64_t seed);

}  // namespace qdo
