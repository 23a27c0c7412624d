// Scoring a reconstruction against the scene its capture shows (reconstruct.hpp).
#include "qdo/asbuilt/reconstruct.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <string>

#include "qdo/data/datasets.hpp"
#include "qdo/data/io.hpp"
#include "qdo/data/scenes.hpp"
#include "qdo/decode/decoder_registry.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/runtime/error.hpp"

namespace qdo {

RealStack read_reconstruct_truth(const ReconstructOptions& o, const std::string& path, const std::string& key,
                                 const TruthArguments& names) {
  const DesignRunOptions ro = read_run_config(o.run, names.run, "a run folder written by qdo design");
  const SystemConfig cfg = o.sensor_file.empty() ? ro.cfg : with_sensor(ro.cfg, o.sensor_file, decoder_entry(ro.decoder.kind_name()).trained);
  RealStack truth = read_scene(cfg, path, key, false, names.key);
  const CaptureFiles f = read_captures(cfg, o.capture);
  if (truth.rows != f.mean_dn.rows || truth.cols != f.mean_dn.cols)
    reject(names.truth, path,
           "a scene of the captures' size, " + std::to_string(f.mean_dn.rows) + " x " + std::to_string(f.mean_dn.cols) + " (it is " +
               std::to_string(truth.rows) + " x " + std::to_string(truth.cols) + ")");
  if (o.capture.crop) truth = crop_window(truth, o.capture.crop_row, o.capture.crop_col, o.capture.crop_rows, o.capture.crop_cols);
  return truth;
}

void check_truth_border(const RealStack& truth, std::size_t border_px, const TruthArguments& names) {
  const std::size_t side = std::min(truth.rows, truth.cols);
  if (side < 11 || border_px > (side - 11) / 2)
    reject(names.border, std::to_string(border_px),
           "at most " + std::to_string(side < 11 ? 0 : (side - 11) / 2) + " px for a " + std::to_string(truth.rows) + " x " +
               std::to_string(truth.cols) + " image (the scored interior must be at least 11 x 11, the SSIM window)");
}

testset::Scores score_reconstruction(const ReconstructResult& r, const RealStack& truth, std::size_t border_px,
                                     const std::string& path, const std::string& out, const TruthArguments& names) {
  if (truth.planes != r.cube.planes) reject(names.truth, path, "a cube of the run's " + std::to_string(r.cube.planes) + " bands");
  const auto interior = [&](const RealStack& s) {
    return crop_window(s, border_px, border_px, s.rows - 2 * border_px, s.cols - 2 * border_px);
  };
  const testset::Scores sc = testset::score(interior(r.cube), interior(truth));
  nlohmann::json m;
  m["truth"] = path;
  m["border_px"] = border_px;
  m["psf"] = r.psf;
  m["decoder"] = r.decoder;
  m["mean"] = {{"psnr", sc.psnr}, {"psnr_hyper", sc.psnr_hyper}, {"ssim", sc.ssim}, {"rmse", sc.rmse}, {"ergas", sc.ergas}, {"sam_rad", sc.sam_rad}};
  write_text_atomic(out + "/metrics.json", m.dump(2) + "\n");
  return sc;
}

}  // namespace qdo
