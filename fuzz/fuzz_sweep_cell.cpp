// Fuzz target: a finished sweep cell's metrics.json as `qdo sweep` reads it back to reuse the cell
// (read_cell_metrics, sweep.hpp). The reader must return false or give finite metrics; it never
// throws (a torn or foreign file makes the sweep evaluate the cell again), with and without the
// per-scene rows.
#include <cmath>
#include <vector>

#include "fuzz_util.hpp"
#include "qdo/evaluate/sweep.hpp"

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
  // With the per-scene rows (the sweep's paired comparisons): finite rows, or nothing changed.
  EvalRow mean2;
  mean2.psnr = -7;
  double dev2 = -3;
  std::vector<EvalRow> scenes(1);
  scenes[0].psnr = -11;
  if (read_cell_metrics(path, mean2, dev2, &scenes)) {
    if (scenes.empty()) fuzz::fail("read_cell_metrics accepted a file without per-scene rows");
    for (const EvalRow& r : scenes)
      for (double v : {r.psnr, r.psnr_hyper, r.ssim, r.rmse, r.ergas, r.sam_rad})
        if (!std::isfinite(v)) fuzz::fail("read_cell_metrics accepted a non-finite per-scene value");
  } else if (mean2.psnr != -7 || dev2 != -3 || scenes.size() != 1 || scenes[0].psnr != -11) {
    fuzz::fail("read_cell_metrics changed its outputs and returned false (half-read, per-scene rows)");
  }
  return 0;
}
