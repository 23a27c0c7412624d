#include "qdo/design/joint.hpp"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <random>

#include <Eigen/Eigenvalues>

#include "qdo/physics/cpu_reference.hpp"
#include "qdo/data/datasets.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/mpi.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/runtime/rng.hpp"
#include "qdo/decode/wiener.hpp"

namespace qdo {

std::size_t synthetic_count(const std::string& entry) {
  const std::string num = entry.rfind("synthetic:", 0) == 0 ? entry.substr(10) : std::string();
  char* end = nullptr;
  const long n = num.empty() ? 0 : std::strtol(num.c_str(), &end, 10);
  if (num.empty() || *end || n < 1 || n > 100000) reject("data", entry, "synthetic:N with N an integer in [1, 100000]");
  return std::size_t(n);
}

JointData load_joint_data(const SystemConfig& cfg, const std::vector<std::string>& data_given, const std::string& data_format,
                          std::size_t synthetic, std::uint64_t seed, std::size_t max_val_patches) {
  const std::size_t s = cfg.sensor_size_px();
  JointData d;
  std::vector<testset::Patch> val_all;
  std::vector<std::string> data;
  std::size_t extra_synthetic = 0;
  for (const std::string& e : data_given) {
    if (e.rfind("synthetic:", 0) == 0) extra_synthetic += synthetic_count(e);
    else data.push_back(e);
  }
  if (extra_synthetic > 0 && !data.empty()) {
    const SceneIndex sy = SceneIndex::synthetic(cfg, extra_synthetic, s, seed + 700001);
    for (std::size_t i = 0; i < sy.size(); ++i) {
      d.train.push_back(sy.load(i));
      d.train_names.push_back("synthetic:" + std::to_string(i));
    }
  }
  if (data.empty() && extra_synthetic > 0) synthetic = extra_synthetic;
  if (data.empty()) {
    const SceneIndex tr = SceneIndex::synthetic(cfg, std::max<std::size_t>(synthetic, 1), s, seed);
    for (std::size_t i = 0; i < tr.size(); ++i) {
      d.train.push_back(tr.load(i));
      d.train_names.push_back("synthetic_" + std::to_string(i));
    }
    const SceneIndex va = SceneIndex::synthetic(cfg, std::max<std::size_t>(2, synthetic / 4), s, seed + 500009);
    for (std::size_t i = 0; i < va.size(); ++i) {
      d.val_names.push_back("synthetic_val_" + std::to_string(i));
      val_all.push_back({d.val_names.back(), va.load(i)});
    }
  } else {
    const SceneIndex idx(data, data_format, cfg.bands, cfg.wavelengths_nm());
    SceneSplit sp = idx.split(seed, 0.9, 0.1);
    if (idx.size() >= 2 && sp.val.empty()) {  // at least one validation scene
      sp.val.push_back(sp.train.back());
      sp.train.pop_back();
    }
    if (sp.train.empty()) sp.train = sp.val;
    if (sp.val.empty()) sp.val = sp.train;
    for (std::size_t i : sp.train) {
      RealStack cube = idx.load(i);
      check_training_scene(cube, idx[i].path);
      if (cube.rows < s || cube.cols < s)
        reject("data", idx[i].path, "scenes of at least S x S = " + to_str(s) + " x " + to_str(s) + " pixels (the sensor PSF size)");
      d.train.push_back(std::move(cube));
      d.train_names.push_back(idx[i].path);
    }
    for (std::size_t i : sp.val) {
      const RealStack cube = idx.load(i);
      if (cube.rows < s || cube.cols < s)
        reject("data", idx[i].path, "scenes of at least S x S = " + to_str(s) + " x " + to_str(s) + " pixels (the sensor PSF size)");
      d.val_names.push_back(idx[i].path);
      for (auto& p : extract_patches(cube, s, s)) val_all.push_back({idx[i].path, std::move(p)});
    }
  }
  const std::size_t keep = std::min(val_all.size(), std::max<std::size_t>(max_val_patches, 1));
  for (std::size_t k = 0; k < keep; ++k) d.val.push_back(val_all[k * val_all.size() / keep]);
  return d;
}

std::vector<RealStack> joint_batch(const JointData& d, std::size_t s, std::size_t batch, std::uint64_t seed, long step) {
  if (d.train.empty()) reject("data", "(no training scenes)", "at least one training scene");
  std::mt19937_64 rng(seed * 0x9E3779B97F4A7C15ull + std::uint64_t(step) * 2654435761ull + 0x5eedull);
  std::vector<RealStack> out;
  out.reserve(batch);
  for (std::size_t k = 0; k < batch; ++k) {
    const RealStack& c = d.train[rng() % d.train.size()];
    const std::size_t y0 = std::size_t(rng() % (c.rows - s + 1)), x0 = std::size_t(rng() % (c.cols - s + 1));
    const unsigned t = unsigned(rng() % 8);
    RealStack p(c.planes, s, s);
    for (std::size_t b = 0; b < c.planes; ++b)
      for (std::size_t y = 0; y < s; ++y)
        for (std::size_t x = 0; x < s; ++x) {
          std::size_t yy = (t & 4) ? x : y, xx = (t & 4) ? y : x;
          if (t & 1) xx = s - 1 - xx;
          if (t & 2) yy = s - 1 - yy;
          p(b, y, x) = c(b, y0 + yy, x0 + xx);
        }
    out.push_back(std::move(p));
  }
  return out;
}

std::vector<FixedPatch> fixed_patches(const JointData& d, std::size_t s) {
  std::vector<FixedPatch> out;
  for (std::size_t i = 0; i < d.train.size(); ++i) {
    const RealStack& c = d.train[i];
    if (c.rows < s || c.cols < s)
      reject("data", d.train_names.size() > i ? d.train_names[i] : to_str(i), "scenes of at least S x S = " + to_str(s) + " pixels");
    out.push_back({i, true, 0, 0});
    const std::size_t sy = (c.rows + 2) / 3, sx = (c.cols + 2) / 3;  // ceil(H / 3), ceil(W / 3)
    for (std::size_t y = 0; y < c.rows; y += sy)
      for (std::size_t x = 0; x < c.cols; x += sx) out.push_back({i, false, std::min(y, c.rows - s), std::min(x, c.cols - s)});
  }
  return out;
}

namespace {
// tf.image.resize's bilinear weights along one axis (half-pixel centres, no anti-aliasing).
struct Lerp {
  std::size_t lo, hi;
  double t;
};
std::vector<Lerp> lerps(std::size_t in, std::size_t out) {
  std::vector<Lerp> w(out);
  const double scale = double(in) / double(out);
  for (std::size_t i = 0; i < out; ++i) {
    const double src = (double(i) + 0.5) * scale - 0.5, f = std::floor(src);
    w[i] = {std::size_t(std::max(f, 0.0)), std::size_t(std::min(std::ceil(src), double(in - 1))), src - f};
  }
  return w;
}
}  // namespace

RealStack fixed_patch(const JointData& d, const FixedPatch& p, std::size_t s) {
  if (p.scene >= d.train.size()) reject("patch scene", p.scene, "below the training scenes' count " + to_str(d.train.size()));
  const RealStack& c = d.train[p.scene];
  RealStack out(c.planes, s, s);
  if (!p.resized) {
    if (p.y0 + s > c.rows || p.x0 + s > c.cols) reject("patch corner", to_str(p.y0) + ", " + to_str(p.x0), "a crop inside the scene");
    for (std::size_t b = 0; b < c.planes; ++b)
      for (std::size_t y = 0; y < s; ++y)
        for (std::size_t x = 0; x < s; ++x) out(b, y, x) = c(b, p.y0 + y, p.x0 + x);
    return out;
  }
  const std::vector<Lerp> wy = lerps(c.rows, s), wx = lerps(c.cols, s);
  for (std::size_t b = 0; b < c.planes; ++b)
    for (std::size_t y = 0; y < s; ++y)
      for (std::size_t x = 0; x < s; ++x) {
        const Lerp &a = wy[y], &e = wx[x];
        const double top = c(b, a.lo, e.lo) + (c(b, a.lo, e.hi) - c(b, a.lo, e.lo)) * e.t;
        const double bottom = c(b, a.hi, e.lo) + (c(b, a.hi, e.hi) - c(b, a.hi, e.lo)) * e.t;
        out(b, y, x) = top + (bottom - top) * a.t;
      }
  return out;
}

std::vector<RealStack> fixed_batch(const JointData& d, const std::vector<FixedPatch>& list, std::size_t s, std::size_t batch,
                                   long step) {
  if (list.empty()) reject("data", "(no fixed patches)", "at least one training scene");
  if (step < 0) reject("step", step, ">= 0");
  std::vector<RealStack> out;
  out.reserve(batch);
  for (std::size_t k = 0; k < batch; ++k) out.push_back(fixed_patch(d, list[(std::size_t(step) * batch + k) % list.size()], s));
  return out;
}

double band_noise_sigma(const SystemConfig& cfg, double sigma) { return sigma * cfg.pitch_m / cfg.sensor_pitch_m; }

void add_band_noise(RealStack& rgb, const Eigen::MatrixXd& srf, double sigma_band, unsigned long long seed,
                    std::size_t scene_index) {
  if (rgb.planes != 3 || srf.rows() != 3) reject("rgb", rgb.planes, "3 channels and a 3 x bands srf");
  if (!(sigma_band >= 0) || !std::isfinite(sigma_band)) reject("sigma_band", sigma_band, ">= 0, finite");
  if (sigma_band == 0) return;
  // srf n with n ~ N(0, sigma_band^2 I) is Gaussian with covariance C = sigma_band^2 srf srf^T (3 x 3):
  // drawn as C^(1/2) z, z three standard normals per pixel (the symmetric square root, so a
  // response of rank below 3 is drawn exactly too), instead of one draw per band.
  const Eigen::Matrix3d c = sigma_band * sigma_band * (srf * srf.transpose());
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(c);
  const Eigen::Matrix3d root =
      eig.eigenvectors() * eig.eigenvalues().cwiseMax(0.0).cwiseSqrt().asDiagonal() * eig.eigenvectors().transpose();
  const std::size_t hw = rgb.plane_size();
  for (std::size_t p = 0; p < hw; ++p) {
    Eigen::Vector3d z;
    for (Eigen::Index k = 0; k < 3; ++k) z(k) = noise_draw(seed, (scene_index * hw + p) * 3 + std::size_t(k)).gaussian;
    const Eigen::Vector3d e = root * z;
    for (std::size_t ch = 0; ch < 3; ++ch) rgb.plane(ch)[p] += e(Eigen::Index(ch));
  }
}

JointTrainer::JointTrainer(Runtime& rt, const SystemConfig& cfg, Precision p, NetworkDecoder& net, const JointData& data,
                           std::size_t batch, double noise_sigma, std::uint64_t seed, const JointSampling& sampling)
    : camera_(rt, cfg, p), net_(net), data_(data), s_(cfg.sensor_size_px()), batch_(batch), sigma_(noise_sigma), seed_(seed),
      sampling_(sampling) {
  if (sampling_.fixed_patches) fixed_ = fixed_patches(data_, s_);
  if (sampling_.noise_on_bands) {
    srf_ = sensor_response(cfg);
    sigma_band_ = band_noise_sigma(cfg, noise_sigma);
  }
  if (batch < 1 || batch > testset::PatchCamera::kMaxBatch)
    reject("batch", batch, "1 to " + to_str(testset::PatchCamera::kMaxBatch) + " scenes per step");
  if (!(noise_sigma >= 0) || !std::isfinite(noise_sigma)) reject("noise_sigma", noise_sigma, ">= 0");
  const mpi::World* w = mpi::world();
  if (w && w->active() && w->size() > 1) {
    rank_ = std::size_t(w->rank());
    ranks_ = std::size_t(w->size());
    if (batch % ranks_ != 0)
      reject("batch", batch, "a multiple of the MPI world size " + to_str(ranks_) + " (each rank trains on batch / " + to_str(ranks_) +
                                 " scenes of every step's batch)");
    net_.set_rank_sum([w](double* values, std::size_t n) { w->allreduce_sum(values, n); });
  }
}

double JointTrainer::step(long step, double lr_net, const RealStack& psf, RealStack& grad_psf) {
  // This rank's items [k0, k1) of the step's batch (all of it in one process).
  std::vector<RealStack> batch =
      sampling_.fixed_patches ? fixed_batch(data_, fixed_, s_, batch_, step) : joint_batch(data_, s_, batch_, seed_, step);
  const std::size_t k0 = rank_ * batch_ / ranks_, k1 = (rank_ + 1) * batch_ / ranks_;
  const std::vector<RealStack> cubes = ranks_ == 1 ? std::move(batch) : std::vector<RealStack>(batch.begin() + long(k0), batch.begin() + long(k1));
  std::vector<RealStack> images = camera_.measure(psf, cubes);
  // Read noise, drawn per step (scene k of the batch: counters of ref::add_noise's scene k).
  const unsigned long long noise_seed = (seed_ + 31) * 1000003ull + std::uint64_t(step);
  for (std::size_t k = 0; k < images.size(); ++k) {
    if (sampling_.noise_on_bands) add_band_noise(images[k], srf_, sigma_band_, noise_seed, k0 + k);
    else ref::add_noise(images[k], sigma_, 0, noise_seed, k0 + k);
  }
  last_ = ranks_ == 1 ? net_.train(images, cubes, lr_net) : net_.backward(images, cubes, double(k1 - k0) / double(batch_), rank_ == 0);
  if (last_.grad_images.size() != images.size() || !std::isfinite(last_.loss))
    throw NumericalError("joint step " + std::to_string(step) + ": the network returned loss " + to_str(last_.loss) + " and " +
                         to_str(last_.grad_images.size()) + " image gradients for " + to_str(images.size()) + " images");
  grad_psf = camera_.vjp(last_.grad_images);
  if (ranks_ > 1) {
    // The one sum of the step: [dL/dPSF (bands x S x S, row-major planes), the network's gradients
    // (parameter order), loss, MAE, MSE], each this rank's weighted part.
    const std::size_t g = grad_psf.data.size(), p = net_.parameter_count();
    std::vector<double> sum(g + p + 3);
    std::copy(grad_psf.data.begin(), grad_psf.data.end(), sum.begin());
    net_.read_gradients(sum.data() + g);
    sum[g + p] = last_.loss;
    sum[g + p + 1] = last_.mae;
    sum[g + p + 2] = last_.psnr_db;  // the weighted MSE (NetworkDecoder::backward)
    mpi::world()->allreduce_sum(sum.data(), sum.size());
    std::copy(sum.begin(), sum.begin() + long(g), grad_psf.data.begin());
    net_.apply_gradients(sum.data() + g, lr_net);
    last_.loss = sum[g + p];
    last_.mae = sum[g + p + 1];
    last_.psnr_db = sum[g + p + 2] > 0 ? 10 * std::log10(1 / sum[g + p + 2]) : INFINITY;
    if (!std::isfinite(last_.loss))
      throw NumericalError("joint step " + std::to_string(step) + ": the loss summed over the ranks is " + to_str(last_.loss));
  }
  last_psf_ = psf;
  return last_.loss;
}

double JointTrainer::validation_psnr_db(const RealStack& psf) {
  if (data_.val.empty()) return NAN;
  const NetworkImageDecoder dec(net_, psf.planes, batch_);
  const testset::Evaluation ev = testset::evaluate(camera_, psf, data_.val, dec, sigma_, seed_ + 1);
  double sum = 0;
  for (const auto& [scene, sc] : ev.per_patch) sum += sc.psnr;
  return sum / double(ev.per_patch.size());
}

}  // namespace qdo
