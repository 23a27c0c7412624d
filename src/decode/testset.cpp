#include "qdo/decode/testset.hpp"

#include <algorithm>
#include <filesystem>
#include <map>

#include "qdo/physics/cpu_reference.hpp"
#include "qdo/data/datasets.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/fft.hpp"

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

PatchCamera::PatchCamera(Runtime& rt, const SystemConfig& cfg)
    : PatchCamera(rt, cfg, rt.has_fp64() ? Precision::F64 : Precision::F32) {}

PatchCamera::PatchCamera(Runtime& rt, const SystemConfig& cfg, Precision p) : s_(cfg.sensor_size_px()), prec_(p) {
  extend_ = fast_fft_size(s_) != s_;
  SystemConfig c = cfg;
  c.convolution = extend_ ? ConvolutionMode::Linear : ConvolutionMode::Circular;
  c.read_noise_sigma = 0;  // the noise is drawn on the host (reconstruct), per patch
  c.full_well_photons = 0;
  camera_ = std::make_unique<Camera>(rt, c, prec_);
}

std::vector<RealStack> PatchCamera::measure(const RealStack& psf_sensor, const std::vector<Patch>& patches) {
  const std::size_t s = s_, c = s / 2, lead = s - 1 - c, e = extend_ ? 2 * s - 1 : s;
  for (std::size_t k = 0; k < patches.size(); ++k)
    if (patches[k].cube.rows != s || patches[k].cube.cols != s)
      reject("patches[" + to_str(k) + "]", shape(patches[k].cube), "S x S patches with S = " + to_str(s));
  camera_->set_psf(psf_sensor);
  SkipOptions exact;
  exact.exact = true;
  constexpr std::size_t kBatch = kMaxBatch;
  last_count_ = patches.size();
  std::vector<RealStack> out;
  out.reserve(patches.size());
  for (std::size_t base = 0; base < patches.size(); base += kBatch) {
    std::vector<RealStack> batch;
    for (std::size_t k = base; k < std::min(patches.size(), base + kBatch); ++k) {
      const RealStack& x = patches[k].cube;
      if (!extend_) {
        batch.push_back(x);
        continue;
      }
      // Periodic extension: ext(y, x) = x((y - lead) mod S, (x - lead) mod S).
      RealStack ext(x.planes, e, e);
      for (std::size_t b = 0; b < x.planes; ++b)
        for (std::size_t y = 0; y < e; ++y)
          for (std::size_t xx = 0; xx < e; ++xx) ext(b, y, xx) = x(b, (y + s - lead) % s, (xx + s - lead) % s);
      batch.push_back(std::move(ext));
    }
    for (RealStack& y : camera_->images(batch, exact)) {
      if (!extend_) {
        out.push_back(std::move(y));
        continue;
      }
      RealStack centre(3, s, s);
      for (std::size_t ch = 0; ch < 3; ++ch)
        for (std::size_t r = 0; r < s; ++r)
          for (std::size_t col = 0; col < s; ++col) centre(ch, r, col) = y(ch, r + lead, col + lead);
      out.push_back(std::move(centre));
    }
  }
  return out;
}

std::vector<RealStack> PatchCamera::measure(const RealStack& psf_sensor, const std::vector<RealStack>& cubes) {
  if (extend_ || cubes.size() > kMaxBatch) {
    std::vector<Patch> patches;
    patches.reserve(cubes.size());
    for (const RealStack& c : cubes) patches.push_back({"", c});
    return measure(psf_sensor, patches);
  }
  for (std::size_t k = 0; k < cubes.size(); ++k)
    if (cubes[k].rows != s_ || cubes[k].cols != s_)
      reject("cubes[" + to_str(k) + "]", shape(cubes[k]), "S x S patches with S = " + to_str(s_));
  camera_->set_psf(psf_sensor);
  SkipOptions exact;
  exact.exact = true;
  last_count_ = cubes.size();
  return camera_->images(cubes, exact);
}

RealStack PatchCamera::vjp(const std::vector<RealStack>& g_images) {
  if (last_count_ == 0 || last_count_ > kMaxBatch)
    reject("g_images", to_str(g_images.size()) + " gradients",
           "the gradients of a measure() call of 1 to " + to_str(kMaxBatch) + " patches (the last one had " + to_str(last_count_) + ")");
  if (g_images.size() != last_count_)
    reject("g_images", to_str(g_images.size()) + " gradients", "one per patch of the last measure() call (" + to_str(last_count_) + ")");
  const std::size_t s = s_, lead = s - 1 - s / 2, e = extend_ ? 2 * s - 1 : s;
  std::vector<RealStack> g;
  g.reserve(g_images.size());
  for (std::size_t k = 0; k < g_images.size(); ++k) {
    const RealStack& gi = g_images[k];
    if (gi.planes != 3 || gi.rows != s || gi.cols != s)
      reject("g_images[" + to_str(k) + "]", shape(gi), "3 x S x S with S = " + to_str(s));
    if (!extend_) {
      g.push_back(gi);
      continue;
    }
    RealStack ext(3, e, e, 0.0);  // the image kept the centre [lead, lead + S) of the extended one
    for (std::size_t ch = 0; ch < 3; ++ch)
      for (std::size_t r = 0; r < s; ++r)
        for (std::size_t col = 0; col < s; ++col) ext(ch, r + lead, col + lead) = gi(ch, r, col);
    g.push_back(std::move(ext));
  }
  return camera_->vjp(g, false).psf;
}

RealStack reconstruct(const RealStack& y_noiseless, const Decoder& dec, double sigma, std::uint64_t run_seed, std::size_t k) {
  RealStack y = y_noiseless;
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

Evaluation evaluate(PatchCamera& camera, const RealStack& psf_actual, const std::vector<Patch>& patches, const Decoder& dec,
                    double sigma, std::uint64_t run_seed, const std::function<void(std::size_t k, const RealStack& xh)>& each) {
  const std::size_t batch = dec.batch();
  if (batch < 1) reject("batch", batch, ">= 1");
  const std::vector<RealStack> measured = camera.measure(psf_actual, patches);
  Evaluation ev;
  for (std::size_t base = 0; base < patches.size(); base += batch) {
    const std::size_t end = std::min(patches.size(), base + batch);
    std::vector<RealStack> noisy;
    for (std::size_t k = base; k < end; ++k) {
      RealStack y = measured[k];
      ref::add_noise(y, sigma, 0, run_seed + 77, k);  // as reconstruct()
      noisy.push_back(std::move(y));
    }
    std::vector<RealStack> xs = dec.decode_batch(noisy);
    if (xs.size() != noisy.size())
      throw Error("internal: the decoder returned " + to_str(xs.size()) + " cubes for " + to_str(noisy.size()) + " images");
    for (std::size_t k = base; k < end; ++k) {
      RealStack& xh = xs[k - base];
      const RealStack& x = patches[k].cube;
      if (xh.planes != x.planes || xh.rows != x.rows || xh.cols != x.cols)
        throw Error("internal: the decoder returned a " + shape(xh) + " cube for a " + shape(x) + " patch");
      for (double& v : xh.data) v = std::clamp(v, 0.0, 1.0);
      Scores sc;
      try {
        sc = score(xh, x);
      } catch (const InputError& e) {  // e.g. a band of the scene that is all zero (ERGAS divides by its mean)
        throw InputError("test scene '" + patches[k].scene + "': " + e.what());
      }
      ev.per_patch.push_back({patches[k].scene, sc});
      if (each) each(k, xh);
    }
  }
  ev.per_scene = per_scene_means(ev.per_patch);
  std::vector<Scores> rows;
  for (const auto& s : ev.per_scene) rows.push_back(s.second);
  ev.mean = mean_of(rows);
  return ev;
}

}  // namespace qdo::testset
