#include "qdo/testset.hpp"

#include <algorithm>
#include <filesystem>
#include <map>

#include "qdo/cpu_reference.hpp"
#include "qdo/datasets.hpp"
#include "qdo/error.hpp"

namespace fs = std::filesystem;

namespace qdo::testset {

std::vector<Patch> patches(const SystemConfig& cfg, std::size_t s, const std::vector<std::string>& data,
                           const std::string& data_format, std::size_t synthetic_scenes, std::uint64_t run_seed) {
  std::vector<Patch> out;
  if (data.empty()) {
    const SceneIndex idx = SceneIndex::synthetic(cfg, synthetic_scenes, s, run_seed + 1000003);
    for (std::size_t i = 0; i < idx.size(); ++i) out.push_back({"synthetic_" + std::to_string(i), idx.load(i)});
    return out;
  }
  const SceneIndex idx(data, data_format, cfg.bands, cfg.wavelengths_nm());
  for (std::size_t i = 0; i < idx.size(); ++i) {
    const RealStack cube = idx.load(i);
    if (cube.rows < s || cube.cols < s) reject("data", idx[i].path, "scenes of at least S x S = " + to_str(s) + " pixels");
    for (auto& p : extract_patches(cube, s, s)) out.push_back({fs::path(idx[i].path).stem().string(), std::move(p)});
  }
  return out;
}

RealStack reconstruct(const RealStack& x, const ComplexStack& otf, const Eigen::MatrixXd& srf, const WienerDecoder& dec,
                      double sigma, std::uint64_t run_seed, std::size_t k) {
  RealStack y = wiener::simulate_measurement(x, otf, srf);
  ref::add_noise(y, sigma, 0, run_seed + 77, k);
  RealStack xh = dec.decode(y);
  for (double& v : xh.data) v = std::clamp(v, 0.0, 1.0);
  return xh;
}

Scores score(const RealStack& xh, const RealStack& x) {
  Scores r;
  r.psnr = metrics::psnr(xh, x);
  r.psnr_hyper = metrics::psnr_hyper(xh, x);
  r.ssim = metrics::ssim(xh, x);
  r.rmse = metrics::rmse(xh, x);
  r.ergas = metrics::ergas(xh, x);
  r.sam_rad = metrics::sam(xh, x);
  return r;
}

namespace {
void add_scaled(Scores& m, const Scores& r, double n) {
  m.psnr += r.psnr / n;
  m.psnr_hyper += r.psnr_hyper / n;
  m.ssim += r.ssim / n;
  m.rmse += r.rmse / n;
  m.ergas += r.ergas / n;
  m.sam_rad += r.sam_rad / n;
}
}  // namespace

std::vector<std::pair<std::string, Scores>> per_scene_means(const std::vector<std::pair<std::string, Scores>>& per_patch) {
  std::map<std::string, std::vector<Scores>> by_scene;
  std::vector<std::string> order;
  for (const auto& [scene, s] : per_patch) {
    if (!by_scene.count(scene)) order.push_back(scene);
    by_scene[scene].push_back(s);
  }
  std::vector<std::pair<std::string, Scores>> out;
  for (const auto& name : order) {
    const auto& v = by_scene[name];
    Scores m;
    for (const auto& r : v) add_scaled(m, r, double(v.size()));
    out.push_back({name, m});
  }
  return out;
}

Scores mean_of(const std::vector<Scores>& rows) {
  Scores m;
  for (const auto& r : rows) add_scaled(m, r, double(rows.size()));
  return m;
}

}  // namespace qdo::testset
