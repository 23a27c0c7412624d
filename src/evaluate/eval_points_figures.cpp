// The figures of qdo eval-points (eval_points_figures.hpp).
#include "evaluate/eval_points_figures.hpp"

#include <cmath>
#include <string>
#include <vector>

#include "qdo/runtime/error.hpp"
#include "qdo/data/figure.hpp"

namespace fs = std::filesystem;

namespace qdo {

namespace {

// One band's PSF of every point side by side, the central crop of each, titled by its point.
void write_psf_row(const std::string& path, const std::string& title, const std::vector<RealStack>& psfs, std::size_t band,
                   const std::vector<std::string>& titles, double nm, double pitch_m) {
  const RealStack& first = psfs.front();
  RealStack row(psfs.size(), first.rows, first.cols);
  for (std::size_t q = 0; q < psfs.size(); ++q) std::copy(psfs[q].plane(band), psfs[q].plane(band) + first.plane_size(), row.plane(q));
  write_psf_panels(path, title + " at " + to_str(nm) + " nm", row, titles, pitch_m, 96);
}

}  // namespace

// x = 1/d (diopters; infinity at 0) for distances, degrees for angles.
void write_points_figures(const fs::path& out, const EvalPointsResult& res, const EvalPointsOptions& o, const SystemConfig& cfg,
                          const std::vector<RealStack>& dpsf, const std::vector<RealStack>& apsf) {
  const std::string run = fs::path(o.run).filename().string();
  LinePlot psnr_d, ssim_d;
  psnr_d.title = "PSNR against object distance: " + run;
  ssim_d.title = "SSIM against object distance";
  psnr_d.x_label = ssim_d.x_label = "1 / object distance (1/m; 0 = infinity)";
  psnr_d.y_label = "PSNR (dB)";
  ssim_d.y_label = "SSIM";
  PlotSeries mis{"decoder for the design distance (mismatched)", {}, {}, {}, {}, false}, mat{"decoder for each distance (matched)", {}, {}, {}, {}, false};
  PlotSeries smis = mis, smat = mat;
  for (const DistanceRow& r : res.distances) {
    const double x = std::isinf(r.distance_m) ? 0.0 : 1.0 / r.distance_m;
    for (PlotSeries* ps : {&mis, &mat, &smis, &smat}) ps->x.push_back(x);
    mis.y.push_back(r.mismatch.psnr_db.mean);
    mat.y.push_back(r.matched.psnr_db.mean);
    smis.y.push_back(r.mismatch.ssim.mean);
    smat.y.push_back(r.matched.ssim.mean);
  }
  psnr_d.series = {mis, mat};
  psnr_d.hlines = {res.nominal_psnr_db - o.dof_margin_db};  // the depth-of-field margin below the nominal PSNR
  psnr_d.title += " (dashed: nominal − " + to_str(o.dof_margin_db) + " dB)";
  ssim_d.series = {smis, smat};
  write_line_panels((out / "quality_vs_distance.png").string(), "Quality against object distance: " + run, {psnr_d, ssim_d});
  LinePlot psnr_a, err_a;
  psnr_a.title = "PSNR against field angle, on-axis decoder";
  err_a.title = "Shift-invariant model error against field angle (dashed: the tolerance)";
  psnr_a.x_label = err_a.x_label = "field angle (deg)";
  psnr_a.y_label = "PSNR (dB)";
  err_a.y_label = "||I_theta - I_0|| / ||I_0||";
  PlotSeries ap{"on-axis decoder", {}, {}, {}, {}, false}, ae{"model error", {}, {}, {}, {}, false};
  for (const AngleRow& r : res.angles) {
    ap.x.push_back(r.angle_deg);
    ap.y.push_back(r.on_axis_decoder.psnr_db.mean);
    ae.x.push_back(r.angle_deg);
    ae.y.push_back(r.model_error);
  }
  psnr_a.series = {ap};
  err_a.series = {ae};
  err_a.hlines = {o.fov_tolerance};
  write_line_panels((out / "quality_vs_angle.png").string(), "Quality against field angle: " + run, {psnr_a, err_a});
  const std::size_t band = cfg.bands / 2;
  const double nm = cfg.wavelengths_nm()[band];
  std::vector<std::string> dt, at;
  for (const DistanceRow& r : res.distances) dt.push_back(std::isinf(r.distance_m) ? std::string("inf") : to_str(r.distance_m) + " m");
  for (const AngleRow& r : res.angles) at.push_back(to_str(r.angle_deg) + " deg");
  write_psf_row((out / "psf_vs_distance.png").string(), "PSF against object distance: " + run, dpsf, band, dt, nm, cfg.sensor_pitch_m);
  write_psf_row((out / "psf_vs_angle.png").string(), "PSF against field angle: " + run, apsf, band, at, nm, cfg.sensor_pitch_m);
}

}  // namespace qdo
