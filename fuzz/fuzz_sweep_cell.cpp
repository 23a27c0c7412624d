// Fuzz target: a finished sweep cell's metrics.json as `qdo sweep` reads it back to reuse the cell
// (read_cell_metrics, sweep.hpp). The reader must return false or give finite metrics; it never
// throws (a torn or foreign file makes the sweep evaluate the cell again).
#include <cmath>

#include "fuzz_util.hpp"
#include "qdo/sweep.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace qdo;
  const std::string path = fuzz::scratch().write("metrics.json", data, size);
  EvalRow mean;
  mean.psnr = -7;  // left as it was unless the whole file reads
  double dev = -3;
  if (read_cell_metrics(path, mean, dev)) {
    for (double v : {mean.psnr, mean.psnr_hyper, mean.ssim, mean.rmse, mean.ergas, mean.sam_rad, dev})
      if (!std::isfinite(v)) fuzz::fail("read_cell_metrics accepted a non-finite value");
  } else if (mean.psnr != -7 || dev != -3) {
    fuzz::fail("read_cell_metrics changed its outputs and returned false (half-read)");
  }
  return 0;
}
