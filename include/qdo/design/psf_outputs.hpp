// The PSF outputs of a simulated design (`qdo psf`, `qdo simulate`): psf.h5 with the simulator's
// sampling and the heights, the object points' summaries (points.csv), the figures (psf.png,
// design.png), and the concurrent writing of data and figures.
#pragma once
#include <functional>
#include <string>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/runtime/parse.hpp"
#include "qdo/data/psf_file.hpp"
#include "qdo/physics/psf_metrics.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

// DIR/psf.h5 through write_psf_file: the sensor PSF stack psf_s (points x bands planes of S x S,
// point-major; stored bands x S x S for one object point, points x bands x S x S for several) as
// /psf_sensor, the native-grid stack /psf_native (same layout, N x N planes) when `native`,
// /wavelengths_nm, /aliased_energy_fraction and /energy_outside_window (bands, or points x bands),
// /object_points (points x 5, with several), /height_m (h: N x N, row-major); root attributes
// config, design (= tag) and precision. The PSF stacks are stored in the run's precision: float32
// for an f32 run (a float32 psf_s exactly as the device computed it, without a copy), float64 for
// f64; `compress` compresses both. Reads the device for /psf_native (call it on the thread that
// owns the simulator).
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
// Band `band` of every point of psf_s (cfg.point_count() x cfg.bands planes of S x S,
// point-major), crop x crop centred on each point's chief-ray image point (0 outside the window):
// points x crop x crop.
RealStack point_crops(const SystemConfig& cfg, const SensorStack& psf_s, std::size_t band, std::size_t crop);
// psf_s: cfg.point_count() x cfg.bands planes of S x S (point-major), cfg's points in order. One
// summary per point.
std::vector<PointSummary> psf_point_summaries(const SystemConfig& cfg, const SensorStack& psf_s);
// The table of psf_point_summaries as CSV (lengths in micrometres), written atomically.
void write_points_csv(const SystemConfig& cfg, const std::vector<PointSummary>& rows, const std::string& path);
// DIR/psf.png (montage of the sensor PSF stack psf_s, cfg.point_count() x cfg.bands planes of
// S x S, point-major) and DIR/design.png (height map h, N x N row-major). Host only.
void write_psf_figures(const SystemConfig& cfg, const SensorStack& psf_s, const Map2D& h, const std::string& dir);
// Runs `figures` (PNG writers only: libpng is reentrant) on a second thread while `data` (every
// HDF5 writer, one at a time: the HDF5 library is not built thread-safe, and any device read)
// runs on this one; after both have stopped, rethrows the first failure (data's first).
void write_concurrently(const std::function<void()>& data, const std::function<void()>& figures);

// --save: extra outputs of qdo psf and qdo simulate, comma-separated; today only "native" (the
// native-grid PSF stack /psf_native in psf.h5, bands x N x N: the largest output, off by default).
// An InputError naming --save for any other item.
bool save_native_from_option(const std::string& save);

// qdo psf's work from its options as typed (TextOptions): the configuration (several object points
// from the configuration or --object-distances x --field-angles: one batched pass, points x bands
// planes), the design's heights (--design, --levels, --placement), then psf.h5 (write_psf_h5, with
// --save and --compress), points.csv with several points, psf.png and design.png in the folder
// claim_dir() returns. The device (--device) starts on a second thread while the inputs are read
// and the folder claimed (an input's error is reported first). float32: the files are written from
// the device buffer mapped on the host. Returns the report: device, stack, seconds, sampling, files.
std::string psf_outputs_from_options(const TextOptions& a, const std::function<std::string()>& claim_dir);

}  // namespace qdo
