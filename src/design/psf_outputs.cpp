// The PSF outputs of a simulated design (psf_outputs.hpp).
#include "qdo/design/psf_outputs.hpp"

#include <algorithm>
#include <cmath>
#include <future>
#include <sstream>
#include <tuple>
#include <utility>

#include "qdo/data/figure.hpp"
#include "qdo/data/io.hpp"
#include "qdo/runtime/error.hpp"

namespace qdo {

void write_psf_h5(Simulator& sim, const SensorStack& psf_s, const Map2D& h, const std::string& dir, const std::string& tag,
                  bool native, bool compress) {
  const SystemConfig& cfg = sim.config();
  const bool f32 = sim.precision() == Precision::F32;
  const std::size_t points = cfg.point_count();
  // One object point: bands x rows x cols; several: points x bands x rows x cols.
  auto dims = [&](std::size_t rows, std::size_t cols) {
    return points > 1 ? std::vector<std::size_t>{points, cfg.bands, rows, cols} : std::vector<std::size_t>{cfg.bands, rows, cols};
  };
  PsfFile f = psf_file_for(cfg, psf_s);  // /psf_sensor written from psf_s itself (the figures read it meanwhile)
  f.float32 = f32;
  f.compress = compress;
  f.root_attrs["design"] = tag;
  f.root_attrs["precision"] = to_string(sim.precision());
  RealStack psf_native;  // read from the device; written from here (no copy)
  if (native) {
    psf_native = sim.psf_native();
    H5Dataset n{"/psf_native", dims(psf_native.rows, psf_native.cols), {}, {{"pitch_m", cfg.pitch_m}},
                {{"units", "fraction of band energy per sample"}}};
    n.view = &psf_native.data;
    n.float32 = f32;
    n.compress = compress;
    f.extra.push_back(std::move(n));
  }
  std::vector<double> alias, outside;
  for (const auto& b : sim.sampling().bands) {
    alias.push_back(b.aliased_energy_fraction);
    outside.push_back(b.energy_outside_window);
  }
  const std::vector<std::size_t> per_plane = points > 1 ? std::vector<std::size_t>{points, cfg.bands} : std::vector<std::size_t>{cfg.bands};
  f.extra.push_back({"/aliased_energy_fraction", per_plane, std::move(alias), {}, {{"units", "fraction"}}});
  f.extra.push_back({"/energy_outside_window", per_plane, std::move(outside), {}, {{"units", "fraction"}}});
  if (points > 1) {  // the points' table: 1 / distance (0: at infinity), field angles, chief-ray image point
    std::vector<double> table;
    for (const ObjectPoint& q : cfg.points()) {
      const auto [cx, cy] = chief_ray_image_m(cfg, q);
      for (double v : {q.at_infinity() ? 0.0 : 1.0 / q.distance_m, q.field_x_deg, q.field_y_deg, cx, cy}) table.push_back(v);
    }
    f.extra.push_back({"/object_points", {points, 5}, std::move(table), {},
                       {{"columns", "inverse_distance_per_m (0: a point at infinity), field_x_deg, field_y_deg, chief_ray_x_m, chief_ray_y_m"},
                        {"units", "1/m, deg, deg, m, m"}}});
  }
  H5Dataset height{"/height_m", {h.rows, h.cols}, {}, {{"pitch_m", cfg.pitch_m}}, {{"units", "m"}}};
  height.view = &h.data;
  height.compress = few_distinct_values(h.data);  // as in design files: quantized maps only
  f.extra.push_back(std::move(height));
  write_psf_file(dir + "/psf.h5", std::move(f));
}

RealStack point_crops(const SystemConfig& cfg, const SensorStack& psf_s, std::size_t band, std::size_t crop) {
  const auto pts = cfg.points();
  RealStack out(pts.size(), crop, crop, 0.0);
  for (std::size_t p = 0; p < pts.size(); ++p) {
    const auto [x_m, y_m] = chief_ray_image_m(cfg, pts[p]);
    // Centred on the chief-ray pixel; samples outside the window stay 0.
    const long cy = long(psf_s.rows / 2) + std::lround(y_m / cfg.sensor_pitch_m) - long(crop / 2);
    const long cx = long(psf_s.cols / 2) + std::lround(x_m / cfg.sensor_pitch_m) - long(crop / 2);
    const std::size_t base = (p * cfg.bands + band) * psf_s.rows * psf_s.cols;
    for (std::size_t y = 0; y < crop; ++y)
      for (std::size_t x = 0; x < crop; ++x) {
        const long sy = cy + long(y), sx = cx + long(x);
        if (sy < 0 || sx < 0 || sy >= long(psf_s.rows) || sx >= long(psf_s.cols)) continue;
        const std::size_t at = base + std::size_t(sy) * psf_s.cols + std::size_t(sx);
        out(p, y, x) = psf_s.at(at);
      }
  }
  return out;
}

std::vector<PointSummary> psf_point_summaries(const SystemConfig& cfg, const SensorStack& psf_s) {
  const std::size_t bands = cfg.bands, plane = psf_s.rows * psf_s.cols, mid = bands / 2;
  std::vector<PointSummary> out;
  const auto pts = cfg.points();
  std::vector<double> buf(plane);
  for (std::size_t p = 0; p < pts.size(); ++p) {
    PointSummary r;
    r.point = pts[p];
    std::tie(r.chief_ray_x_m, r.chief_ray_y_m) = chief_ray_image_m(cfg, pts[p]);
    r.min_energy_in_window = 1.0;
    double ee_sum = 0;
    for (std::size_t b = 0; b < bands; ++b) {
      const std::size_t at = (p * bands + b) * plane;
      for (std::size_t k = 0; k < plane; ++k) buf[k] = psf_s.at(at + k);
      const PsfPlaneMetrics m = psf_plane_metrics(buf.data(), psf_s.rows, psf_s.cols, cfg.sensor_pitch_m);
      ee_sum += m.ee80_radius_m;
      r.min_energy_in_window = std::min(r.min_energy_in_window, m.sum);
      if (b == mid) r.mid = m;
    }
    r.ee80_mean_m = ee_sum / double(bands);
    out.push_back(r);
  }
  return out;
}

void write_points_csv(const SystemConfig& cfg, const std::vector<PointSummary>& rows, const std::string& path) {
  std::ostringstream csv;
  const double mid_nm = cfg.wavelengths_nm()[cfg.bands / 2];
  csv << "point,distance_m,field_x_deg,field_y_deg,chief_ray_x_um,chief_ray_y_um,centroid_x_um_" << mid_nm << "nm,centroid_y_um_"
      << mid_nm << "nm,peak_" << mid_nm << "nm,ee80_um_" << mid_nm << "nm,ee80_um_mean_over_bands,min_energy_in_window\n";
  csv.precision(9);
  auto um = [](double m) { return m * 1e6 + 0.0; };  // + 0.0: no "-0" in the table
  for (std::size_t p = 0; p < rows.size(); ++p) {
    const PointSummary& r = rows[p];
    csv << p << ',' << (r.point.at_infinity() ? std::string("inf") : to_str(r.point.distance_m)) << ',' << r.point.field_x_deg << ','
        << r.point.field_y_deg << ',' << um(r.chief_ray_x_m) << ',' << um(r.chief_ray_y_m) << ',' << um(r.mid.centroid_x_m) << ','
        << um(r.mid.centroid_y_m) << ',' << r.mid.peak << ',' << um(r.mid.ee80_radius_m) << ',' << um(r.ee80_mean_m) << ','
        << r.min_energy_in_window << '\n';
  }
  write_text_atomic(path, csv.str());
}

// DIR/psf.png (montage of the sensor PSF stack) and DIR/design.png (height map). Host only.
// design.png is a preview at most 512 px per side (every k-th sample, k = ceil(N / 512): every
// 2nd at N = 1024); the heights themselves are in the HDF5 files. The two figures are drawn on two
// threads (libpng is reentrant).
void write_psf_figures(const SystemConfig& cfg, const SensorStack& psf_s, const Map2D& h, const std::string& dir) {
  auto montage = std::async(std::launch::async, [&] {
    if (cfg.point_count() > 1) {
      // Several object points: the middle band of each, 96 x 96 around its chief-ray image point.
      std::vector<std::string> titles;
      for (const ObjectPoint& q : cfg.points())
        titles.push_back((q.at_infinity() ? std::string("inf") : to_str(q.distance_m) + " m") + ", " + to_str(q.field_x_deg) +
                         (q.field_y_deg != 0 ? ":" + to_str(q.field_y_deg) : std::string()) + " deg");
      write_psf_panels(dir + "/psf.png",
                       "PSF of each object point at " + to_str(cfg.wavelengths_nm()[cfg.bands / 2]) + " nm, centred on its chief ray",
                       point_crops(cfg, psf_s, cfg.bands / 2, 48), titles, cfg.sensor_pitch_m, 0, "the chief ray's image point");
      return;
    }
    // The montage shows the central 96 x 96 of each plane: only that part is converted.
    const RealStack crop = psf_s.central(96);
    write_psf_figure(dir + "/psf.png", "PSF stack on the sensor (central " + to_str(crop.rows) + " pixels)", crop, cfg.wavelengths_nm(),
                     cfg.sensor_pitch_m);
  });
  const std::size_t k = (std::max(h.rows, h.cols) + 511) / 512;
  try {
    if (k <= 1) {
      write_height_figure(dir + "/design.png", "DOE height map", h, cfg.pitch_m);
    } else {
      Map2D small((h.rows + k - 1) / k, (h.cols + k - 1) / k);
      for (std::size_t y = 0; y < small.rows; ++y)
        for (std::size_t x = 0; x < small.cols; ++x) small(y, x) = h(y * k, x * k);
      write_height_figure(dir + "/design.png", "DOE height map (1 sample in " + to_str(k) + " per axis)", small, cfg.pitch_m * double(k));
    }
  } catch (...) {
    montage.wait();
    throw;
  }
  montage.get();
}

// Runs `figures` (PNG writers only: libpng is reentrant) on a second thread while `data` (every
// HDF5 writer, one at a time: the HDF5 library is not built thread-safe, and any device read)
// runs on this one; after both have stopped, rethrows the first failure (data's first).
void write_concurrently(const std::function<void()>& data, const std::function<void()>& figures) {
  auto fig = std::async(std::launch::async, figures);
  try {
    data();
  } catch (...) {
    fig.wait();
    throw;
  }
  fig.get();
}

}  // namespace qdo
