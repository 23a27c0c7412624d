// Training scenes: the scene index and split, patches and augmentation, the cube cache and
// the patch sampler (see include/qdo/data/datasets.hpp).
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <limits>
#include <numeric>
#include <utility>

#include "data/datasets_internal.hpp"
#include "qdo/data/datasets.hpp"
#include "qdo/runtime/error.hpp"

namespace qdo {
using namespace io_detail;
using namespace datasets_detail;
namespace {

namespace fs = std::filesystem;

template <typename T>
void shuffle(std::vector<T>& v, std::mt19937_64& rng) {
  for (std::size_t i = v.size(); i > 1; --i) std::swap(v[i - 1], v[uniform_below(rng, i)]);
}

}  // namespace

// =========================================================================================
// Scene index and split
// =========================================================================================

SceneIndex::SceneIndex(const std::vector<std::string>& paths, const std::string& format, std::size_t expected_bands,
                       const std::vector<double>& wavelengths_nm)
    : bands_(expected_bands), wavelengths_nm_(wavelengths_nm) {
  check_format(format);
  if (paths.empty()) reject("paths", "[]", "at least one scene file or folder");
  const bool want_png = format == "auto" || format == "cave" || format == "cave-png";
  const bool want_files = format != "cave-png";
  std::vector<std::string> found;
  auto folder_has_png = [](const fs::path& d) {
    std::error_code e;
    for (fs::directory_iterator it(d, e), end; !e && it != end; it.increment(e))
      if (it->is_regular_file(e) && lower_ext(it->path()) == ".png") return true;
    return false;
  };
  auto scene_file = [](const fs::path& f) {
    const std::string e = lower_ext(f);
    return e == ".mat" || e == ".h5" || e == ".hdf5";
  };
  for (const std::string& p : paths) {
    std::error_code ec;
    if (fs::is_regular_file(p, ec)) {
      found.push_back(p);
      continue;
    }
    if (!fs::is_directory(p, ec)) fail(p, "no such file or folder");
    if (want_png && folder_has_png(p)) found.push_back(p);
    for (fs::recursive_directory_iterator it(p, fs::directory_options::skip_permission_denied, ec), end;
         !ec && it != end; it.increment(ec)) {
      if (want_files && it->is_regular_file(ec) && scene_file(it->path())) found.push_back(it->path().string());
      else if (want_png && it->is_directory(ec) && folder_has_png(it->path())) found.push_back(it->path().string());
    }
    if (ec) fail_dir(p, "cannot list the folder: " + ec.message());
  }
  std::sort(found.begin(), found.end());
  found.erase(std::unique(found.begin(), found.end()), found.end());
  if (found.empty()) {
    std::string list;
    for (const auto& p : paths) list += (list.empty() ? "" : ", ") + p;
    throw InputError("no scenes (*.mat, *.h5, *.hdf5 or folders of PNG bands) found under " + list);
  }
  for (const std::string& f : found) {
    SceneEntry e;
    e.path = f;
    e.format = resolve_format(f, format);
    e.shape = probe_scene(f, e.format, expected_bands, wavelengths_nm);
    entries_.push_back(std::move(e));
  }
}

SceneIndex SceneIndex::synthetic(const SystemConfig& cfg, std::size_t count, std::size_t size_px, std::uint64_t seed) {
  if (count == 0) reject("count", count, "at least 1 synthetic scene");
  if (size_px == 0 || size_px > 16384) reject("size_px", size_px, "1 .. 16384 pixels");
  const std::size_t bands = cfg.wavelengths_nm().size();
  if (bands == 0) reject("bands", bands, "at least 1 band");
  SceneIndex idx;
  idx.bands_ = bands;
  idx.synthetic_cfg_ = std::make_shared<const SystemConfig>(cfg);
  for (std::size_t k = 0; k < count; ++k) {
    SceneEntry e;
    e.path = "synthetic:" + std::to_string(k);
    e.format = "synthetic";
    e.shape = {bands, size_px, size_px};
    e.synthetic_seed = mix_seed(seed, k);
    idx.entries_.push_back(std::move(e));
  }
  return idx;
}

RealStack SceneIndex::load(std::size_t i) const {
  if (i >= entries_.size()) reject("scene", i, "an index below " + std::to_string(entries_.size()));
  const SceneEntry& e = entries_[i];
  RealStack cube = e.format == "synthetic" ? synthetic_scene(*synthetic_cfg_, e.shape.rows, e.synthetic_seed)
                                           : load_scene(e.path, e.format, bands_, wavelengths_nm_);
  const SceneShape got{cube.planes, cube.rows, cube.cols};
  if (!(got == e.shape))
    fail(e.path, "read as " + shape_str(got) + " but indexed as " + shape_str(e.shape) + " (changed since indexed?)");
  return cube;
}

SceneSplit SceneIndex::split(std::uint64_t seed, double train_frac, double val_frac) const {
  if (!(train_frac >= 0 && train_frac <= 1)) reject("train_frac", train_frac, "0 .. 1");
  if (!(val_frac >= 0 && val_frac <= 1)) reject("val_frac", val_frac, "0 .. 1");
  if (train_frac + val_frac > 1 + 1e-12) reject("train_frac + val_frac", train_frac + val_frac, "at most 1");
  const std::size_t n = entries_.size();
  const auto count = [n](double f) { return static_cast<std::size_t>(std::llround(f * static_cast<double>(n))); };
  const std::size_t n_train = std::min(n, count(train_frac));
  const std::size_t n_val = std::min(n - n_train, count(val_frac));
  std::vector<std::size_t> order(n);
  std::iota(order.begin(), order.end(), std::size_t{0});
  std::mt19937_64 rng(mix_seed(seed, 0x5911u));
  shuffle(order, rng);
  SceneSplit s;
  s.train.assign(order.begin(), order.begin() + static_cast<std::ptrdiff_t>(n_train));
  s.val.assign(order.begin() + static_cast<std::ptrdiff_t>(n_train),
               order.begin() + static_cast<std::ptrdiff_t>(n_train + n_val));
  s.test.assign(order.begin() + static_cast<std::ptrdiff_t>(n_train + n_val), order.end());
  std::sort(s.train.begin(), s.train.end());
  std::sort(s.val.begin(), s.val.end());
  std::sort(s.test.begin(), s.test.end());
  return s;
}

// =========================================================================================
// Patches and augmentation
// =========================================================================================

bool operator==(const PatchOrigin& a, const PatchOrigin& b) { return a.y == b.y && a.x == b.x; }

std::vector<std::size_t> patch_starts(std::size_t length, std::size_t size, std::size_t stride) {
  if (size == 0) reject("patch size", size, "at least 1 pixel");
  if (stride == 0) reject("stride", stride, "at least 1 pixel");
  if (size > length)
    reject("patch size", size, "at most the scene size along each axis (" + std::to_string(length) + " pixels)");
  std::vector<std::size_t> s;
  for (std::size_t p = 0; p + size <= length; p += stride) s.push_back(p);
  if (s.back() + size < length) s.push_back(length - size);
  return s;
}

std::vector<PatchOrigin> patch_origins(std::size_t rows, std::size_t cols, std::size_t size, std::size_t stride) {
  const std::vector<std::size_t> ys = patch_starts(rows, size, stride), xs = patch_starts(cols, size, stride);
  std::vector<PatchOrigin> o;
  for (std::size_t y : ys)
    for (std::size_t x : xs) o.push_back({y, x});
  return o;
}

std::vector<PatchOrigin> grid_origins(std::size_t rows, std::size_t cols, std::size_t size, std::size_t per_axis) {
  if (per_axis == 0) reject("per_axis", per_axis, "at least 1 crop per axis");
  if (size == 0) reject("patch size", size, "at least 1 pixel");
  if (size > rows || size > cols)
    reject("patch size", size,
           "at most the scene size " + std::to_string(rows) + " x " + std::to_string(cols) + " (rows x cols)");
  auto starts = [&](std::size_t length) {
    std::vector<std::size_t> s;
    for (std::size_t k = 0; k < per_axis; ++k)
      s.push_back(per_axis == 1 ? (length - size) / 2
                                : static_cast<std::size_t>(std::llround(static_cast<double>(k * (length - size)) /
                                                                        static_cast<double>(per_axis - 1))));
    return s;
  };
  std::vector<PatchOrigin> o;
  for (std::size_t y : starts(rows))
    for (std::size_t x : starts(cols)) o.push_back({y, x});
  return o;
}

RealStack crop_window(const RealStack& cube, std::size_t row, std::size_t col, std::size_t rows, std::size_t cols) {
  if (rows == 0 || cols == 0 || row + rows > cube.rows || col + cols > cube.cols)
    reject("patch", "(" + std::to_string(row) + ", " + std::to_string(col) + ") size " + std::to_string(rows) + " x " + std::to_string(cols),
           "a non-empty crop inside the " + std::to_string(cube.rows) + " x " + std::to_string(cube.cols) + " scene");
  RealStack p(cube.planes, rows, cols);
  for (std::size_t b = 0; b < cube.planes; ++b)
    for (std::size_t y = 0; y < rows; ++y) {
      const double* src = &cube(b, row + y, col);
      std::copy(src, src + cols, &p(b, y, 0));
    }
  return p;
}

RealStack crop_patch(const RealStack& cube, const PatchOrigin& o, std::size_t size) {
  if (size == 0 || o.y + size > cube.rows || o.x + size > cube.cols)
    reject("patch", "(" + std::to_string(o.y) + ", " + std::to_string(o.x) + ") size " + std::to_string(size),
           "a non-empty crop inside the " + std::to_string(cube.rows) + " x " + std::to_string(cube.cols) + " scene");
  return crop_window(cube, o.y, o.x, size, size);
}

std::vector<RealStack> extract_patches(const RealStack& cube, std::size_t size, std::size_t stride) {
  std::vector<RealStack> out;
  for (const PatchOrigin& o : patch_origins(cube.rows, cube.cols, size, stride)) out.push_back(crop_patch(cube, o, size));
  return out;
}

std::vector<RealStack> paper_crops(const RealStack& cube, std::size_t size) {
  std::vector<RealStack> out;
  for (const PatchOrigin& o : grid_origins(cube.rows, cube.cols, size, 3)) out.push_back(crop_patch(cube, o, size));
  return out;
}

RealStack augment(const RealStack& cube, int code) {
  if (code < 0 || code > 7) reject("augmentation code", code, "0 .. 7 (4 x flip + quarter turns)");
  const std::size_t rot = static_cast<std::size_t>(code % 4);
  const bool flip = code >= 4;
  const std::size_t H = cube.rows, W = cube.cols;
  const bool swap = rot % 2 == 1;
  RealStack out(cube.planes, swap ? W : H, swap ? H : W);
  // Source pixel of each output pixel: undo the rotations (each counter-clockwise quarter
  // turn maps in(y, x) to out(W-1-x, y), i.e. out(i, j) = in(j, h-1-i) with h = out rows),
  // then the mirror.
  std::vector<std::size_t> src(out.rows * out.cols);
  for (std::size_t i0 = 0; i0 < out.rows; ++i0)
    for (std::size_t j0 = 0; j0 < out.cols; ++j0) {
      std::size_t i = i0, j = j0, h = out.rows, w = out.cols;
      for (std::size_t r = 0; r < rot; ++r) {
        const std::size_t ni = j, nj = h - 1 - i;
        i = ni;
        j = nj;
        std::swap(h, w);
      }
      if (flip) j = w - 1 - j;
      src[i0 * out.cols + j0] = i * W + j;
    }
  for (std::size_t b = 0; b < cube.planes; ++b) {
    const double* in = cube.plane(b);
    double* o = out.plane(b);
    for (std::size_t k = 0; k < src.size(); ++k) o[k] = in[src[k]];
  }
  return out;
}

int augment_inverse(int code) {
  if (code < 0 || code > 7) reject("augmentation code", code, "0 .. 7 (4 x flip + quarter turns)");
  return code >= 4 ? code : (4 - code) % 4;  // mirrors are their own inverse
}

// =========================================================================================
// Patch sampler
// =========================================================================================

CubeCache::CubeCache(std::size_t capacity) : capacity_(capacity) {
  if (capacity == 0) reject("cache_scenes", capacity, "at least 1 cube");
}

std::shared_ptr<const RealStack> CubeCache::get(const SceneIndex& index, std::size_t i) {
  const auto it = where_.find(i);
  if (it != where_.end()) {
    lru_.splice(lru_.begin(), lru_, it->second);
    return it->second->second;
  }
  auto cube = std::make_shared<const RealStack>(index.load(i));
  ++loads_;
  while (lru_.size() >= capacity_) {
    where_.erase(lru_.back().first);
    lru_.pop_back();
  }
  lru_.emplace_front(i, cube);
  where_[i] = lru_.begin();
  return cube;
}

PatchSampler::PatchSampler(SceneIndex index, std::vector<std::size_t> scenes, const PatchSamplerOptions& opt,
                           std::uint64_t seed)
    : index_(std::move(index)), scenes_(std::move(scenes)), opt_(opt), seed_(seed), cache_(opt.cache_scenes) {
  if (scenes_.empty()) reject("scenes", "[]", "at least one scene of the index");
  if (opt_.batch_size == 0) reject("batch_size", opt_.batch_size, "at least 1");
  if (opt_.patch_size == 0) reject("patch_size", opt_.patch_size, "at least 1 pixel");
  for (std::size_t s : scenes_) {
    if (s >= index_.size()) reject("scene", s, "an index below " + std::to_string(index_.size()));
    const SceneEntry& e = index_[s];
    if (e.shape.rows < opt_.patch_size || e.shape.cols < opt_.patch_size)
      fail(e.path, "scene of " + std::to_string(e.shape.rows) + " x " + std::to_string(e.shape.cols) +
                       " pixels is smaller than the " + std::to_string(opt_.patch_size) + " x " +
                       std::to_string(opt_.patch_size) + " patch");
  }
}

std::vector<PatchOrigin> PatchSampler::origins_for(std::size_t scene, std::mt19937_64& rng) const {
  const SceneShape& s = index_[scene].shape;
  const std::size_t P = opt_.patch_size;
  if (opt_.random_per_scene > 0) {
    std::vector<PatchOrigin> o;
    for (std::size_t k = 0; k < opt_.random_per_scene; ++k) {
      const std::size_t y = uniform_below(rng, s.rows - P + 1);
      o.push_back({y, uniform_below(rng, s.cols - P + 1)});
    }
    return o;
  }
  return opt_.stride == 0 ? grid_origins(s.rows, s.cols, P, 3) : patch_origins(s.rows, s.cols, P, opt_.stride);
}

std::size_t PatchSampler::patches_per_epoch() const {
  if (opt_.random_per_scene > 0) return opt_.random_per_scene * scenes_.size();
  std::size_t n = 0;
  std::mt19937_64 unused(0);
  for (std::size_t s : scenes_) n += origins_for(s, unused).size();
  return n;
}

void PatchSampler::plan_epoch() {
  ++epoch_;
  std::mt19937_64 rng(mix_seed(seed_, epoch_));
  std::vector<std::size_t> order = scenes_;
  shuffle(order, rng);
  plan_.clear();
  for (std::size_t g = 0; g < order.size(); g += opt_.cache_scenes) {
    std::vector<PatchRef> group;
    for (std::size_t k = g; k < std::min(order.size(), g + opt_.cache_scenes); ++k)
      for (const PatchOrigin& o : origins_for(order[k], rng)) group.push_back({order[k], o, 0});
    shuffle(group, rng);
    for (PatchRef& r : group) r.code = opt_.augment ? static_cast<int>(uniform_below(rng, 8)) : 0;
    plan_.insert(plan_.end(), group.begin(), group.end());
  }
  next_ = 0;
}

std::vector<RealStack> PatchSampler::next_batch() {
  std::vector<RealStack> batch;
  last_refs_.clear();
  while (batch.size() < opt_.batch_size) {
    if (next_ >= plan_.size()) plan_epoch();
    const PatchRef& r = plan_[next_++];
    const std::shared_ptr<const RealStack> cube = cache_.get(index_, r.scene);
    RealStack p = crop_patch(*cube, r.origin, opt_.patch_size);
    batch.push_back(r.code == 0 ? std::move(p) : augment(p, r.code));
    last_refs_.push_back(r);
  }
  return batch;
}

}  // namespace qdo
