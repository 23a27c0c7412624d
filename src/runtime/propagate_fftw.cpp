// Fused, pruned propagation on CPU devices (HostPropagator in host_propagator.hpp: the passes and the layout).
//
// Why it exists: on a CPU device the transforms run at FFTW's speed (the FFTW backend), but the
// passes between them (zero-padded field, transfer function with its energy sums, crop) went
// through PoCL's work-item loops, each a full sweep over the bands x M x M window, and together
// they cost about as much as the transforms (BENCHMARKS "CPU speed"). Here one host thread per
// plane does the whole propagation of that plane with every intermediate in cache: the rows of
// the data block, then blocks of kBlock columns (forward column transform, transfer function,
// inverse column transform back to back on a contiguous copy), then the rows of the crop.
// Reads of the window: the N x N input block once, the N x M intermediate twice; nothing of the
// M - N zero rows is ever touched.
//
// Threads: min(device compute units, hardware threads, planes), planes handed out one at a time.
// FFTW plans are single-threaded, made with FFTW_MEASURE under the planner lock, wisdom shared
// with the FFTW backend (fftw_internal.hpp); executing one plan from several threads on different
// arrays (fftw_execute_dft) is thread-safe.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstring>
#include <memory>
#include <thread>
#include <type_traits>
#include <vector>

#include "qdo/runtime/error.hpp"
#include "qdo/runtime/host_propagator.hpp"
#include "qdo/runtime/runtime.hpp"
#include "runtime/fftw_internal.hpp"

namespace qdo {
namespace {

using fftw_detail::Fftw;
using fftw_detail::planner_mutex;

// Columns per block: kBlock columns of M complex values stay in L2 (8 x 1536 x 8 B = 96 KiB in
// float32) and a gathered row segment is one 64-byte cache line in float32.
constexpr std::size_t kBlock = 8;

template <typename R>
class FftwPropagator final : public HostPropagator {
  using F = Fftw<R>;
  using C = typename F::complex;

 public:
  FftwPropagator(Runtime& rt, std::size_t m, std::size_t n, std::size_t planes, Precision p)
      : HostPropagator(m, n, planes, p), rt_(rt) {
    const auto t0 = std::chrono::steady_clock::now();
    const unsigned hw = std::max(1u, std::thread::hardware_concurrency());
    threads_ = std::max<std::size_t>(1, std::min<std::size_t>({std::size_t(std::max(1u, rt.info().compute_units)),
                                                               std::size_t(hw), planes}));
    for (std::size_t t = 0; t < threads_; ++t) {
      own_.rows.push_back(F::alloc(m));
      own_.cols.push_back(F::alloc(kBlock * m));
      if (!own_.rows.back() || !own_.cols.back()) throw std::bad_alloc();
    }
    const std::lock_guard<std::mutex> lock(planner_mutex());
    fftw_detail::init_threads_once();
    fftw_detail::load_wisdom<F>();
    F::threads(1);
    own_.row_fwd = make(1, FFTW_FORWARD);
    own_.row_bwd = make(1, FFTW_BACKWARD);
    own_.col_fwd = make(kBlock, FFTW_FORWARD);
    own_.col_bwd = make(kBlock, FFTW_BACKWARD);
    fftw_detail::save_wisdom<F>();
    bake_seconds_ = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  }

  void run(cl::Buffer& field, const Tf& tf, const Outputs& out, const IntensityAdjointInput* in) override {
    run_range(field, 0, planes_, tf, out, in);
  }
  void run_planes(cl::Buffer& field, std::size_t first, std::size_t count, const Tf& tf, const Outputs& out) override {
    if (count < 1 || first >= planes_ || count > planes_ - first)
      reject("first/count", std::to_string(first) + "/" + std::to_string(count),
             "count >= 1 and first + count <= " + std::to_string(planes_) + " planes");
    run_range(field, first, count, tf, out, nullptr);
  }
  std::size_t threads() const override { return threads_; }

 private:
  // Planes [first, first + count); `field` (and in->u) hold those planes only, from plane `first`.
  void run_range(cl::Buffer& field, std::size_t first, std::size_t count, const Tf& tf, const Outputs& out,
                 const IntensityAdjointInput* in) {
    const std::size_t m = m_, n = n_, planes = planes_, rs = sizeof(R);
    if (!tf.table) reject("tf.table", "null", "a transfer-function buffer");
    if (out.energy3 && !out.klim) reject("out.klim", "null", "a planes-long limit table when energy3 is asked for");
    if ((out.intensity == nullptr) != (out.crop_sums == nullptr))
      reject("out.intensity/out.crop_sums", "one of the two", "both or neither");
    const std::size_t field_bytes = count * m * m * 2 * rs, tf_bytes = (tf.separable ? planes * m : planes * m * m) * 2 * rs;
    check_size("field", field, field_bytes);
    check_size("tf.table", *tf.table, tf_bytes);
    if (out.energy3) check_size("out.energy3", *out.energy3, planes * 3 * rs);
    if (out.intensity) check_size("out.intensity", *out.intensity, planes * n * n * rs);
    if (out.crop_sums) check_size("out.crop_sums", *out.crop_sums, planes * rs);

    std::vector<R> w_in;
    if (in) {
      if (!in->g_sensor || !in->u || !in->start || !in->w)
        reject("in", "a partial IntensityAdjointInput", "g_sensor, u, start and w all given");
      if ((in->y_sensor == nullptr) != (in->sensor_sums == nullptr))
        reject("in->y_sensor/in->sensor_sums", "one of the two", "both or neither");
      if (in->y_sensor) {
        check_size("in->y_sensor", *in->y_sensor, planes * in->s * in->s * rs);
        check_size("in->sensor_sums", *in->sensor_sums, planes * rs);
      }
      if (in->s < 1 || in->taps < 1) reject("in->s/in->taps", std::to_string(in->s) + "/" + std::to_string(in->taps), ">= 1");
      check_size("in->g_sensor", *in->g_sensor, planes * in->s * in->s * rs);
      check_size("in->u", *in->u, field_bytes);
      if (in->col_offset != 0 && in->col_offset != n) reject("in->col_offset", std::to_string(in->col_offset), "0 or N");
      w_in.assign(in->w, in->w + (in->col_offset + n) * in->taps);
    }
    auto& q = rt_.queue();
    const MappedBuffer mf(q, field, CL_MAP_READ | CL_MAP_WRITE, field_bytes);
    const MappedBuffer mt(q, *tf.table, CL_MAP_READ, tf_bytes);
    std::unique_ptr<MappedBuffer> me, mi, ms;
    if (out.energy3) me = std::make_unique<MappedBuffer>(q, *out.energy3, CL_MAP_WRITE, planes * 3 * rs);
    if (out.intensity) {
      mi = std::make_unique<MappedBuffer>(q, *out.intensity, CL_MAP_WRITE, planes * n * n * rs);
      ms = std::make_unique<MappedBuffer>(q, *out.crop_sums, CL_MAP_WRITE, planes * rs);
    }
    Plane job;
    job.first = first;
    job.field = mf.as<C>();
    job.tf = mt.as<const C>();
    job.separable = tf.separable;
    job.klim = out.energy3 ? out.klim : nullptr;
    job.energy3 = me ? me->as<R>() : nullptr;
    job.intensity = mi ? mi->as<R>() : nullptr;
    job.crop_sums = ms ? ms->as<R>() : nullptr;
    std::unique_ptr<MappedBuffer> mg, mu, my, mss;
    if (in) {
      mg = std::make_unique<MappedBuffer>(q, *in->g_sensor, CL_MAP_READ, planes * in->s * in->s * rs);
      mu = std::make_unique<MappedBuffer>(q, *in->u, CL_MAP_READ, field_bytes);
      job.g = mg->as<const R>();
      job.u = mu->as<const C>();
      job.s = in->s;
      job.taps = in->taps;
      job.col_offset = in->col_offset;
      job.start = in->start;
      job.w = w_in.data();
      if (in->y_sensor) {
        my = std::make_unique<MappedBuffer>(q, *in->y_sensor, CL_MAP_READ, planes * in->s * in->s * rs);
        mss = std::make_unique<MappedBuffer>(q, *in->sensor_sums, CL_MAP_READ, planes * rs);
        job.y = my->as<const R>();
        job.sums = mss->as<const R>();
      }
    }

    std::atomic<std::size_t> next{first};
    const std::size_t end = first + count, workers = std::min(threads_, count);
    // Per-thread scratch allocated here, so that nothing in the worker threads can throw.
    std::vector<std::vector<R>> resampled(workers, std::vector<R>(in ? in->s : 0));
    auto work = [&](std::size_t t) {
      for (std::size_t b = next++; b < end; b = next++) plane(job, b, own_.rows[t], own_.cols[t], resampled[t].data());
    };
    std::vector<std::thread> pool;
    for (std::size_t t = 1; t < workers; ++t) pool.emplace_back(work, t);
    work(0);
    for (auto& th : pool) th.join();
  }

  struct Plane {
    std::size_t first = 0;  // the global plane held at field (and u) offset 0
    C* field = nullptr;
    const C* tf = nullptr;
    bool separable = true;
    const int* klim = nullptr;
    R* energy3 = nullptr;
    R* intensity = nullptr;
    R* crop_sums = nullptr;
    // IntensityAdjointInput, mapped (g null: the field's own block is the input).
    const R* g = nullptr;
    const C* u = nullptr;
    std::size_t s = 0, taps = 0, col_offset = 0;
    const int* start = nullptr;
    const R* w = nullptr;
    const R* y = nullptr;     // normalised sensor PSF and its sums (null: g is used as given)
    const R* sums = nullptr;
  };

  // The normalisation vjp's per-plane terms: g' = (g - <g, y>) / sum = a g + c with a = 1 / sum,
  // c = -<g, y> / sum (0 and 0 where sum <= 0, as normalize_vjp); <g, y> in double.
  void normalisation(const Plane& job, std::size_t b, R& a, R& c) const {
    a = 1;
    c = 0;
    if (!job.y) return;
    const std::size_t ss = job.s * job.s;
    const R* g = job.g + b * ss;
    const R* y = job.y + b * ss;
    double dot = 0;
    for (std::size_t i = 0; i < ss; ++i) dot += double(g[i]) * double(y[i]);
    const double sum = double(job.sums[b]);
    a = sum > 0 ? R(1.0 / sum) : R(0);
    c = sum > 0 ? R(-dot / sum) : R(0);
  }

  // Row y of plane b from an IntensityAdjointInput into row[0, N): the y-taps of g summed into
  // r (length S), then the x-taps of r, times 2 U.
  void adjoint_row(const Plane& job, std::size_t b, std::size_t y, C* row, R* r, R na, R nc) const {
    const std::size_t n = n_, m = m_, s = job.s, taps = job.taps;
    const std::ptrdiff_t last = std::ptrdiff_t(s) - 1;
    const auto clamp = [last](std::ptrdiff_t i) { return i < 0 ? 0 : i > last ? last : i; };
    const R* g = job.g + b * s * s;
    for (std::size_t x = 0; x < s; ++x) r[x] = 0;
    for (std::size_t ty = 0; ty < taps; ++ty) {
      const R wy = job.w[y * taps + ty];
      if (wy == R(0)) continue;
      const R* gr = g + std::size_t(clamp(std::ptrdiff_t(job.start[y]) + std::ptrdiff_t(ty))) * s;
      for (std::size_t x = 0; x < s; ++x) r[x] += wy * (na * gr[x] + nc);
    }
    const C* u = job.u + (b - job.first) * m * m + y * m;
    const R* wx = job.w + job.col_offset * taps;  // the columns' table (the rows' when col_offset = 0)
    const int* sx = job.start + job.col_offset;
    for (std::size_t x = 0; x < n; ++x) {
      R acc = 0;
      for (std::size_t tx = 0; tx < taps; ++tx)
        acc += wx[x * taps + tx] * r[clamp(std::ptrdiff_t(sx[x]) + std::ptrdiff_t(tx))];
      row[x][0] = R(2) * acc * u[x][0];
      row[x][1] = R(2) * acc * u[x][1];
    }
  }

  static void check_size(const char* what, const cl::Buffer& b, std::size_t bytes) {
    const std::size_t have = b.getInfo<CL_MEM_SIZE>();
    if (have < bytes) reject(what, std::to_string(have) + " bytes", ">= " + std::to_string(bytes) + " bytes");
  }

  // `count` in-place transforms of length M, contiguous, M apart (planned on a scratch array of
  // the same alignment as the per-thread arrays: both come from fftw_alloc).
  typename F::plan make(std::size_t count, int sign) {
    using D = std::conditional_t<std::is_same<R, float>::value, fftwf_iodim64, fftw_iodim64>;
    const std::ptrdiff_t mm = std::ptrdiff_t(m_);
    const D dim{mm, 1, 1};
    const D h{std::ptrdiff_t(count), mm, mm};
    C* scratch = count == 1 ? own_.rows[0] : own_.cols[0];
    typename F::plan p = F::guru(1, &dim, 1, &h, scratch, sign, FFTW_MEASURE);
    if (!p) throw DeviceError("FFTW could not plan the host propagation's " + std::to_string(m_) + "-point transforms");
    return p;
  }

  // The three passes of one plane (b), on this thread's row and column arrays.
  void plane(const Plane& job, std::size_t b, C* row, C* cols, R* resampled) const {
    const std::size_t m = m_, n = n_;
    const std::ptrdiff_t half = std::ptrdiff_t(m + 1) / 2;
    C* const P = job.field + (b - job.first) * m * m;
    const C* const T = job.tf + (job.separable ? b * m : b * m * m);
    // 1. Data rows, forward.
    R na = 1, nc = 0;
    if (job.g) normalisation(job, b, na, nc);
    for (std::size_t y = 0; y < n; ++y) {
      if (job.g)
        adjoint_row(job, b, y, row, resampled, na, nc);
      else
        std::memcpy(row, P + y * m, n * sizeof(C));
      std::memset(static_cast<void*>(row + n), 0, (m - n) * sizeof(C));
      F::execute(own_.row_fwd, row);
      std::memcpy(P + y * m, row, m * sizeof(C));
    }
    // 2. Column blocks: forward, transfer function (+ energies, 1/M² scale), inverse.
    const int lim = job.klim ? job.klim[b] : int(m);
    const auto beyond_index = [&](std::size_t k) {  // |f| > lim for FFT index k
      const std::ptrdiff_t f = std::ptrdiff_t(k) < half ? std::ptrdiff_t(k) : std::ptrdiff_t(k) - std::ptrdiff_t(m);
      return (f < 0 ? -f : f) > lim;
    };
    const R scale = R(1) / R(double(m) * double(m));
    const bool energies = job.energy3 != nullptr;  // the adjoint asks for none (loop-invariant branch)
    double tot = 0, beyond = 0, after = 0;
    for (std::size_t c0 = 0; c0 < m; c0 += kBlock) {
      const std::size_t nb = std::min(kBlock, m - c0);
      for (std::size_t y = 0; y < n; ++y) {
        const C* src = P + y * m + c0;
        for (std::size_t j = 0; j < nb; ++j) {
          cols[j * m + y][0] = src[j][0];
          cols[j * m + y][1] = src[j][1];
        }
      }
      for (std::size_t j = 0; j < nb; ++j) std::memset(static_cast<void*>(cols + j * m + n), 0, (m - n) * sizeof(C));
      if (nb < kBlock) std::memset(static_cast<void*>(cols + nb * m), 0, (kBlock - nb) * m * sizeof(C));
      F::execute(own_.col_fwd, cols);
      for (std::size_t j = 0; j < nb; ++j) {
        const std::size_t kx = c0 + j;
        C* col = cols + j * m;
        double ctot = 0, cbeyond = 0, cafter = 0;
        const bool col_beyond = job.klim && beyond_index(kx);
        if (job.klim && !col_beyond) {
          // The rows beyond the limit, |f| > lim in FFT order: ky in [lim + 1, half) and
          // [half, M - lim); summed before the transfer function overwrites the column.
          for (std::ptrdiff_t ky = std::max<std::ptrdiff_t>(lim + 1, 0); ky < half; ++ky)
            cbeyond += double(col[ky][0] * col[ky][0] + col[ky][1] * col[ky][1]);
          for (std::ptrdiff_t ky = half; ky < std::ptrdiff_t(m) - lim; ++ky)
            cbeyond += double(col[ky][0] * col[ky][0] + col[ky][1] * col[ky][1]);
        }
        if (job.separable) {
          const R txr = T[kx][0], txi = T[kx][1];
          for (std::size_t ky = 0; ky < m; ++ky) {
            const R vr = col[ky][0], vi = col[ky][1];
            const R tr = T[ky][0] * txr - T[ky][1] * txi, ti = T[ky][0] * txi + T[ky][1] * txr;
            const R wr = vr * tr - vi * ti, wi = vr * ti + vi * tr;
            if (energies) {
              ctot += double(vr * vr + vi * vi);
              cafter += double(wr * wr + wi * wi);
            }
            col[ky][0] = wr * scale;
            col[ky][1] = wi * scale;
          }
        } else {
          for (std::size_t ky = 0; ky < m; ++ky) {
            const R vr = col[ky][0], vi = col[ky][1];
            const R tr = T[ky * m + kx][0], ti = T[ky * m + kx][1];
            const R wr = vr * tr - vi * ti, wi = vr * ti + vi * tr;
            if (energies) {
              ctot += double(vr * vr + vi * vi);
              cafter += double(wr * wr + wi * wi);
            }
            col[ky][0] = wr * scale;
            col[ky][1] = wi * scale;
          }
        }
        if (col_beyond) cbeyond = ctot;
        tot += ctot;
        after += cafter;
        beyond += cbeyond;
      }
      F::execute(own_.col_bwd, cols);
      for (std::size_t y = 0; y < n; ++y) {
        C* dst = P + y * m + c0;
        for (std::size_t j = 0; j < nb; ++j) {
          dst[j][0] = cols[j * m + y][0];
          dst[j][1] = cols[j * m + y][1];
        }
      }
    }
    // 3. Data rows, inverse; the crop and its intensity.
    R* I = job.intensity ? job.intensity + b * n * n : nullptr;
    double crop = 0;
    for (std::size_t y = 0; y < n; ++y) {
      std::memcpy(row, P + y * m, m * sizeof(C));
      F::execute(own_.row_bwd, row);
      std::memcpy(P + y * m, row, n * sizeof(C));
      if (I) {
        // In double: the crop sum normalises the PSF, and a float sum of N values would put an
        // error of ~sqrt(N) eps on every sample (measured: 2.7e-6 against 3.6e-7 at N = 1024).
        for (std::size_t x = 0; x < n; ++x) {
          const R p = row[x][0] * row[x][0] + row[x][1] * row[x][1];
          I[y * n + x] = p;
          crop += double(p);
        }
      }
    }
    if (job.energy3) {
      job.energy3[3 * b] = R(tot);
      job.energy3[3 * b + 1] = R(beyond);
      job.energy3[3 * b + 2] = R(after);
    }
    if (job.crop_sums) job.crop_sums[b] = R(crop);
  }

  Runtime& rt_;
  std::size_t threads_ = 1;
  // Plans and per-thread arrays, freed by Owned's destructor (also when the constructor throws).
  struct Owned {
    std::vector<C*> rows, cols;
    typename F::plan row_fwd = nullptr, row_bwd = nullptr, col_fwd = nullptr, col_bwd = nullptr;
    Owned() = default;
    Owned(const Owned&) = delete;
    Owned& operator=(const Owned&) = delete;
    ~Owned() {
      const std::lock_guard<std::mutex> lock(planner_mutex());
      for (auto p : {row_fwd, row_bwd, col_fwd, col_bwd})
        if (p) F::destroy(p);
      for (C* a : rows) F::free(a);
      for (C* a : cols) F::free(a);
    }
  };
  Owned own_;
};

}  // namespace

std::unique_ptr<HostPropagator> make_host_propagator(Runtime& rt, std::size_t m, std::size_t n, std::size_t planes,
                                                     Precision p) {
  if (rt.info().type != "CPU")
    throw DeviceError("the host propagation maps device buffers on the host: it needs a CPU device, not " + rt.info().name);
  if (!(n > 0 && n < m)) reject("n", n, "0 < n < m = " + std::to_string(m) + " (a zero-padded field)");
  if (planes < 1) reject("planes", planes, ">= 1");
  rt.require(p);
  if (p == Precision::F64) return std::make_unique<FftwPropagator<double>>(rt, m, n, planes, p);
  return std::make_unique<FftwPropagator<float>>(rt, m, n, planes, p);
}

}  // namespace qdo
