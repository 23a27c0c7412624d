// FFTW backend of FftPlan for CPU OpenCL devices (see fft.hpp for the layout and conventions).
// A CPU device's buffers are host memory: run() maps the buffer (PoCL maps without copying; the
// in-order queue finishes the kernels before it), runs FFTW in place on the mapped pointer with
// the device's compute units as threads, scales the inverse, and unmaps. Plans are made with
// FFTW_MEASURE on a scratch array; the wisdom (what FFTW learnt) is kept in the kernel cache
// folder (fftw-wisdom-f32.txt / -f64.txt), so a size is measured once per machine. A wisdom file
// that FFTW cannot parse is ignored and rewritten.
//
// Pruning (FftZeroPad): the 2-D transform runs as two 1-D passes. Forward (input zero outside the
// data rectangle): the rows pass skips the rows of the zero row block (their transform is zero
// and they stay zero), then the columns pass runs over every column. Inverse (output defined only
// inside the rectangle): the rows pass runs over every row, then the columns pass only over the
// columns outside the zero column block, and only the rectangle is scaled.
#include <fftw3.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <mutex>
#include <thread>
#include <type_traits>
#include <vector>

#include <unistd.h>

#include "qdo/runtime/error.hpp"
#include "qdo/runtime/fft.hpp"
#include "runtime/fftw_internal.hpp"

namespace qdo {
namespace {

using fftw_detail::Fftw;
using fftw_detail::planner_mutex;

// One 1-D pass over one plane: `count` transforms of length n (stride `stride`, consecutive
// transforms `dist` apart), in place.
struct Pass {
  std::ptrdiff_t n = 0, stride = 1, count = 0, dist = 0;
};

template <typename R>
class FftwPlan final : public FftPlan {
  using F = Fftw<R>;
  using C = typename F::complex;

 public:
  FftwPlan(Runtime& rt, std::size_t rows, std::size_t cols, std::size_t batch, Precision p, const FftZeroPad& zp)
      : FftPlan(FftBackend::FFTW, rows, cols, batch, p, zp), rt_(rt) {
    const auto t0 = std::chrono::steady_clock::now();
    const std::ptrdiff_t r = std::ptrdiff_t(rows), c = std::ptrdiff_t(cols), pl = r * c;
    // Row blocks that carry data: [0, row_begin) and [row_end, rows) (all rows without a hint).
    const bool rows_hint = zp.row_end > zp.row_begin, cols_hint = zp.col_end > zp.col_begin;
    row_blocks_ = rows_hint ? blocks(zp.row_begin, zp.row_end, rows) : std::vector<Block>{{0, r}};
    col_blocks_ = cols_hint ? blocks(zp.col_begin, zp.col_end, cols) : std::vector<Block>{{0, c}};
    const int threads = int(std::max(1u, std::min(rt.info().compute_units, std::max(1u, std::thread::hardware_concurrency()))));
    const std::lock_guard<std::mutex> lock(planner_mutex());
    fftw_detail::init_threads_once();
    fftw_detail::load_wisdom<F>();
    // Scratch for FFTW_MEASURE (it overwrites the array): one plane.
    own_.scratch = F::alloc(std::size_t(pl));
    if (!own_.scratch) throw std::bad_alloc();
    F::threads(threads);
    make_all(0);
    F::threads(1);  // the host code's own FFTW plans (CPU references) stay single-threaded
    fftw_detail::save_wisdom<F>();
    align_ = F::alignment(reinterpret_cast<const R*>(own_.scratch));
    bake_seconds_ = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  }
 private:
  struct Block {
    std::ptrdiff_t begin = 0, len = 0;
  };
  static std::vector<Block> blocks(std::size_t zb, std::size_t ze, std::size_t n) {
    std::vector<Block> out;
    if (zb > 0) out.push_back({0, std::ptrdiff_t(zb)});
    if (ze < n) out.push_back({std::ptrdiff_t(ze), std::ptrdiff_t(n - ze)});
    return out;
  }
  // Rows pass (length cols, stride 1) and columns pass (length rows, stride cols), one plan per
  // block of rows or columns transformed: forward over the data rows then every column; inverse
  // over every row then the data columns.
  void make_all(unsigned extra) {
    const std::ptrdiff_t r = std::ptrdiff_t(rows()), c = std::ptrdiff_t(cols());
    auto& rows_p = extra ? own_.rows_u : own_.rows;
    auto& cols_p = extra ? own_.cols_u : own_.cols;
    for (const Block& b : row_blocks_) rows_p[0].push_back(make(Pass{c, 1, b.len, c}, FFTW_FORWARD, extra));
    cols_p[0].push_back(make(Pass{r, c, c, 1}, FFTW_FORWARD, extra));
    rows_p[1].push_back(make(Pass{c, 1, r, c}, FFTW_BACKWARD, extra));
    for (const Block& b : col_blocks_) cols_p[1].push_back(make(Pass{r, c, b.len, 1}, FFTW_BACKWARD, extra));
  }
  typename F::plan make(const Pass& p, int sign, unsigned extra = 0) {
    using D = std::conditional_t<std::is_same<R, float>::value, fftwf_iodim64, fftw_iodim64>;
    const D dim{p.n, p.stride, p.stride};
    const D h{p.count, p.dist, p.dist};
    typename F::plan plan = F::guru(1, &dim, 1, &h, own_.scratch, sign, FFTW_MEASURE | extra);
    if (!plan) throw DeviceError("FFTW could not plan a " + std::to_string(rows()) + " x " + std::to_string(cols()) + " pass");
    return plan;
  }
  // Unaligned variants, made on first use if a mapped pointer's SIMD alignment differs from the
  // scratch array's (FFTW's new-array execute requires the same alignment).
  void ensure_unaligned() {
    if (!own_.rows_u[0].empty()) return;
    const std::lock_guard<std::mutex> lock(planner_mutex());
    F::threads(threads_of());
    make_all(FFTW_UNALIGNED);
    F::threads(1);
  }
  int threads_of() const {
    return int(std::max(1u, std::min(rt_.info().compute_units, std::max(1u, std::thread::hardware_concurrency()))));
  }

  void run(cl::Buffer& data, bool fwd) override {
    auto& q = rt_.queue();
    const std::size_t n = bytes();
    void* ptr = q.enqueueMapBuffer(data, CL_TRUE, CL_MAP_READ | CL_MAP_WRITE, 0, n);
    try {
      C* base = static_cast<C*>(ptr);
      const std::ptrdiff_t c = std::ptrdiff_t(this->cols()), pl = std::ptrdiff_t(this->rows()) * c;
      const int d = fwd ? 0 : 1;
      for (std::size_t k = 0; k < batch(); ++k) {
        C* plane = base + std::ptrdiff_t(k) * pl;
        // New-array execution needs the planning array's SIMD alignment (odd plane sizes shift it).
        const bool aligned = F::alignment(reinterpret_cast<const R*>(plane)) == align_;
        if (!aligned) ensure_unaligned();
        auto& rows = aligned ? own_.rows : own_.rows_u;
        auto& cols = aligned ? own_.cols : own_.cols_u;
        if (fwd) {
          for (std::size_t i = 0; i < row_blocks_.size(); ++i) F::execute(rows[d][i], plane + row_blocks_[i].begin * c);
          F::execute(cols[d][0], plane);
        } else {
          F::execute(rows[d][0], plane);
          for (std::size_t i = 0; i < col_blocks_.size(); ++i) F::execute(cols[d][i], plane + col_blocks_[i].begin);
        }
      }
      if (!fwd) scale(base);
    } catch (...) {
      q.enqueueUnmapMemObject(data, ptr);
      throw;
    }
    q.enqueueUnmapMemObject(data, ptr);
  }
  // Inverse scaling 1/(rows*cols) over the data rectangle (the whole plane without a hint), on
  // the plan's threads.
  void scale(C* base) const {
    const R s = R(1) / R(double(rows()) * double(cols()));
    const std::ptrdiff_t c = std::ptrdiff_t(cols()), pl = std::ptrdiff_t(rows()) * c;
    std::vector<std::pair<std::ptrdiff_t, std::ptrdiff_t>> runs;  // (offset, length) in one plane
    for (const Block& rb : row_blocks_)
      for (std::ptrdiff_t y = rb.begin; y < rb.begin + rb.len; ++y)
        for (const Block& cb : col_blocks_) runs.push_back({y * c + cb.begin, cb.len});
    const std::ptrdiff_t planes = std::ptrdiff_t(batch());
    const int nt = std::min<int>(threads_of(), int(planes));
    auto work = [&](int t) {
      for (std::ptrdiff_t k = t; k < planes; k += nt)
        for (const auto& [off, len] : runs) {
          R* v = reinterpret_cast<R*>(base + k * pl + off);
          for (std::ptrdiff_t i = 0; i < 2 * len; ++i) v[i] *= s;
        }
    };
    std::vector<std::thread> pool;
    for (int t = 1; t < nt; ++t) pool.emplace_back(work, t);
    work(0);
    for (auto& th : pool) th.join();
  }

  Runtime& rt_;
  std::vector<Block> row_blocks_, col_blocks_;
  // The FFTW plans and the planning array, freed by Owned's destructor: also when the constructor
  // throws half-way (a member is destroyed then; ~FftwPlan would not run).
  struct Owned {
    std::vector<typename F::plan> rows[2], cols[2], rows_u[2], cols_u[2];
    C* scratch = nullptr;
    Owned() = default;
    Owned(const Owned&) = delete;
    Owned& operator=(const Owned&) = delete;
    ~Owned() {
      const std::lock_guard<std::mutex> lock(planner_mutex());
      for (auto* set : {rows, cols, rows_u, cols_u})
        for (int d = 0; d < 2; ++d)
          for (auto p : set[d]) F::destroy(p);
      if (scratch) F::free(scratch);
    }
  };
  Owned own_;
  int align_ = 0;
};

}  // namespace

std::string fftw_library_version() { return fftw_version; }

namespace fftw_detail {
std::mutex& planner_mutex() {
  static std::mutex m;
  return m;
}
void init_threads_once() {
  static std::once_flag once;
  std::call_once(once, [] {
    Fftw<float>::init_threads();
    Fftw<double>::init_threads();
  });
}
std::filesystem::path wisdom_file(const char* tag) {
  const std::filesystem::path dir = kernel_cache_dir();
  if (dir.empty()) return {};
  return dir / (std::string("fftw-wisdom-") + tag + ".txt");
}
void save_wisdom_file(const std::filesystem::path& wf, int (*export_fn)(const char*)) {
  if (wf.empty()) return;
  std::error_code ec;
  std::filesystem::create_directories(wf.parent_path(), ec);
  const std::string tmp = wf.string() + ".tmp-" + std::to_string(long(::getpid()));
  if (!ec && export_fn(tmp.c_str())) std::filesystem::rename(tmp, wf, ec);
  std::filesystem::remove(tmp, ec);
}
}  // namespace fftw_detail

namespace detail {
std::unique_ptr<FftPlan> make_fftw_plan(Runtime& rt, std::size_t rows, std::size_t cols, std::size_t batch, Precision p,
                                        const FftZeroPad& zero_pad) {
  if (p == Precision::F64) return std::make_unique<FftwPlan<double>>(rt, rows, cols, batch, p, zero_pad);
  return std::make_unique<FftwPlan<float>>(rt, rows, cols, batch, p, zero_pad);
}
}  // namespace detail

}  // namespace qdo
