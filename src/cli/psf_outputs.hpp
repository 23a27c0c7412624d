// What `qdo psf` and `qdo simulate` share (private to src/cli/): the PSF outputs (psf.h5 and its
// figures) and the concurrent writing of data and figures.
#pragma once
#include <functional>
#include <string>
#include <vector>

#include "cli.hpp"
#include "qdo/physics/psf_metrics.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo::cli {

// --save: extra outputs of psf and simulate, comma-separated; today only "native" (the native-grid
// PSF stack /psf_native in psf.h5, bands x N x N: the largest output, off by default).
bool save_native(const Args& a);

// The sensor PSF stack as the writers below take it (bands x S x S, row-major): a host stack of
// doubles, or the float32 device buffer mapped on the host (no read-back, no conversion).
struct SensorStack {
  std::size_t planes = 0, rows = 0, cols = 0;
  const std::vector<double>* f64 = nullptr;
  const float* f32 = nullptr;
  explicit SensorStack(const RealStack& s) : planes(s.planes), rows(s.rows), cols(s.cols), f64(&s.data) {}
  SensorStack(std::size_t p, std::size_t r, std::size_t c, const float* v) : planes(p), rows(r), cols(c), f32(v) {}
  // The central crop x crop of every plane, in double (figures).
  RealStack central(std::size_t crop) const;
};

// DIR/psf.h5: the sensor PSF stack psf_s (bands x S x S) as /psf_sensor, the native-grid stack
// /psf_native when `native`, wavelengths, sampling, heights. The PSF stacks are stored in the run's
// precision: float32 for an f32 run (exactly the device's values, half the bytes), float64 for
// f64. Reads the device (call it on the thread that owns the simulator).
void write_psf_h5(Simulator& sim, const SensorStack& psf_s, const Map2D& h, const std::string& dir, const std::string& tag,
                  bool native, bool compress);
// One object point of a points x bands stack, summarised: where its chief ray lands, the middle
// band's metrics, the 80 % encircled-energy radius averaged over the bands, and the smallest
// fraction of a band's energy inside the window.
struct PointSummary {
  ObjectPoint point;
  double chief_ray_x_m = 0, chief_ray_y_m = 0;
  PsfPlaneMetrics mid;
  double ee80_mean_m = 0, min_energy_in_window = 0;
};
// Band `band` of every point of psf_s (points x bands planes of S x S, point-major), crop x crop
// centred on each point's chief-ray image point (0 outside the window): points x crop x crop.
RealStack point_crops(const SystemConfig& cfg, const SensorStack& psf_s, std::size_t band, std::size_t crop);
// psf_s: points x bands planes of S x S (point-major), cfg's points in order.
std::vector<PointSummary> psf_point_summaries(const SystemConfig& cfg, const SensorStack& psf_s);
// The table of psf_point_summaries as CSV (lengths in micrometres), written atomically.
void write_points_csv(const SystemConfig& cfg, const std::vector<PointSummary>& rows, const std::string& path);
// DIR/psf.png (montage of the sensor PSF stack) and DIR/design.png (height map). Host only.
void write_psf_figures(const SystemConfig& cfg, const SensorStack& psf_s, const Map2D& h, const std::string& dir);
// Runs `figures` (PNG writers only: libpng is reentrant) on a second thread while `data` (every
// HDF5 writer, one at a time: the HDF5 library is not built thread-safe, and any device read)
// runs on this one; after both have stopped, rethrows the first failure (data's first).
void write_concurrently(const std::function<void()>& data, const std::function<void()>& figures);

}  // namespace qdo::cli
