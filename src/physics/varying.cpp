#include "qdo/physics/varying.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

#include "qdo/runtime/error.hpp"
#include "qdo/runtime/fft.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/point_psf.hpp"

namespace qdo {

PsfPlacement psf_placement_from_string(const std::string& s) {
  if (s == "source") return PsfPlacement::Source;
  if (s == "output") return PsfPlacement::Output;
  reject("placement", s, "\"source\" (each scene pixel emits through its own PSF) or \"output\" (each output pixel takes its own PSF's image)");
}
std::string to_string(PsfPlacement p) { return p == PsfPlacement::Source ? "source" : "output"; }

std::string VaryingReport::to_json() const {
  nlohmann::json j;
  j["placement"] = to_string(placement);
  j["components"] = components;
  j["height"] = height;
  j["width"] = width;
  j["bands"] = bands;
  j["kept"] = kept;
  j["skipped"] = skipped;
  j["grid_rows"] = grid_rows;
  j["grid_cols"] = grid_cols;
  j["forward_ffts"] = forward_ffts;
  j["inverse_ffts"] = inverse_ffts;
  j["otf_builds"] = otf_builds;
  j["psf_generation"] = psf_generation;
  return j.dump();
}

VaryingCamera::VaryingCamera(const PsfSource& source)
    : rt_(source.runtime()), source_(&source), cfg_(source.config()), prec_(source.precision()), s_(source.sensor_size()),
      rsz_(real_size(source.precision())), srf_(sensor_response(source.config())) {
  if (cfg_.bands == 0 || source.psf_planes() % cfg_.bands != 0 || source.psf_planes() == 0)
    reject("PSF source planes", source.psf_planes(), "components x bands, a multiple of the configuration's " + to_str(cfg_.bands) + " bands (" + source.describe() + ")");
  k_ = source.psf_planes() / cfg_.bands;
  init();
}

VaryingCamera::VaryingCamera(Runtime& rt, const SystemConfig& cfg, Precision p, std::size_t components)
    : rt_(rt), cfg_(cfg), prec_(p), k_(components), rsz_(real_size(p)) {
  cfg_.validate();
  rt_.require(p);
  if (components < 1) reject("components", components, "at least 1");
  s_ = cfg_.sensor_size_px();
  srf_ = sensor_response(cfg_);
  init();
}

void VaryingCamera::init() {
  if (cfg_.convolution != ConvolutionMode::Linear)
    reject("convolution", "circular", "\"linear\" (spatially varying imaging uses the camera's linear convolution)");
  shifts_.assign(k_, {0, 0});
  otf_keys_.assign(k_, OtfKey{});
  k_place_psf_ = rt_.kernel("varying.cl", "place_psf_shifted", prec_);
  k_gather_psf_ = rt_.kernel("varying.cl", "gather_psf_shifted", prec_);
  k_place_ = rt_.kernel("varying.cl", "place_weighted", prec_);
  k_gather_ = rt_.kernel("varying.cl", "gather_weighted", prec_);
  k_combine_ = rt_.kernel("varying.cl", "combine_component", prec_);
  k_vjp_ = rt_.kernel("varying.cl", "component_vjp_spectra", prec_);
  k_wgrad_ = rt_.kernel("varying.cl", "weight_gradient", prec_);
  // Sensor response of each band, 3 x 2Pb, zero-padded.
  const std::size_t pairs = (cfg_.bands + 1) / 2;
  std::vector<double> wt(3 * 2 * pairs, 0.0);
  for (std::size_t c = 0; c < 3; ++c)
    for (std::size_t b = 0; b < cfg_.bands; ++b) wt[c * 2 * pairs + b] = srf_(Eigen::Index(c), Eigen::Index(b));
  grow(wts_, wts_cap_, wt.size() * rsz_);
  rt_.write_reals(wts_, wt.data(), wt.size(), prec_);
}

void VaryingCamera::set_psfs(const RealStack& psfs) {
  if (source_) reject("set_psfs", "(camera bound to a PSF source)", "a standalone VaryingCamera (a bound camera follows its source: " + source_->describe() + ")");
  if (psfs.planes != k_ * cfg_.bands || psfs.rows != s_ || psfs.cols != s_)
    reject("psfs", shape(psfs), "(K * bands) x S x S = " + shape(k_ * cfg_.bands, s_, s_));
  for (std::size_t i = 0; i < psfs.size(); ++i)
    if (!std::isfinite(psfs.data[i])) reject("psfs[" + to_str(i) + "]", psfs.data[i], "finite values");
  own_psf_ = cl::Buffer(rt_.context(), CL_MEM_READ_ONLY, std::max<std::size_t>(psfs.size() * rsz_, 8));
  rt_.write_reals(own_psf_, psfs.data.data(), psfs.size(), prec_);
  ++own_generation_;
  vjp_ready_ = false;
}

void VaryingCamera::set_shifts(const std::vector<std::pair<long, long>>& shifts_px) {
  if (shifts_px.size() != k_) reject("shifts_px.size()", shifts_px.size(), "one (dy, dx) per component (" + to_str(k_) + ")");
  const long s = long(s_);
  for (std::size_t k = 0; k < k_; ++k)
    if (std::labs(shifts_px[k].first) >= s || std::labs(shifts_px[k].second) >= s)
      reject("shifts_px[" + to_str(k) + "]", "(" + to_str(shifts_px[k].first) + ", " + to_str(shifts_px[k].second) + ")",
             "|dy|, |dx| < S = " + to_str(s_) + " (a larger shift leaves nothing of the PSF in the window)");
  shifts_ = shifts_px;
  vjp_ready_ = false;
}

const cl::Buffer& VaryingCamera::psf_buffer() const { return source_ ? source_->psf_sensor_buffer() : own_psf_; }
std::uint64_t VaryingCamera::current_generation() const { return source_ ? source_->psf_generation() : own_generation_; }

cl::Buffer& VaryingCamera::grow(cl::Buffer& b, std::size_t& cap, std::size_t bytes) {
  bytes = std::max<std::size_t>(bytes, 8);
  if (!b() || cap < bytes) {
    b = cl::Buffer(rt_.context(), CL_MEM_READ_WRITE, bytes);
    cap = bytes;
  }
  return b;
}

void VaryingCamera::check_inputs(const RealStack& scene, const RealStack& weights) const {
  const std::size_t h = scene.rows, w = scene.cols;
  if (scene.planes != cfg_.bands) reject("scene bands", scene.planes, "the configuration's band count (" + to_str(cfg_.bands) + ")");
  if (h < 1 || w < 1) reject("scene", to_str(h) + " x " + to_str(w), "at least 1 x 1 pixels");
  if (weights.planes != k_ || weights.rows != h || weights.cols != w)
    reject("weights", shape(weights), "K x H x W = " + shape(k_, h, w) + " (one weight map per component, the scene's size)");
  for (std::size_t i = 0; i < scene.size(); ++i)
    if (!std::isfinite(scene.data[i]))
      reject("scene(" + to_str(i / (h * w)) + ", " + to_str((i / w) % h) + ", " + to_str(i % w) + ")", scene.data[i], "finite values");
  for (std::size_t i = 0; i < weights.size(); ++i)
    if (!std::isfinite(weights.data[i]))
      reject("weights(" + to_str(i / (h * w)) + ", " + to_str((i / w) % h) + ", " + to_str(i % w) + ")", weights.data[i], "finite values");
  if (source_ ? !source_->psf_ready() : own_generation_ == 0)
    throw Error(source_ ? "VaryingCamera: its PSF source has no stack yet (" + source_->describe() + "; a simulator's compute_psf() must run first)"
                        : std::string("VaryingCamera: set_psfs() must be called before images()"));
}

// Component k's pair-packed, shifted OTFs on the current grid (report_.grid_rows x grid_cols),
// into otf_ at k * Pb * G; rebuilt only when the generation, grid or shift changed.
void VaryingCamera::ensure_otf(std::size_t k) {
  const std::uint64_t gen = current_generation();
  const std::size_t gy = report_.grid_rows, gx = report_.grid_cols, g = gy * gx, pairs = (cfg_.bands + 1) / 2;
  OtfKey& key = otf_keys_[k];
  if (key.valid && key.gen == gen && key.gy == gy && key.gx == gx && key.shift == shifts_[k]) return;
  const std::size_t bytes = pairs * g * 2 * rsz_;
  grow(otf_tmp_, otf_tmp_cap_, bytes);
  rt_.launch_1d(k_place_psf_, pairs * g, prec_, psf_buffer(), otf_tmp_, int(s_), int(gy), int(gx), int(k * cfg_.bands),
                int(cfg_.bands), int(shifts_[k].first), int(shifts_[k].second));
  rt_.fft(gy, gx, pairs, prec_).forward(otf_tmp_);
  rt_.queue().enqueueCopyBuffer(otf_tmp_, otf_, 0, k * bytes, bytes);
  key = OtfKey{true, gen, gy, gx, shifts_[k]};
  ++otf_builds_;
  ++report_.otf_builds;
}

RealStack VaryingCamera::images(const RealStack& scene, const RealStack& weights, PsfPlacement placement) {
  check_inputs(scene, weights);
  vjp_ready_ = false;
  const std::size_t bands = cfg_.bands, h = scene.rows, w = scene.cols, hw = h * w, pairs = (bands + 1) / 2;
  VaryingReport rep;
  rep.placement = placement;
  rep.components = k_;
  rep.height = h;
  rep.width = w;
  rep.bands = bands;
  rep.psf_generation = current_generation();
  const std::size_t c = s_ / 2;
  rep.grid_rows = fast_fft_size(std::max(h + c, s_));
  rep.grid_cols = fast_fft_size(std::max(w + c, s_));
  for (std::size_t k = 0; k < k_; ++k) {
    const double* p = weights.plane(k);
    const bool zero = std::all_of(p, p + hw, [](double v) { return v == 0.0; });
    (zero ? rep.skipped : rep.kept).push_back(k);
  }
  // A new grid invalidates every cached OTF (their key holds the grid).
  const std::size_t gy = rep.grid_rows, gx = rep.grid_cols, g = gy * gx;
  report_ = rep;

  // ---- Device work ----
  auto& q = rt_.queue();
  const std::size_t otf_cap_before = otf_cap_;
  grow(otf_, otf_cap_, k_ * pairs * g * 2 * rsz_);
  if (otf_cap_ != otf_cap_before)  // a new buffer: nothing cached in it
    for (auto& key : otf_keys_) key.valid = false;
  grow(scene_, scene_cap_, bands * hw * rsz_);
  grow(weights_, weights_cap_, k_ * hw * rsz_);
  rt_.write_reals(scene_, scene.data.data(), scene.size(), prec_);
  rt_.write_reals(weights_, weights.data.data(), weights.size(), prec_);
  grow(spec_, spec_cap_, pairs * g * 2 * rsz_);
  grow(rgbspec_, rgbspec_cap_, 2 * g * 2 * rsz_);
  grow(rgb_, rgb_cap_, 3 * hw * rsz_);
  q.enqueueFillBuffer(rgb_, cl_uint(0), 0, 3 * hw * rsz_);
  FftPlan& fwd = rt_.fft(gy, gx, pairs, prec_);
  FftPlan& inv2 = rt_.fft(gy, gx, 2, prec_);
  const auto& kept = report_.kept;
  if (!kept.empty()) {
    for (std::size_t k : kept) ensure_otf(k);
    if (placement == PsfPlacement::Source) {
      for (std::size_t i = 0; i < kept.size(); ++i) {
        const std::size_t k = kept[i];
        rt_.launch_1d(k_place_, pairs * g, prec_, scene_, weights_, spec_, int(h), int(w), int(bands), int(gy), int(gx),
                      int(k), 1);
        fwd.forward(spec_);
        rt_.launch_1d(k_combine_, g, prec_, spec_, otf_, wts_, rgbspec_, int(gy), int(gx), int(bands), int(k),
                      int(i > 0 ? 1 : 0));
        report_.forward_ffts += pairs;
      }
      inv2.inverse(rgbspec_);
      report_.inverse_ffts += 2;
      rt_.launch_1d(k_gather_, 3 * hw, prec_, rgbspec_, weights_, rgb_, int(h), int(w), 3, int(gy), int(gx), 0, 0, 0);
    } else {
      rt_.launch_1d(k_place_, pairs * g, prec_, scene_, weights_, spec_, int(h), int(w), int(bands), int(gy), int(gx), 0,
                    0);
      fwd.forward(spec_);
      report_.forward_ffts += pairs;
      for (std::size_t k : kept) {
        rt_.launch_1d(k_combine_, g, prec_, spec_, otf_, wts_, rgbspec_, int(gy), int(gx), int(bands), int(k), 0);
        inv2.inverse(rgbspec_);
        report_.inverse_ffts += 2;
        rt_.launch_1d(k_gather_, 3 * hw, prec_, rgbspec_, weights_, rgb_, int(h), int(w), 3, int(gy), int(gx), int(k), 1,
                      1);
      }
    }
  }
  RealStack out(3, h, w);
  rt_.read_reals(rgb_, out.data.data(), out.size(), prec_);
  vjp_ready_ = true;
  return out;
}

VaryingCamera::Gradient VaryingCamera::vjp(const RealStack& g_rgb, bool want_scene, bool want_psfs, bool want_weights) {
  if (!vjp_ready_)
    reject("vjp", "without a preceding images() call", "images() on this camera first (set_psfs / set_shifts in between discard it)");
  const VaryingReport& rep = report_;
  if (current_generation() != rep.psf_generation)
    throw Error("VaryingCamera::vjp: the PSF changed since the images() call it would differentiate");
  const std::size_t bands = rep.bands, h = rep.height, w = rep.width, hw = h * w, pairs = (bands + 1) / 2;
  if (g_rgb.planes != 3 || g_rgb.rows != h || g_rgb.cols != w) reject("g_rgb", shape(g_rgb), "3 x H x W = " + shape(3, h, w));
  for (std::size_t i = 0; i < g_rgb.size(); ++i)
    if (!std::isfinite(g_rgb.data[i])) reject("g_rgb[" + to_str(i) + "]", g_rgb.data[i], "finite values");
  Gradient out;
  if (want_scene) out.scene = RealStack(bands, h, w);
  if (want_psfs) out.psfs = RealStack(k_ * bands, s_, s_);
  if (want_weights) out.weights = RealStack(k_, h, w);
  const std::size_t gy = rep.grid_rows, gx = rep.grid_cols, g = gy * gx, ss = s_ * s_;
  auto& q = rt_.queue();
  grow(grgb_, grgb_cap_, 3 * hw * rsz_);
  rt_.write_reals(grgb_, g_rgb.data.data(), g_rgb.size(), prec_);
  grow(gspec_, gspec_cap_, 2 * g * 2 * rsz_);
  grow(gscene_spec_, gscene_spec_cap_, pairs * g * 2 * rsz_);
  grow(gpsf_spec_, gpsf_spec_cap_, pairs * g * 2 * rsz_);
  grow(gscene_, gscene_cap_, bands * hw * rsz_);
  grow(gpsf_, gpsf_cap_, k_ * bands * ss * rsz_);
  grow(gw_, gw_cap_, k_ * hw * rsz_);
  q.enqueueFillBuffer(gscene_, cl_uint(0), 0, bands * hw * rsz_);
  q.enqueueFillBuffer(gpsf_, cl_uint(0), 0, k_ * bands * ss * rsz_);
  FftPlan& fwdp = rt_.fft(gy, gx, pairs, prec_);
  FftPlan& fwd2 = rt_.fft(gy, gx, 2, prec_);
  const int ws = want_scene ? 1 : 0, wp = want_psfs ? 1 : 0;
  // Components visited: the kept ones, or all of them for the weight gradient.
  std::vector<std::uint8_t> is_kept(k_, 0);
  for (std::size_t k : rep.kept) is_kept[k] = 1;
  std::vector<std::size_t> visit = rep.kept;
  if (want_weights) {
    visit.resize(k_);
    std::iota(visit.begin(), visit.end(), std::size_t(0));
  }
  for (std::size_t k : visit) ensure_otf(k);  // cached unless the grid changed or a skipped one is new
  auto gather_psf = [&](std::size_t k) {
    fwdp.inverse(gpsf_spec_);
    rt_.launch_1d(k_gather_psf_, bands * ss, prec_, gpsf_spec_, gpsf_, int(s_), int(gy), int(gx), int(k * bands),
                  int(bands), int(shifts_[k].first), int(shifts_[k].second));
  };
  if (!visit.empty()) {
    if (rep.placement == PsfPlacement::Source) {
      // G = F(g); per component: X_k = F(w_k x), B_k = F^-1(conj(OTF_k) G) (the back-projected
      // band gradients), scene gradient w_k ⊙ B_k, PSF gradient F^-1(conj(X_k) G), weight
      // gradient sum_b x_b ⊙ B_k,b.
      rt_.launch_1d(k_place_, 2 * g, prec_, grgb_, weights_, gspec_, int(h), int(w), 3, int(gy), int(gx), 0, 0);
      fwd2.forward(gspec_);
      for (std::size_t k : visit) {
        const bool kept = is_kept[k] != 0;
        const int wpk = kept ? wp : 0, wsk = (kept && want_scene) || want_weights ? 1 : 0;
        if (wpk) {
          rt_.launch_1d(k_place_, pairs * g, prec_, scene_, weights_, spec_, int(h), int(w), int(bands), int(gy), int(gx),
                        int(k), 1);
          fwdp.forward(spec_);
        }
        rt_.launch_1d(k_vjp_, pairs * g, prec_, gspec_, spec_, otf_, wts_, gscene_spec_, gpsf_spec_, int(gy), int(gx),
                      int(bands), int(k), wsk, 0, wpk);
        if (wsk) fwdp.inverse(gscene_spec_);
        if (kept && want_scene)
          rt_.launch_1d(k_gather_, bands * hw, prec_, gscene_spec_, weights_, gscene_, int(h), int(w), int(bands), int(gy),
                        int(gx), int(k), 1, 1);
        if (want_weights)
          rt_.launch_1d(k_wgrad_, hw, prec_, gscene_spec_, scene_, gw_, int(h), int(w), int(bands), int(gy), int(gx), int(k));
        if (wpk) gather_psf(k);
      }
    } else {
      // X = F(x); per component: G_k = F(w_k ⊙ g), scene gradient spectra conj(OTF_k) G_k summed
      // over k (one set of inverse transforms), PSF gradient F^-1(conj(X) G_k).
      rt_.launch_1d(k_place_, pairs * g, prec_, scene_, weights_, spec_, int(h), int(w), int(bands), int(gy), int(gx), 0,
                    0);
      fwdp.forward(spec_);
      for (std::size_t i = 0; i < rep.kept.size(); ++i) {
        const std::size_t k = rep.kept[i];
        rt_.launch_1d(k_place_, 2 * g, prec_, grgb_, weights_, gspec_, int(h), int(w), 3, int(gy), int(gx), int(k), 1);
        fwd2.forward(gspec_);
        rt_.launch_1d(k_vjp_, pairs * g, prec_, gspec_, spec_, otf_, wts_, gscene_spec_, gpsf_spec_, int(gy), int(gx),
                      int(bands), int(k), ws, int(i > 0 ? 1 : 0), wp);
        if (want_psfs) gather_psf(k);
      }
      // Weight gradient: sum_c g_c ⊙ (component k's unweighted RGB image), for every component.
      if (want_weights)
        for (std::size_t k : visit) {
          rt_.launch_1d(k_combine_, g, prec_, spec_, otf_, wts_, rgbspec_, int(gy), int(gx), int(bands), int(k), 0);
          fwd2.inverse(rgbspec_);
          rt_.launch_1d(k_wgrad_, hw, prec_, rgbspec_, grgb_, gw_, int(h), int(w), 3, int(gy), int(gx), int(k));
        }
      if (want_scene && !rep.kept.empty()) {
        fwdp.inverse(gscene_spec_);
        rt_.launch_1d(k_gather_, bands * hw, prec_, gscene_spec_, weights_, gscene_, int(h), int(w), int(bands), int(gy),
                      int(gx), 0, 0, 0);
      }
    }
  }
  if (want_scene) rt_.read_reals(gscene_, out.scene.data.data(), out.scene.size(), prec_);
  if (want_psfs) rt_.read_reals(gpsf_, out.psfs.data.data(), out.psfs.size(), prec_);
  if (want_weights) rt_.read_reals(gw_, out.weights.data.data(), out.weights.size(), prec_);
  return out;
}

// ---- Weight builders ----

namespace {
void check_distance(const std::string& name, double d) {
  if (std::isnan(d) || d <= 0 || d == -std::numeric_limits<double>::infinity())
    reject(name, d, "a distance > 0 m, or +infinity (a point at infinity)");
}
double diopters(double d) { return std::isinf(d) ? 0.0 : 1.0 / d; }

// The 1-D hats of knots t (strictly monotone) at position x: weights per knot (two nonzero at most).
void hats(const std::vector<double>& t, double x, std::vector<double>& out) {
  const std::size_t n = t.size();
  out.assign(n, 0.0);
  std::vector<std::size_t> order(n);
  std::iota(order.begin(), order.end(), 0);
  if (n > 1 && t[0] > t[1]) std::reverse(order.begin(), order.end());  // ascending knots
  if (x <= t[order.front()]) {
    out[order.front()] = 1;
    return;
  }
  if (x >= t[order.back()]) {
    out[order.back()] = 1;
    return;
  }
  for (std::size_t i = 0; i + 1 < n; ++i) {
    const double a = t[order[i]], b = t[order[i + 1]];
    if (x >= a && x <= b) {
      const double f = (x - a) / (b - a);
      out[order[i]] = 1 - f;
      out[order[i + 1]] = f;
      return;
    }
  }
}

void check_knots(const std::string& name, const std::vector<double>& t) {
  if (t.empty()) reject(name, "(empty)", "at least one offset");
  for (std::size_t i = 0; i < t.size(); ++i)
    if (!std::isfinite(t[i])) reject(name + "[" + to_str(i) + "]", t[i], "finite offsets in pixels");
  if (t.size() < 2) return;
  const bool up = t[1] > t[0];
  for (std::size_t i = 0; i + 1 < t.size(); ++i)
    if (up ? !(t[i + 1] > t[i]) : !(t[i + 1] < t[i]))
      reject(name + "[" + to_str(i + 1) + "]", t[i + 1], "strictly monotone offsets (increasing or decreasing), after " + to_str(t[i]));
}
}  // namespace

RealStack depth_layer_weights(const Map2D& depth_m, const std::vector<double>& layers_m, std::size_t rows, std::size_t cols) {
  if (depth_m.rows != rows || depth_m.cols != cols)
    reject("depth map", to_str(depth_m.rows) + " x " + to_str(depth_m.cols), "the scene's size " + to_str(rows) + " x " + to_str(cols));
  if (layers_m.empty()) reject("depth layers", "(none)", "at least one layer distance");
  for (std::size_t k = 0; k < layers_m.size(); ++k) check_distance("depth layer[" + to_str(k) + "] (m)", layers_m[k]);
  for (std::size_t i = 0; i < depth_m.data.size(); ++i)
    check_distance("depth(" + to_str(i / cols) + ", " + to_str(i % cols) + ") (m)", depth_m.data[i]);
  const std::size_t kk = layers_m.size(), hw = rows * cols;
  RealStack wts(kk, rows, cols);
  std::vector<double> inv(kk);
  for (std::size_t k = 0; k < kk; ++k) inv[k] = diopters(layers_m[k]);
  for (std::size_t i = 0; i < hw; ++i) {
    const double v = diopters(depth_m.data[i]);
    std::size_t best = 0;
    for (std::size_t k = 1; k < kk; ++k)
      if (std::fabs(inv[k] - v) < std::fabs(inv[best] - v)) best = k;
    wts.data[best * hw + i] = 1.0;
  }
  return wts;
}

RealStack field_grid_weights(std::size_t height, std::size_t width, const std::vector<double>& rows_px,
                             const std::vector<double>& cols_px) {
  if (height < 1 || width < 1) reject("scene", to_str(height) + " x " + to_str(width), "at least 1 x 1 pixels");
  check_knots("rows_px", rows_px);
  check_knots("cols_px", cols_px);
  const std::size_t ny = rows_px.size(), nx = cols_px.size();
  RealStack out(ny * nx, height, width);
  std::vector<std::vector<double>> hy(height), hx(width);
  for (std::size_t y = 0; y < height; ++y) hats(rows_px, double(y) - double(height / 2), hy[y]);
  for (std::size_t x = 0; x < width; ++x) hats(cols_px, double(x) - double(width / 2), hx[x]);
  for (std::size_t i = 0; i < ny; ++i)
    for (std::size_t j = 0; j < nx; ++j) {
      double* p = out.plane(i * nx + j);
      for (std::size_t y = 0; y < height; ++y) {
        if (hy[y][i] == 0) continue;
        for (std::size_t x = 0; x < width; ++x) p[y * width + x] = hy[y][i] * hx[x][j];
      }
    }
  return out;
}

FieldGrid field_grid(const SystemConfig& cfg, double distance_m, const std::vector<double>& theta_x_deg,
                     const std::vector<double>& theta_y_deg) {
  check_distance("distance_m", distance_m);
  if (theta_x_deg.empty()) reject("theta_x_deg", "(empty)", "at least one field angle");
  if (theta_y_deg.empty()) reject("theta_y_deg", "(empty)", "at least one field angle");
  FieldGrid fg;
  for (double ty : theta_y_deg) fg.rows_px.push_back(chief_ray_offset_px(cfg, ObjectPoint{distance_m, 0, ty}).first);
  for (double tx : theta_x_deg) fg.cols_px.push_back(chief_ray_offset_px(cfg, ObjectPoint{distance_m, tx, 0}).second);
  for (std::size_t i = 0; i < theta_y_deg.size(); ++i)
    for (std::size_t j = 0; j < theta_x_deg.size(); ++j) {
      const ObjectPoint p{distance_m, theta_x_deg[j], theta_y_deg[i]};
      fg.points.push_back(p);
      const auto off = chief_ray_offset_px(cfg, p);
      fg.shifts_px.emplace_back(std::lround(off.first), std::lround(off.second));
    }
  return fg;
}

LowRankPsf low_rank_psf(const RealStack& psfs, std::size_t bands, std::size_t rank) {
  if (bands == 0 || psfs.planes == 0 || psfs.planes % bands != 0)
    reject("bands", bands, "a divisor of the stack's " + to_str(psfs.planes) + " planes (components x bands)");
  const std::size_t kk = psfs.planes / bands, n = bands * psfs.plane_size();
  if (rank < 1 || rank > kk) reject("rank", rank, "1 .. K = " + to_str(kk));
  for (std::size_t i = 0; i < psfs.size(); ++i)
    if (!std::isfinite(psfs.data[i])) reject("psfs[" + to_str(i) + "]", psfs.data[i], "finite values");
  Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>> v(psfs.data.data(), Eigen::Index(kk),
                                                                                           Eigen::Index(n));
  const Eigen::MatrixXd gram = v * v.transpose();
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(gram);
  // Eigenvalues ascending: reverse to descending.
  LowRankPsf out;
  Eigen::MatrixXd u = Eigen::MatrixXd::Zero(Eigen::Index(kk), Eigen::Index(kk));
  std::vector<double> lam(kk);
  for (std::size_t r = 0; r < kk; ++r) {
    u.col(Eigen::Index(r)) = es.eigenvectors().col(Eigen::Index(kk - 1 - r));
    lam[r] = std::max(0.0, es.eigenvalues()(Eigen::Index(kk - 1 - r)));
    out.singular.push_back(std::sqrt(lam[r]));
  }
  out.coeff = u.leftCols(Eigen::Index(rank));
  const Eigen::MatrixXd comp = out.coeff.transpose() * v;  // R x n
  out.psfs = RealStack(rank * bands, psfs.rows, psfs.cols);
  for (std::size_t r = 0; r < rank; ++r)
    for (std::size_t i = 0; i < n; ++i) out.psfs.data[r * n + i] = comp(Eigen::Index(r), Eigen::Index(i));
  double total = 0, dropped = 0;
  for (std::size_t r = 0; r < kk; ++r) {
    total += lam[r];
    if (r >= rank) dropped += lam[r];
  }
  out.truncation_error = total > 0 ? std::sqrt(dropped / total) : 0.0;
  return out;
}

RealStack combine_weights(const RealStack& weights, const Eigen::MatrixXd& coeff) {
  if (Eigen::Index(weights.planes) != coeff.rows())
    reject("coeff rows", coeff.rows(), "the weight maps' component count K = " + to_str(weights.planes));
  const std::size_t rr = std::size_t(coeff.cols()), hw = weights.plane_size();
  RealStack out(rr, weights.rows, weights.cols);
  for (std::size_t r = 0; r < rr; ++r)
    for (std::size_t k = 0; k < weights.planes; ++k) {
      const double a = coeff(Eigen::Index(k), Eigen::Index(r));
      if (a == 0) continue;
      const double* src = weights.plane(k);
      double* dst = out.plane(r);
      for (std::size_t i = 0; i < hw; ++i) dst[i] += a * src[i];
    }
  return out;
}

}  // namespace qdo
