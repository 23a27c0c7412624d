// Stability suite (issue 6): the legal extremes of the configuration, checked for invariants
// rather than "no crash"; long runs; hostile input to every reader; device faults; interrupted
// runs. The envelope, the invariants and the known limits are in STABILITY.md.
//
// Cases whose name ends in "[slow]" run under the CTest label "stress" (ctest -L stress);
// the others with the default label (CTest entry "stress-quick").
#include <fcntl.h>
#include <hdf5.h>
#include <matio.h>
#include <png.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>
#include <zlib.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <limits>
#include <map>
#include <memory>
#include <numeric>
#include <random>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "common.hpp"
#include "qdo/run_folder.hpp"
#include "qdo/adjoint.hpp"
#include "qdo/cpu_reference.hpp"
#include "qdo/datasets.hpp"
#include "qdo/design.hpp"
#include "qdo/design_run.hpp"
#include "qdo/doe.hpp"
#include "qdo/error.hpp"
#include "qdo/io.hpp"
#include "qdo/optics.hpp"
#include "qdo/run.hpp"
#include "qdo/simulator.hpp"

extern char** environ;

using namespace qdo;
using namespace qdo::test;
namespace fs = std::filesystem;

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

// ---------------------------------------------------------------------------------------
// Configurations at the extremes
// ---------------------------------------------------------------------------------------

// tiny_config(n, bands) with the given pitch, scene distance (kInf: plane wave) and sensor
// distance; the sensor pitch is twice the DOE pitch (S = N/2).
SystemConfig extreme_config(std::size_t n, double pitch_m, double scene_m, double sensor_m, std::size_t bands = 3) {
  SystemConfig c = tiny_config(n, bands);
  c.pitch_m = pitch_m;
  c.sensor_pitch_m = 2 * pitch_m;
  c.scene_at_infinity = std::isinf(scene_m);
  c.scene_distance_m = scene_m;
  c.sensor_distance_m = sensor_m;
  c.read_noise_sigma = 0;
  c.validate();
  return c;
}

std::string describe(const SystemConfig& c) {
  return "n=" + to_str(c.n) + " pitch=" + to_str(c.pitch_m) + " d=" + (c.scene_at_infinity ? std::string("inf") : to_str(c.scene_distance_m)) +
         " z=" + to_str(c.sensor_distance_m) + " bands=" + to_str(c.bands) + " pad=" + to_str(c.padding_px) +
         (c.propagator == Propagator::AngularSpectrum ? " asm" : " fresnel");
}

// Every plane finite, non-negative and summing to 1 within sum_tol.
void check_unit_planes(const RealStack& s, double sum_tol, const std::string& what) {
  CAPTURE(what);
  bool finite = true, nonneg = true;
  double worst = 0;
  for (std::size_t p = 0; p < s.planes; ++p) {
    double sum = 0;
    for (std::size_t i = 0; i < s.plane_size(); ++i) {
      const double v = s.plane(p)[i];
      finite = finite && std::isfinite(v);
      nonneg = nonneg && v >= 0;
      sum += v;
    }
    worst = std::max(worst, std::fabs(sum - 1));
  }
  CHECK(finite);
  CHECK(nonneg);
  CAPTURE(worst);
  CHECK(worst <= sum_tol);
}

bool all_finite(const std::vector<double>& v) {
  return std::all_of(v.begin(), v.end(), [](double x) { return std::isfinite(x); });
}

double rel_l2(const std::vector<double>& a, const std::vector<double>& b) { return diff(a, b).rel_l2; }

double dot(const std::vector<double>& a, const std::vector<double>& b) {
  REQUIRE(a.size() == b.size());
  return std::inner_product(a.begin(), a.end(), b.begin(), 0.0);
}

RealStack random_stack(std::size_t p, std::size_t r, std::size_t c, unsigned seed, double lo = -1, double hi = 1) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(lo, hi);
  RealStack s(p, r, c);
  for (double& v : s.data) v = u(rng);
  return s;
}

// Energy of the propagated field inside the central N x N crop and in the whole window, per band.
void window_energies(const ComplexStack& f, const PropagationGeometry& g, std::vector<double>& crop, std::vector<double>& total) {
  crop.assign(f.planes, 0.0);
  total.assign(f.planes, 0.0);
  for (std::size_t b = 0; b < f.planes; ++b)
    for (std::size_t i = 0; i < f.rows; ++i)
      for (std::size_t j = 0; j < f.cols; ++j) {
        const double e = std::norm(f(b, i, j));
        total[b] += e;
        if (i >= g.offset && i < g.offset + g.n && j >= g.offset && j < g.offset + g.n) crop[b] += e;
      }
}

// Heights of a blazed grating at the base wavelength: a linear phase ramp of `cycles_per_m`
// along x, wrapped into [0, h_max) (at 700 nm exactly a tilted plane wave).
Map2D blazed_grating(const SystemConfig& c, double cycles_per_m) {
  Map2D h(c.n, c.n);
  const double hmax = c.h_max_m();
  for (std::size_t i = 0; i < c.n; ++i)
    for (std::size_t j = 0; j < c.n; ++j) {
      const double x = (double(j) - double(c.n / 2)) * c.pitch_m;
      const double ph = x * cycles_per_m;
      h(i, j) = hmax * (ph - std::floor(ph));
    }
  return h;
}

// <g, psf_sensor(H)> and its gradient direction check: directional central difference of the
// CPU reference (double) along dh against <vjp(g), dh>. Returns |fd - an| / max(|an|, floor).
double directional_fd_error(const SystemConfig& c, const Map2D& h, const RealStack& g, const Map2D& grad, unsigned seed,
                            double step_m) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  Map2D dh(c.n, c.n);
  for (double& v : dh.data) v = u(rng);
  Map2D a = h, b = h;
  for (std::size_t i = 0; i < h.data.size(); ++i) {
    a.data[i] += step_m * dh.data[i];
    b.data[i] -= step_m * dh.data[i];
  }
  const double fd = (dot(g.data, ref::psf_sensor_stack(c, a).data) - dot(g.data, ref::psf_sensor_stack(c, b).data)) / (2 * step_m);
  const double an = dot(grad.data, dh.data);
  CAPTURE(fd);
  CAPTURE(an);
  return std::fabs(fd - an) / std::max(std::fabs(an), 1e-30);
}

// ---------------------------------------------------------------------------------------
// Files
// ---------------------------------------------------------------------------------------

std::string slurp(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}
void spit(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out << bytes;
  REQUIRE(out.good());
}

// The InputError message of f(), or "" when f succeeds; any other exception fails the test
// (doctest reports it).
template <typename F>
std::string input_error(F&& f) {
  try {
    f();
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}
bool has(const std::string& s, const std::string& part) { return s.find(part) != std::string::npos; }

// Runs `reader` on truncations of `good` at many lengths and on copies with bytes flipped at
// many positions (deterministic): each either succeeds (then `accept` checks the result) or
// throws an InputError naming the file. Returns how many variants were rejected.
std::size_t mutate_and_read(const std::string& path, const std::string& good, const std::function<void()>& reader,
                            std::size_t variants = 96) {
  std::size_t rejected = 0;
  std::mt19937_64 rng(1234);
  for (std::size_t k = 0; k < variants; ++k) {
    std::string bad = good;
    if (k % 2 == 0) {
      bad.resize(good.size() * k / variants);  // truncated (0 .. almost all of it)
    } else {
      const std::size_t flips = 1 + k % 7;
      for (std::size_t f = 0; f < flips; ++f) bad[rng() % bad.size()] = static_cast<char>(rng() & 0xff);
    }
    spit(path, bad);
    const std::string err = input_error(reader);
    if (!err.empty()) {
      ++rejected;
      CAPTURE(k);
      CAPTURE(err);
      CHECK(has(err, path));
    }
  }
  return rejected;
}

struct MatCloser {
  void operator()(mat_t* m) const { Mat_Close(m); }
};
struct MatVarFreer {
  void operator()(matvar_t* v) const { Mat_VarFree(v); }
};
template <typename T>
void write_mat(const std::string& path, mat_ft ver, const std::string& name, std::vector<std::size_t> dims, matio_classes cls,
               matio_types type, std::vector<T> data, matio_compression comp = MAT_COMPRESSION_NONE) {
  std::unique_ptr<mat_t, MatCloser> m(Mat_CreateVer(path.c_str(), nullptr, ver));
  REQUIRE(m);
  std::unique_ptr<matvar_t, MatVarFreer> v(
      Mat_VarCreate(name.c_str(), cls, type, int(dims.size()), dims.data(), data.data(), MAT_F_DONT_COPY_DATA));
  REQUIRE(v);
  REQUIRE(Mat_VarWrite(m.get(), v.get(), comp) == 0);
}

void write_png_gray(const std::string& path, std::uint32_t w, std::uint32_t h, bool sixteen) {
  png_image img;
  std::memset(&img, 0, sizeof img);
  img.version = PNG_IMAGE_VERSION;
  img.width = w;
  img.height = h;
  img.format = sixteen ? PNG_FORMAT_LINEAR_Y : PNG_FORMAT_GRAY;
  std::vector<std::uint16_t> px(std::size_t(w) * h);
  for (std::size_t i = 0; i < px.size(); ++i) px[i] = static_cast<std::uint16_t>((i * 2654435761u) & (sixteen ? 0xffff : 0xff));
  std::vector<std::uint8_t> px8(px.begin(), px.end());
  const int ok = png_image_write_to_file(&img, path.c_str(), 0, sixteen ? static_cast<const void*>(px.data()) : px8.data(), 0, nullptr);
  png_image_free(&img);
  REQUIRE(ok);
}

std::uint32_t crc32(const unsigned char* p, std::size_t n) {
  std::uint32_t c = 0xffffffffu;
  for (std::size_t i = 0; i < n; ++i) {
    c ^= p[i];
    for (int k = 0; k < 8; ++k) c = (c >> 1) ^ (0xedb88320u & (0u - (c & 1u)));
  }
  return c ^ 0xffffffffu;
}

// A PNG whose IHDR declares width x height (gray 16-bit) followed by a tiny IDAT and IEND,
// with valid CRCs: a header that promises far more pixels than the file holds.
std::string png_claiming(std::uint32_t width, std::uint32_t height) {
  std::string s("\x89PNG\r\n\x1a\n", 8);
  auto be32 = [](std::uint32_t v) {
    std::string b(4, '\0');
    for (int i = 0; i < 4; ++i) b[std::size_t(i)] = char((v >> (24 - 8 * i)) & 0xff);
    return b;
  };
  auto chunk = [&](const std::string& type, const std::string& data) {
    std::string body = type + data;
    s += be32(std::uint32_t(data.size())) + body +
         be32(crc32(reinterpret_cast<const unsigned char*>(body.data()), body.size()));
  };
  std::string ihdr = be32(width) + be32(height);
  ihdr += std::string("\x10\x00\x00\x00\x00", 5);  // bit depth 16, gray, deflate, filter 0, no interlace
  chunk("IHDR", ihdr);
  chunk("IDAT", std::string("\x78\x9c\x63\x00\x00\x00\x01\x00\x01", 9));  // zlib stream of one zero byte
  chunk("IEND", "");
  return s;
}

// ---------------------------------------------------------------------------------------
// Child processes (the qdo binary)
// ---------------------------------------------------------------------------------------

class Child {
 public:
  Child(const std::vector<std::string>& args, const std::string& log) {
    std::vector<char*> argv;
    for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_addopen(&fa, 1, log.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
    posix_spawn_file_actions_addopen(&fa, 2, log.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
    const int rc = posix_spawn(&pid_, argv[0], &fa, nullptr, argv.data(), environ);
    posix_spawn_file_actions_destroy(&fa);
    REQUIRE(rc == 0);
  }
  Child(const Child&) = delete;
  Child& operator=(const Child&) = delete;
  ~Child() {
    if (pid_ > 0) {
      ::kill(pid_, SIGKILL);
      wait();
    }
  }
  bool running() {
    if (pid_ <= 0) return false;
    int st = 0;
    const pid_t r = ::waitpid(pid_, &st, WNOHANG);
    if (r == pid_) {
      status_ = st;
      pid_ = -1;
      return false;
    }
    return true;
  }
  void kill9() {
    if (pid_ > 0) ::kill(pid_, SIGKILL);
    wait();
  }
  int wait() {
    if (pid_ > 0) {
      int st = 0;
      ::waitpid(pid_, &st, 0);
      status_ = st;
      pid_ = -1;
    }
    return status_;
  }
  int exit_code() { return WIFEXITED(wait()) ? WEXITSTATUS(status_) : -1; }
  pid_t pid() const { return pid_; }

 private:
  pid_t pid_ = -1;
  int status_ = 0;
};

// True when the checkpoint at `path` reads and holds a step other than `before` (a file that
// does not read is a failure of the atomic writes and is reported by the caller's checks).
bool load_checkpoint_step_changed(const std::string& path, long before) {
  try {
    return load_checkpoint(path, 16, 4).step != before;
  } catch (const InputError& e) {
    FAIL_CHECK("checkpoint unreadable while the run was going: " << e.what());
    return true;
  }
}


// ---------------------------------------------------------------------------------------
// Sweep folders (section 5): the smallest `qdo sweep` that trains two runs (do, and qdo at
// L = 2) past a checkpoint (12 steps each, checkpoints at steps 10 and 12) and evaluates three
// cells (full, do_L2, qdo_L2).
// ---------------------------------------------------------------------------------------

std::vector<std::string> sweep_args(const std::string& cfg, const std::string& out, const std::string& epochs = "4") {
  return {QDO_QDO_BINARY, "sweep", "--config", cfg, "--grid", "levels=2", "--grid", "mode=do,qdo", "--epochs", epochs,
          "--steps-per-epoch", "3", "--t0", "1", "--t1", "3", "--synthetic-scenes", "3", "--eval-scenes", "2", "--seed", "5",
          "--out", out};
}
std::string sweep_config_file(const fs::path& dir) {
  const std::string cfg = (dir / "cfg.json").string();
  write_text_atomic(cfg, config_to_json_text(tiny_config(32, 3)));
  return cfg;
}

// table1.csv and table2.csv of a sweep folder, parsed, as text without the `inputs` column (a
// hash of the files' paths and bytes, so it differs between folders; the values must not).
std::string sweep_table_values(const fs::path& out) {
  std::string text;
  for (const char* name : {"table1.csv", "table2.csv"}) {
    const CsvTable t = read_csv((out / name).string());
    REQUIRE(!t.raw.empty());
    text += std::string(name) + ":";
    for (std::size_t r = 0; r < t.raw[0].size(); ++r) {
      for (std::size_t c = 0; c < t.header.size(); ++c)
        if (t.header[c] != "inputs") text += t.raw[c][r] + ",";
      text += "\n";
    }
  }
  return text;
}

// Every file under `dir` with its size and modification time (to show that nothing changed).
std::map<std::string, std::pair<std::uintmax_t, fs::file_time_type>> folder_listing(const fs::path& dir) {
  std::map<std::string, std::pair<std::uintmax_t, fs::file_time_type>> m;
  for (const auto& e : fs::recursive_directory_iterator(dir))
    if (e.is_regular_file()) m[fs::relative(e.path(), dir).string()] = {e.file_size(), e.last_write_time()};
  return m;
}
std::size_t temp_files(const fs::path& dir) {
  std::size_t n = 0;
  for (const auto& e : fs::recursive_directory_iterator(dir))
    if (e.path().filename().string().find(".tmp-") != std::string::npos) ++n;
  return n;
}

// The uninterrupted sweep the workflow cases compare with, made once per test binary.
struct ReferenceSweep {
  fs::path dir, cfg, out;
  std::string values;
  double seconds = 0;
  ~ReferenceSweep() {
    std::error_code ec;
    if (!dir.empty()) fs::remove_all(dir, ec);
  }
};
const ReferenceSweep& reference_sweep() {
  static ReferenceSweep r;
  if (r.values.empty()) {
    r.dir = temp_dir("stress_sweep_ref");
    r.cfg = sweep_config_file(r.dir);
    r.out = r.dir / "ref";
    const auto t0 = std::chrono::steady_clock::now();
    Child c(sweep_args(r.cfg.string(), r.out.string()), (r.dir / "log.txt").string());
    const int code = c.exit_code();
    r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    INFO(slurp((r.dir / "log.txt").string()));
    REQUIRE(code == 0);
    r.values = sweep_table_values(r.out);
  }
  return r;
}

}  // namespace

TEST_SUITE("stress") {
  // =====================================================================================
  // 1. Numerical extremes
  // =====================================================================================

  TEST_CASE("distance, pitch and sensor-distance extremes: finite unit-sum PSFs, energy accounted, f32 ~ f64, honest reports") {
    // N = 32 (M = 48), 3 bands 450..550 nm, a lens and random heights. Scene 0.05 m .. 1 km and
    // infinity; sensor 1 mm .. 1 m; pitch 0.5 .. 20 um: 36 geometries x 2 designs x 2 precisions.
    REQUIRE(runtime().has_fp64());
    double worst_f32 = 0, worst_ref = 0;
    std::size_t flagged = 0, total = 0;
    for (double pitch : {0.5e-6, 4e-6, 20e-6})
      for (double d : {0.05, 1.0, 1000.0, kInf})
        for (double z : {1e-3, 0.03, 1.0}) {
          const SystemConfig c = extreme_config(32, pitch, d, z);
          CAPTURE(describe(c));
          Simulator s64(runtime(), c, Precision::F64), s32(runtime(), c, Precision::F32);
          for (int design = 0; design < 2; ++design) {
            CAPTURE(design);
            const Map2D h = design == 0 ? lens_design(c, 500) : random_heights(c.n, c.h_max_m(), 17);
            s64.set_heights(h);
            s32.set_heights(h);
            s64.compute_psf();
            s32.compute_psf();
            const RealStack p64 = s64.psf_sensor(), p32 = s32.psf_sensor();
            check_unit_planes(s64.psf_native(), 1e-12, "f64 native");
            check_unit_planes(p64, 1e-12, "f64 sensor");
            check_unit_planes(s32.psf_native(), 2e-5, "f32 native");
            check_unit_planes(p32, 2e-5, "f32 sensor");
            // float32 vs float64: relative L2 over the stack (bound stated in STABILITY.md).
            const double e32 = rel_l2(p32.data, p64.data);
            worst_f32 = std::max(worst_f32, e32);
            CAPTURE(e32);
            CHECK(e32 <= 1e-5);
            // float64 kernels vs the double CPU reference.
            const double er = rel_l2(p64.data, ref::psf_sensor_stack(c, h).data);
            worst_ref = std::max(worst_ref, er);
            CHECK(er <= 1e-9);
            // Energy: the Fresnel transfer function is unitary (Parseval), and the reported
            // energy outside the N x N window equals what the field itself says.
            const SamplingReport rep = s64.sampling(), rep32 = s32.sampling();  // copies: the debug calls below redo the stages
            const ComplexStack before = s64.debug_field_after_doe();
            const ComplexStack after = s64.debug_field_after_propagation();
            std::vector<double> crop0, tot0, crop1, tot1;
            window_energies(before, s64.geometry(), crop0, tot0);
            window_energies(after, s64.geometry(), crop1, tot1);
            REQUIRE(rep.bands.size() == c.bands);
            for (std::size_t b = 0; b < c.bands; ++b) {
              CAPTURE(b);
              CHECK(std::fabs(tot1[b] - tot0[b]) <= 1e-10 * tot0[b]);
              const BandSampling& bs = rep.bands[b];
              CHECK(bs.aliased_energy_fraction >= 0);
              CHECK(bs.aliased_energy_fraction <= 1 + 1e-12);
              CHECK(bs.energy_outside_window == doctest::Approx(1 - crop1[b] / tot1[b]).epsilon(1e-9).scale(1));
              CHECK(rep32.bands[b].energy_outside_window == doctest::Approx(bs.energy_outside_window).epsilon(1e-4).scale(1));
              CHECK(rep32.bands[b].aliased_energy_fraction == doctest::Approx(bs.aliased_energy_fraction).epsilon(1e-4).scale(1));
            }
            // The tool says so: an inaccurate configuration is refused in strict mode, and only then.
            ++total;
            SystemConfig strict = c;
            strict.strict_sampling = true;
            Simulator ss(runtime(), strict, Precision::F64);
            ss.set_heights(h);
            if (rep.any_inaccurate()) {
              ++flagged;
              CHECK(has(rep.summary(), "INACCURATE"));
              CHECK_THROWS_WITH_AS(ss.compute_psf(), doctest::Contains("under-sampled"), AccuracyError);
            } else {
              CHECK_NOTHROW(ss.compute_psf());
            }
            // Adjoint: finite for a random cotangent, in both precisions.
            const RealStack g = random_stack(c.bands, s64.sensor_size(), s64.sensor_size(), 5);
            CHECK(all_finite(s64.psf_sensor_vjp(g).data));
            CHECK(all_finite(s32.psf_sensor_vjp(g).data));
          }
        }
    MESSAGE("worst f32 vs f64 " << worst_f32 << ", worst f64 vs CPU reference " << worst_ref << "; " << flagged << " of "
                                << total << " cases flagged inaccurate");
    CHECK(flagged > 0);          // the sweep does reach the under-sampled corner
    CHECK(flagged < total);      // and the well-sampled one
  }

  TEST_CASE("the angular-spectrum propagator at the extremes: unit-sum PSFs, f32 ~ f64, energy only removed") {
    REQUIRE(runtime().has_fp64());
    for (double pitch : {0.5e-6, 20e-6})
      for (double z : {1e-3, 1.0}) {
        SystemConfig c = extreme_config(32, pitch, kInf, z);
        c.propagator = Propagator::AngularSpectrum;
        CAPTURE(describe(c));
        Simulator s64(runtime(), c, Precision::F64), s32(runtime(), c, Precision::F32);
        const Map2D h = random_heights(c.n, c.h_max_m(), 3);
        s64.set_heights(h);
        s32.set_heights(h);
        s64.compute_psf();
        s32.compute_psf();
        check_unit_planes(s64.psf_sensor(), 1e-12, "asm f64");
        check_unit_planes(s32.psf_sensor(), 2e-5, "asm f32");
        CHECK(rel_l2(s32.psf_sensor().data, s64.psf_sensor().data) <= 2e-4);
        std::vector<double> c0, t0, c1, t1;
        window_energies(s64.debug_field_after_doe(), s64.geometry(), c0, t0);
        window_energies(s64.debug_field_after_propagation(), s64.geometry(), c1, t1);
        for (std::size_t b = 0; b < c.bands; ++b) {
          // The band limit and the evanescent cut remove energy; nothing adds it.
          CHECK(t1[b] <= t0[b] * (1 + 1e-10));
          CHECK(t1[b] > 0);
        }
      }
  }

  TEST_CASE("heights at 0, at h_max and straddling the phase wrap") {
    // Bands 500, 600, 700 nm: at 700 nm (the base wavelength) h_max is exactly one 2pi phase.
    SystemConfig c = extreme_config(32, 4e-6, 1.0, 1.5625e-3);
    c.wavelength_start_nm = 500;
    c.wavelength_step_nm = 100;
    c.validate();
    const double hmax = c.h_max_m();
    for (Precision p : {Precision::F32, Precision::F64}) {
      CAPTURE(to_string(p));
      const double tol = p == Precision::F64 ? 1e-12 : 2e-5;
      Simulator sim(runtime(), c, p);
      // Any constant height is a constant phase: the PSF of H = 0, h_max and 2 h_max is the
      // same in every band.
      sim.set_heights(Map2D(c.n, c.n, 0.0));
      sim.compute_psf();
      const RealStack flat0 = sim.psf_sensor();
      check_unit_planes(flat0, tol, "H = 0");
      for (double level : {hmax, 2 * hmax, 0.37 * hmax}) {
        sim.set_heights(Map2D(c.n, c.n, level));
        sim.compute_psf();
        CHECK(rel_l2(sim.psf_sensor().data, flat0.data) <= (p == Precision::F64 ? 1e-12 : 3e-6));
      }
      // Straddling the wrap: H and H - h_max (for H > h_max) differ by 2pi at 700 nm only.
      Map2D up = random_heights(c.n, 2e-9, 9), wrapped(c.n, c.n);
      for (std::size_t i = 0; i < up.data.size(); ++i) {
        up.data[i] += hmax - 1e-9;  // h_max - 1 nm .. h_max + 1 nm
        wrapped.data[i] = up.data[i] >= hmax ? up.data[i] - hmax : up.data[i];
      }
      sim.set_heights(up);
      sim.compute_psf();
      const RealStack a = sim.psf_sensor();
      sim.set_heights(wrapped);
      sim.compute_psf();
      const RealStack b = sim.psf_sensor();
      check_unit_planes(a, tol, "straddling");
      const std::size_t plane = a.plane_size();
      const std::vector<double> a700(a.plane(2), a.plane(2) + plane), b700(b.plane(2), b.plane(2) + plane);
      CHECK(rel_l2(a700, b700) <= (p == Precision::F64 ? 1e-10 : 5e-6));
      // Out of range: rejected before any device work, naming the sample.
      Map2D bad(c.n, c.n, 0.0);
      bad(3, 4) = 2 * hmax * (1 + 1e-9);
      CHECK_THROWS_WITH_AS(sim.set_heights(bad), doctest::Contains("height_m[3][4]"), InputError);
      bad(3, 4) = -1e-15;
      CHECK_THROWS_AS(sim.set_heights(bad), InputError);
      bad(3, 4) = std::nan("");
      CHECK_THROWS_AS(sim.set_heights(bad), InputError);
    }
  }

  TEST_CASE("quantizer extremes: L = 2 .. 256, offsets at their clip limits, exact decision boundaries") {
    const SystemConfig c = extreme_config(32, 4e-6, 1.0, 1.5625e-3);
    const double hmax = c.h_max_m();
    Simulator sim(runtime(), c, Precision::F64);
    for (int levels : {2, 3, 4, 8, 16, 64, 256})
      for (Placement pl : {Placement::Inclusive, Placement::Wrapped})
        for (int mode = 0; mode < 4; ++mode) {
          Quantizer q;
          q.levels = levels;
          q.placement = pl;
          const double lim = levels == 2 ? 0.2 : 1.0;
          if (mode > 0) {
            q.offsets.assign(std::size_t(levels), 0.0);
            for (int l = 1; l < levels; ++l)
              q.offsets[std::size_t(l)] = mode == 1 ? lim : mode == 2 ? -lim : (l % 2 ? lim : -lim);
          }
          CAPTURE(levels);
          CAPTURE(to_string(pl));
          CAPTURE(mode);
          REQUIRE_NOTHROW(q.validate());
          const auto lv = q.level_heights_m(hmax);
          for (double v : lv) {
            CHECK(v >= 0);
            CHECK(v <= 2 * hmax);  // set_heights' range, so every fabricated design can be simulated
          }
          // Parameters on the radial grid: random, the ends, and exact decision boundaries
          // u = (k + 0.5) / (L - 1) (inclusive) or (k + 0.5) / L (wrapped), where rounding ties.
          std::vector<double> params(parameter_count(Parameterization::Radial, c.n));
          std::mt19937_64 rng(std::uint64_t(levels) * 7 + std::uint64_t(mode));
          const double denom = pl == Placement::Inclusive ? levels - 1 : levels;
          for (std::size_t i = 0; i < params.size(); ++i) {
            const double u = i == 0 ? 0.0 : i == 1 ? 1.0 : i % 3 == 0 ? (double(rng() % std::uint64_t(levels)) + 0.5) / denom
                                                                      : double(rng() >> 11) * 0x1.0p-53;
            params[i] = std::min(1.0, u) * hmax;
          }
          const Map2D hf = expand_parameters(Parameterization::Radial, params, c.n, hmax);
          for (double alpha : {0.0, 0.5, 1.0}) {
            const Map2D host = quantize_heights(hf, hmax, q, alpha);
            sim.set_design(Parameterization::Radial, params, &q, alpha);
            const Map2D dev = sim.heights();
            CHECK(diff(dev.data, host.data).max_abs <= 4e-16 * hmax * levels);
          }
          const Map2D fab = quantize_heights(hf, hmax, q, 1.0);
          const std::set<double> distinct(fab.data.begin(), fab.data.end());
          CHECK(distinct.size() <= std::size_t(levels));
          sim.set_heights(fab);
          sim.compute_psf();
          check_unit_planes(sim.psf_sensor(), 1e-12, "quantized");
          // Offsets gradient at the clip limits against central differences (smooth in a_l).
          const Map2D g = random_heights(c.n, 1.0, 11);
          const auto vjp = ref::quantize_vjp(hf, hmax, q, 0.7, g);
          CHECK(all_finite(vjp.g_offsets));
          if (mode > 0)
            for (int l = 1; l < levels; l += std::max(1, levels / 5)) {
              // One-sided difference from the limit inward (the map is linear in a_l).
              Quantizer a = q;
              const double step = q.offsets[std::size_t(l)] > 0 ? -1e-6 : 1e-6;
              a.offsets[std::size_t(l)] += step;
              const double l0 = dot(g.data, quantize_heights(hf, hmax, q, 0.7).data);
              const double l1 = dot(g.data, quantize_heights(hf, hmax, a, 0.7).data);
              CAPTURE(l);
              CHECK(std::fabs((l1 - l0) / step - vjp.g_offsets[std::size_t(l)]) <= 1e-6 * (1 + std::fabs(vjp.g_offsets[std::size_t(l)])));
            }
        }
  }

  TEST_CASE("1 to 301 spectral samples (srf_interpolate): unit PSFs, a flat spectrum stays flat") {
    for (std::size_t bands : {1ul, 2ul, 31ul, 301ul}) {
      SystemConfig c = extreme_config(32, 4e-6, 1.0, 1.5625e-3, bands);
      c.wavelength_start_nm = 400;
      c.wavelength_step_nm = bands > 1 ? 300.0 / double(bands - 1) : 1.0;
      c.srf_interpolate = true;
      c.validate();
      CAPTURE(bands);
      const Eigen::MatrixXd srf = sensor_response(c);
      for (int r = 0; r < 3; ++r) CHECK(srf.row(r).sum() == doctest::Approx(1).epsilon(1e-12));
      for (Precision p : {Precision::F32, Precision::F64}) {
        Simulator sim(runtime(), c, p);
        sim.set_heights(random_heights(c.n, c.h_max_m(), 4));
        sim.compute_psf();
        check_unit_planes(sim.psf_sensor(), p == Precision::F64 ? 1e-12 : 2e-5, "bands");
        CHECK(sim.sampling().bands.size() == bands);
        // Eq. 7: a flat spectrum of 0.25 integrates to 0.25 in every channel.
        const RealStack flat(bands, 5, 4, 0.25);
        const RealStack rgb = sim.integrate(flat);
        for (double v : rgb.data) CHECK(v == doctest::Approx(0.25).epsilon(p == Precision::F64 ? 1e-12 : 1e-5));
      }
    }
    SystemConfig c = tiny_config(32, 1);
    c.bands = 1002;
    CHECK_THROWS_WITH_AS(c.validate(), doctest::Contains("'bands'"), InputError);
  }

  TEST_CASE("a PSF with almost no energy on the sensor: still finite and normalised, and the report says where the light went") {
    // A blazed grating at 700 nm (one band, plane wave) steers the light 2 N pitch off axis,
    // into the padding (padding 2N per side, z chosen so the grating and the chirp are sampled).
    SystemConfig c = extreme_config(32, 4e-6, kInf, 3.2e-3, 1);
    c.wavelength_start_nm = 700;
    c.padding_px = 64;
    c.validate();
    const double shift_m = 2.0 * double(c.n) * c.pitch_m;
    const Map2D h = blazed_grating(c, shift_m / (700e-9 * c.sensor_distance_m));
    Simulator s64(runtime(), c, Precision::F64), s32(runtime(), c, Precision::F32);
    s64.set_heights(h);
    s32.set_heights(h);
    s64.compute_psf();
    s32.compute_psf();
    const double outside = s64.sampling().bands[0].energy_outside_window;
    CAPTURE(outside);
    CHECK(outside > 0.998);  // the report: almost everything missed the N x N window
    CHECK(has(s64.sampling().summary(), "outside the N x N window"));
    check_unit_planes(s64.psf_native(), 1e-12, "dim f64");
    check_unit_planes(s32.psf_native(), 2e-5, "dim f32");
    check_unit_planes(s32.psf_sensor(), 2e-5, "dim f32 sensor");
    const double e32 = rel_l2(s32.psf_sensor().data, s64.psf_sensor().data);
    CAPTURE(e32);
    MESSAGE("energy inside the window " << 1 - outside << ", f32 vs f64 PSF " << e32);
    CHECK(e32 <= 1e-2);  // the residue is resolved in float32 too, at reduced relative accuracy
    // The adjoint divides by the tiny sum: large but finite, and still the derivative.
    const RealStack g = random_stack(1, s64.sensor_size(), s64.sensor_size(), 8);
    const Map2D grad = s64.psf_sensor_vjp(g);
    CHECK(all_finite(grad.data));
    CHECK(all_finite(s32.psf_sensor_vjp(g).data));
    CHECK(directional_fd_error(c, h, g, grad, 21, 1e-12) <= 1e-5);
  }

  TEST_CASE("gradients match finite differences at the extremes (CPU reference, OpenCL f64 and f32 adjoints)") {
    REQUIRE(runtime().has_fp64());
    struct Case {
      double pitch, d, z;
    };
    const Case cases[] = {{0.5e-6, 0.05, 1e-3}, {20e-6, kInf, 1.0}, {4e-6, 1000.0, 0.03}, {4e-6, 0.05, 1.0}, {20e-6, 0.05, 1e-3}};
    double worst_fd = 0, worst32 = 0;
    for (const Case& k : cases) {
      const SystemConfig c = extreme_config(32, k.pitch, k.d, k.z);
      CAPTURE(describe(c));
      const double hmax = c.h_max_m();
      Map2D straddle = random_heights(c.n, 4e-9, 2);
      for (double& v : straddle.data) v += hmax - 2e-9;
      const Map2D designs[] = {Map2D(c.n, c.n, 0.0), Map2D(c.n, c.n, hmax), straddle, random_heights(c.n, hmax, 4)};
      Simulator s64(runtime(), c, Precision::F64), s32(runtime(), c, Precision::F32);
      for (std::size_t di = 0; di < 4; ++di) {
        CAPTURE(di);
        const Map2D& h = designs[di];
        const RealStack g = random_stack(c.bands, s64.sensor_size(), s64.sensor_size(), unsigned(di + 1));
        const Map2D want = ref::psf_sensor_vjp(c, h, g);
        CHECK(all_finite(want.data));
        const double efd = directional_fd_error(c, h, g, want, unsigned(di) + 40, 1e-12);
        worst_fd = std::max(worst_fd, efd);
        CHECK(efd <= 1e-5);
        s64.set_heights(h);
        s64.compute_psf();
        CHECK(rel_l2(s64.psf_sensor_vjp(g).data, want.data) <= 1e-9);
        s32.set_heights(h);
        s32.compute_psf();
        const double e32 = rel_l2(s32.psf_sensor_vjp(g).data, want.data);
        worst32 = std::max(worst32, e32);
        CAPTURE(e32);
        CHECK(e32 <= 2e-3);
      }
    }
    MESSAGE("worst adjoint vs differences " << worst_fd << ", worst float32 adjoint vs reference " << worst32);
  }

  TEST_CASE("scenes all zero, constant, one bright pixel; results independent of the batch") {
    // Work-group size is fixed (Runtime::kLocalSize = 128) in this code base, so only the batch
    // size can vary: a scene's image must not depend on its batch or its position in it.
    double worst_batch = 0;
    for (ConvolutionMode mode : {ConvolutionMode::Linear, ConvolutionMode::Circular})
      for (Precision p : {Precision::F32, Precision::F64}) {
        SystemConfig c = extreme_config(32, 4e-6, 1.0, 1.5625e-3);
        c.convolution = mode;
        CAPTURE(int(mode));
        CAPTURE(to_string(p));
        const double tol = p == Precision::F64 ? 1e-12 : 2e-6;
        Simulator sim(runtime(), c, p);
        sim.set_heights(lens_design(c, 500));
        sim.compute_psf();
        const RealStack psf = sim.psf_sensor();
        const std::size_t S = sim.sensor_size(), H = 40, W = 48;  // S = 16; 40 = 2^3 5, 48 = 2^4 3
        const RealStack zero(c.bands, H, W, 0.0), constant(c.bands, H, W, 0.5);
        RealStack bright(c.bands, H, W, 0.0);
        for (std::size_t b = 0; b < c.bands; ++b) bright(b, H / 2, W / 2) = 1.0;
        const RealStack noisy = random_cube(c.bands, H, W, 3);
        // One bright pixel: the image is the PSF itself (the PSF fits inside the scene).
        const RealStack blur = sim.convolve(bright);
        CHECK(all_finite(blur.data));
        double worst = 0;
        for (std::size_t b = 0; b < c.bands; ++b) {
          double sum = 0;
          for (std::size_t y = 0; y < S; ++y)
            for (std::size_t x = 0; x < S; ++x) {
              worst = std::max(worst, std::fabs(blur(b, H / 2 - S / 2 + y, W / 2 - S / 2 + x) - psf(b, y, x)));
              sum += blur(b, H / 2 - S / 2 + y, W / 2 - S / 2 + x);
            }
          CHECK(sum == doctest::Approx(1).epsilon(tol * 10));
        }
        CHECK(worst <= tol);
        // All zero stays exactly zero; a constant stays constant where the PSF is inside the
        // scene (everywhere for circular convolution).
        const RealStack z = sim.convolve(zero);
        CHECK(std::all_of(z.data.begin(), z.data.end(), [](double v) { return v == 0.0; }));
        const RealStack k = sim.convolve(constant);
        double kerr = 0;
        for (std::size_t b = 0; b < c.bands; ++b)
          for (std::size_t y = S; y + S < H; ++y)
            for (std::size_t x = S; x + S < W; ++x) kerr = std::max(kerr, std::fabs(k(b, y, x) - 0.5));
        if (mode == ConvolutionMode::Circular)
          for (double v : k.data) kerr = std::max(kerr, std::fabs(v - 0.5));
        CHECK(kerr <= 10 * tol);
        // Batches: each scene's image equals its image alone, for batch sizes 1, 2, 3 and 5.
        const std::vector<RealStack> scenes = {zero, constant, bright, noisy, bright};
        std::vector<RealStack> alone;
        for (const auto& sc : scenes) alone.push_back(sim.sensor_image(sc));
        for (std::size_t batch : {1ul, 2ul, 3ul, 5ul})
          for (std::size_t first = 0; first + batch <= scenes.size(); first += batch) {
            const std::vector<RealStack> in(scenes.begin() + long(first), scenes.begin() + long(first + batch));
            const std::vector<RealStack> out = sim.sensor_images(in);
            for (std::size_t i = 0; i < batch; ++i) {
              CAPTURE(batch);
              CAPTURE(first + i);
              CHECK(all_finite(out[i].data));
              const double d = diff(out[i].data, alone[first + i].data).max_abs;
              worst_batch = std::max(worst_batch, d);
              CHECK(d <= tol);
            }
          }
        // The sensor adjoint through a batch: finite for every scene type.
        std::vector<RealStack> g;
        for (std::size_t i = 0; i < scenes.size(); ++i) g.push_back(random_stack(3, H, W, unsigned(i)));
        sim.sensor_images(scenes);
        CHECK(all_finite(sim.sensor_images_vjp(g).data));
      }
    MESSAGE("largest difference between a scene's image in a batch and alone: " << worst_batch);
  }

  TEST_CASE("the CPU reference at the extremes: unit-sum PSFs, energy accounted, adjoint = finite differences [cpu]") {
    // No OpenCL: the double-precision reference alone (the valgrind target of scripts/sanitize.sh).
    struct Case {
      double pitch, d, z;
    };
    for (const Case& k : {Case{0.5e-6, 0.05, 1e-3}, Case{20e-6, kInf, 1.0}, Case{4e-6, 1000.0, 0.03}}) {
      const SystemConfig c = extreme_config(32, k.pitch, k.d, k.z);
      CAPTURE(describe(c));
      const Map2D h = random_heights(c.n, c.h_max_m(), 12);
      const ref::PsfResult r = ref::psf_stack(c, h);
      check_unit_planes(r.psf, 1e-12, "reference");
      for (const auto& b : r.sampling.bands) {
        CHECK(b.aliased_energy_fraction >= 0);
        CHECK(b.aliased_energy_fraction <= 1 + 1e-12);
      }
      const auto g = PropagationGeometry::from_config(c);
      ComplexStack f = ref::doe_field(c, h, g);
      std::vector<double> c0, t0, c1, t1;
      window_energies(f, g, c0, t0);
      ref::propagate(f, c.wavelengths_nm(), c.pitch_m, c.sensor_distance_m, c.propagator);
      window_energies(f, g, c1, t1);
      for (std::size_t b = 0; b < c.bands; ++b) CHECK(std::fabs(t1[b] - t0[b]) <= 1e-12 * t0[b]);
      const RealStack gs = random_stack(c.bands, c.sensor_size_px(), c.sensor_size_px(), 3);
      const Map2D grad = ref::psf_sensor_vjp(c, h, gs);
      CHECK(all_finite(grad.data));
      CHECK(directional_fd_error(c, h, gs, grad, 77, 1e-12) <= 1e-5);
    }
  }

  TEST_CASE("N from 16 to 256: invariants and f32 ~ f64 ~ CPU reference at every size") {
    for (std::size_t n : {16ul, 32ul, 64ul, 128ul, 256ul}) {
      SystemConfig c = tiny_config(n, 3);
      c.read_noise_sigma = 0;
      CAPTURE(n);
      const Map2D h = random_heights(n, c.h_max_m(), 6);
      Simulator s64(runtime(), c, Precision::F64), s32(runtime(), c, Precision::F32);
      s64.set_heights(h);
      s32.set_heights(h);
      s64.compute_psf();
      s32.compute_psf();
      check_unit_planes(s64.psf_sensor(), 1e-12, "f64");
      check_unit_planes(s32.psf_sensor(), 2e-5, "f32");
      CHECK(rel_l2(s32.psf_sensor().data, s64.psf_sensor().data) <= 2e-4);
      CHECK(rel_l2(s64.psf_sensor().data, ref::psf_sensor_stack(c, h).data) <= 1e-9);
    }
  }

  TEST_CASE("under-sampling of the point source's spherical wave on the DOE grid is reported") {
    // Regression (the sampling report used to check only the transfer function). A source at d = 0.05 m seen through a 20 um grid of N = 64 has a
    // local phase frequency r / (lambda d) = 27.6 /mm at the aperture rim, above the grid's
    // Nyquist 25 /mm, so the field after the DOE aliases (and float32 phases grow with it), yet
    // strict_sampling accepts it. Expected: SamplingReport flags the band and enforce() throws
    // AccuracyError naming the source distance and the remedy (finer pitch or larger d).
    SystemConfig c = extreme_config(64, 20e-6, 0.05, 0.1, 3);  // lambda z <= M pitch^2: the transfer function is fine
    c.padding_px = 64;
    c.strict_sampling = true;
    c.validate();
    Simulator sim(runtime(), c, Precision::F64);
    sim.set_heights(flat_design(c));
    CHECK_THROWS_WITH_AS(sim.compute_psf(), doctest::Contains("scene_distance_m"), AccuracyError);
  }

  // =====================================================================================
  // 2. Device faults
  // =====================================================================================

  TEST_CASE("device faults become clear messages: build failure, unknown kernel, allocation beyond the device") {
    Runtime& rt = runtime();
    for (Precision p : {Precision::F32, Precision::F64}) {
      CAPTURE(to_string(p));
      try {
        rt.kernel_from_source("stress_broken.cl", "__kernel void k(__global real* x) { x[0] = undefined_thing; }", "k", p);
        FAIL("expected a build failure");
      } catch (const DeviceError& e) {
        const std::string msg = e.what();
        CHECK(has(msg, rt.info().name));
        CHECK(has(msg, "stress_broken.cl"));
        CHECK(has(msg, "undefined_thing"));  // the build log
      }
      CHECK_THROWS_WITH_AS(rt.kernel("psf.cl", "no_such_kernel", p), doctest::Contains("no_such_kernel"), DeviceError);
    }
    // A configuration whose padded field exceeds the device's largest allocation is refused by
    // the Simulator before any allocation or kernel build, naming n, the size and the limit.
    SystemConfig big = tiny_config(32, 3);
    big.n = 16384;
    big.padding_px = 4 * big.n;
    big.pitch_m = 1e-6;
    big.sensor_pitch_m = 1e-6;
    big.sensor_distance_m = 1e-3;
    big.bands = 31;
    big.wavelength_start_nm = 400;
    big.wavelength_step_nm = 10;
    big.validate();
    CHECK_THROWS_WITH_AS(Simulator(rt, big, Precision::F32), doctest::Contains("largest allocation"), InputError);
    // The same through the CLI: exit code 2 and the message.
    const auto dir = temp_dir("stress_cli");
    write_text_atomic((dir / "big.json").string(), config_to_json_text(big));
    const std::string log = (dir / "log.txt").string();
    Child c({QDO_QDO_BINARY, "psf", "--config", (dir / "big.json").string(), "--design", "flat", "--out", (dir / "o").string()}, log);
    CHECK(c.exit_code() == 2);
    CHECK(has(slurp(log), "largest allocation"));
    // No such device type: an InputError listing the devices there are.
    bool have_gpu = false;
    for (const auto& d : list_devices()) have_gpu = have_gpu || d.type == "GPU";
    if (!have_gpu) CHECK_THROWS_WITH_AS(Runtime("gpu"), doctest::Contains("'device'"), InputError);
    fs::remove_all(dir);
  }

  TEST_CASE("a device without fp64 refuses float64 with the device named") {
    // Runtime honours QDO_DISABLE_FP64=1 (clears DeviceInfo::fp64), so this path runs anywhere:
    //   Runtime::require(F64) -> DeviceError "device '<name>' (<platform>) has no double precision
    //   (cl_khr_fp64); use --precision f32 or another device"; CLI exit code 4.
    setenv("QDO_DISABLE_FP64", "1", 1);
    Runtime rt;
    unsetenv("QDO_DISABLE_FP64");
    CHECK_FALSE(rt.has_fp64());
    CHECK_THROWS_WITH_AS(Simulator(rt, tiny_config(32, 3), Precision::F64), doctest::Contains("cl_khr_fp64"), DeviceError);
  }

  // =====================================================================================
  // 3. Hostile input
  // =====================================================================================

  TEST_CASE("JSON configuration: deep nesting, huge and non-finite numbers, wrong types are named InputErrors [cpu]") {
    // A value nested 300,000 deep (under the 1 MiB cap): rejected naming the key, without
    // recursing through it (regression: the message used to dump the whole value recursively).
    const std::string deep = "{\"n\": " + std::string(300000, '[') + std::string(300000, ']') + "}";
    const std::string e1 = input_error([&] { config_from_json_text(deep, "deep.json"); });
    CHECK(has(e1, "deep.json"));
    CHECK(has(e1, "'n'"));
    CHECK(e1.size() < 400);
    // A huge string value is quoted, but shortened.
    const std::string e2 = input_error([&] { config_from_json_text("{\"pitch_m\": \"" + std::string(500000, 'x') + "\"}", "s.json"); });
    CHECK(has(e2, "'pitch_m'"));
    CHECK(e2.size() < 400);
    for (const std::string doc : {R"({"pitch_m": 1e999})", R"({"pitch_m": -1e-999})", R"({"n": 1e20})", R"({"n": -32})",
                            R"({"n": 18446744073709551615})", R"({"n": 64.5})", R"({"bands": 0})", R"({"noise_seed": -1})",
                            R"({"scene_distance_m": "-inf"})", R"({"sensor_distance_m": 0})", R"({"strict_sampling": "yes"})",
                            R"({"preset": ["small"]})", R"({"preset": "huge"})", R"({"camera": ""})"}) {
      CAPTURE(doc);
      const std::string e = input_error([&] { config_from_json_text(doc, "h.json"); });
      CHECK(has(e, "h.json"));
      CHECK(has(e, "'"));  // names the key
    }
    for (const std::string doc : {"", "{", "\xef\xbb\xbf{", "{\"n\": 32,}", "[1, 2]", "null", "{\"n\": \"\xff\"}", "{\"a\":1}\0"}) {
      CAPTURE(doc);
      CHECK(has(input_error([&] { config_from_json_text(doc, "m.json"); }), "m.json"));
    }
    // Files: a folder, a FIFO-like device, and a file over the cap are refused before reading.
    const auto dir = temp_dir("stress_json");
    CHECK(has(input_error([&] { config_from_json_file(dir.string()); }), dir.string()));
    CHECK(has(input_error([&] { config_from_json_file("/dev/zero"); }), "/dev/zero"));
    spit((dir / "big.json").string(), "{\"n\": 32" + std::string(2 << 20, ' ') + "}");
    CHECK(has(input_error([&] { config_from_json_file((dir / "big.json").string()); }), "1 MiB"));
    fs::remove_all(dir);
  }

  TEST_CASE("HDF5 design, cube and checkpoint files: truncated, corrupt, mistyped, misshapen [cpu]") {
    const auto dir = temp_dir("stress_h5");
    const std::string design = (dir / "design.h5").string(), cube = (dir / "cube.h5").string(), ck = (dir / "ck.h5").string();
    Design d;
    d.height_m = random_heights(8, 1e-6, 1);
    d.pitch_m = 4e-6;
    d.levels_m = {0, 1e-6};
    write_design(design, d);
    write_cube(cube, random_cube(3, 5, 6, 2), {450, 500, 550});
    DesignState st;
    st.w.assign(16, 0.25);
    st.offsets = {0, 0.1, -0.1, 0};
    st.adam_w.m.assign(16, 1e-3);
    st.adam_w.v.assign(16, 1e-6);
    st.step = st.adam_w.t = 12;
    save_checkpoint(ck, st);
    const std::string bad = (dir / "bad.h5").string();
    // Every truncation and corruption: an InputError naming the file, or a valid result.
    CHECK(mutate_and_read(bad, slurp(design), [&] {
            const Design r = read_design(bad);
            CHECK(all_finite(r.height_m.data));
          }) > 40);
    CHECK(mutate_and_read(bad, slurp(cube), [&] {
            const RealStack c = read_cube(bad, {});
            CHECK(all_finite(c.data));
          }) > 40);
    CHECK(mutate_and_read(bad, slurp(ck), [&] { load_checkpoint(bad, 16, 4); }) > 40);
    // Wrong types and shapes.
    auto write = [&](const std::vector<H5Dataset>& sets) { h5_write_unchecked(bad, sets); };
    write({H5Dataset{"/height_m", {4, 5}, std::vector<double>(20, 0.0), {{"pitch_m", 4e-6}}, {}}});
    CHECK(has(input_error([&] { read_design(bad); }), "not a square"));
    write({H5Dataset{"/height_m", {2, 2, 2}, std::vector<double>(8, 0.0), {{"pitch_m", 4e-6}}, {}}});
    CHECK(has(input_error([&] { read_design(bad); }), "not a square"));
    write({H5Dataset{"/height_m", {2, 2}, std::vector<double>(4, 0.0), {}, {{"pitch_m", "4e-6"}}}});
    CHECK(has(input_error([&] { read_design(bad); }), "pitch_m"));
    write({H5Dataset{"/height_m", {2, 2}, std::vector<double>(4, 0.0), {{"pitch_m", -1}}, {}}});
    CHECK(has(input_error([&] { read_design(bad); }), "pitch_m"));
    write({H5Dataset{"/height_m", {2, 2}, {0, 1, std::nan(""), 0}, {{"pitch_m", 4e-6}}, {}}});
    CHECK(has(input_error([&] { read_design(bad); }), "non-finite"));
    write({H5Dataset{"/cube", {3, 4}, std::vector<double>(12, 0.0), {}, {}}});
    CHECK(has(input_error([&] { read_cube(bad, {}); }), "not a 3-D cube"));
    // A string dataset where numbers belong.
    {
      H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
      const hid_t f = H5Fcreate(bad.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
      const hid_t t = H5Tcopy(H5T_C_S1);
      H5Tset_size(t, 8);
      const hsize_t dims[2] = {2, 2};
      const hid_t sp = H5Screate_simple(2, dims, nullptr);
      const hid_t ds = H5Dcreate2(f, "/height_m", t, sp, H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
      H5Dclose(ds);
      H5Sclose(sp);
      H5Tclose(t);
      H5Fclose(f);
    }
    CHECK(has(input_error([&] { read_design(bad); }), "not numeric"));
    // Checkpoints: sizes, ranges and counters a corrupt file could hold.
    auto ckpt = [&](const std::string& name, std::vector<double> v) {
      std::vector<H5Dataset> sets;
      for (const char* n : {"/w", "/offsets", "/adam_w_m", "/adam_w_v", "/adam_a_m", "/adam_a_v", "/counters"}) {
        std::vector<double> def = std::string(n) == "/counters" ? std::vector<double>{3, 3, 3}
                                  : (std::string(n) == "/w" || std::string(n).rfind("/adam_w", 0) == 0) ? std::vector<double>(16, 0.1)
                                                                                                        : std::vector<double>(4, 0.0);
        if (name == n) def = v;
        sets.push_back(H5Dataset{n, {def.size()}, def, {}, {}});
      }
      h5_write_unchecked(bad, sets);
      return input_error([&] { load_checkpoint(bad, 16, 4); });
    };
    CHECK(ckpt("", {}).empty());  // the defaults load
    CHECK(has(ckpt("/w", std::vector<double>(15, 0.0)), "'/w' has 15 values"));
    CHECK(has(ckpt("/w", std::vector<double>(16, 1.5)), "outside [-1, 1]"));
    CHECK(has(ckpt("/counters", {-1, 0, 0}), "/counters"));
    CHECK(has(ckpt("/counters", {2.5, 0, 0}), "/counters"));
    // Regression (src/design/run.cpp): counters beyond the range of a long (undefined behaviour in the
    // conversion), negative second moments (NaN weights after resume) and offsets beyond their
    // clip limits are rejected naming the dataset.
    CHECK(has(ckpt("/counters", {1e300, 0, 0}), "/counters"));
    CHECK(has(ckpt("/adam_w_v", std::vector<double>(16, -1.0)), "/adam_w_v"));
    CHECK(has(ckpt("/offsets", {0, 3, 0, 0}), "/offsets"));
    CHECK(has(ckpt("/offsets", {0.5, 0, 0, 0}), "/offsets"));
    fs::remove_all(dir);
  }

  TEST_CASE("absurdly large declared shapes are refused before allocating (HDF5, .mat v5, PNG) [cpu]") {
    const auto dir = temp_dir("stress_big");
    // HDF5: /height_m declared 32768 x 32768 (8 GiB of float64) with no data written: a 2 KiB file.
    const std::string h5 = (dir / "big.h5").string();
    for (const std::string name : {"/height_m", "/cube"}) {
      H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
      const hid_t f = H5Fcreate(h5.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
      const bool cube = name == "/cube";
      const hsize_t dims[3] = {cube ? 31ull : 32768ull, cube ? 8192ull : 32768ull, 8192};
      const hsize_t chunk[3] = {1, 64, 64};
      const hid_t sp = H5Screate_simple(cube ? 3 : 2, dims, nullptr);
      const hid_t pl = H5Pcreate(H5P_DATASET_CREATE);
      H5Pset_chunk(pl, cube ? 3 : 2, cube ? chunk : chunk + 1);
      const hid_t ds = H5Dcreate2(f, name.c_str(), H5T_IEEE_F64LE, sp, H5P_DEFAULT, pl, H5P_DEFAULT);
      const hid_t as = H5Screate(H5S_SCALAR);
      const hid_t at = H5Acreate2(ds, "pitch_m", H5T_IEEE_F64LE, as, H5P_DEFAULT, H5P_DEFAULT);
      const double pitch = 4e-6;
      H5Awrite(at, H5T_NATIVE_DOUBLE, &pitch);
      H5Aclose(at);
      H5Sclose(as);
      H5Dclose(ds);
      H5Pclose(pl);
      H5Sclose(sp);
      H5Fclose(f);
      REQUIRE(fs::file_size(h5) < 100000);
      const std::string e = cube ? input_error([&] { read_cube(h5, {}); }) : input_error([&] { read_design(h5); });
      CAPTURE(e);
      CHECK(has(e, h5));
      CHECK(has(e, "declares"));
      if (cube) {
        CHECK(has(input_error([&] { load_scene(h5, "auto", 31); }), "declares"));
        CHECK(has(input_error([&] { probe_scene(h5, "auto", 31); }), "declares"));
      }
    }
    // Regression (fuzz_cube_h5, fuzz/corpus/cube_h5/crash-compact-no-data.h5): a compact
    // dataset whose layout message stores no data crashed libhdf5's read (NULL memcpy); and a
    // contiguous dataset never written holds no data. Both refused before reading.
    const fs::path corpus = fs::path(__FILE__).parent_path().parent_path() / "fuzz" / "corpus";
    const std::string compact = (corpus / "cube_h5" / "crash-compact-no-data.h5").string();
    for (const auto& read : std::vector<std::function<void()>>{[&] { read_cube(compact, {"/rad", "auto", 0, 0, {}, false}); },
                                                               [&] { load_scene(compact, "auto", 0); }}) {
      const std::string e = input_error(read);
      CAPTURE(e);
      CHECK(has(e, "stores 0 bytes"));
    }
    {
      H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
      const hid_t f = H5Fcreate(h5.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
      const hsize_t dims[2] = {4, 4};
      const hid_t sp = H5Screate_simple(2, dims, nullptr);
      const hid_t ds = H5Dcreate2(f, "/height_m", H5T_IEEE_F64LE, sp, H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
      H5Dclose(ds);
      H5Sclose(sp);
      H5Fclose(f);
    }
    CHECK(has(input_error([&] { read_design(h5); }), "unwritten"));
    // Regression (fuzz_mat, fuzz/corpus/mat/crash-v73-datatype-4gb.mat): a v7.3 variable whose
    // datatype claims 4 GiB per element made libhdf5 (through libmatio) zero 4 GB for a 3.8 KiB
    // file. The variable's dataset is now checked like any HDF5 dataset first.
    const std::string v73 = (corpus / "mat" / "crash-v73-datatype-4gb.mat").string();
    CHECK(has(input_error([&] { read_cube(v73, {}); }), "corrupt datatype"));
    // MATLAB v5: a 4 x 5 x 3 double variable whose header is patched to claim 32768 x 32768 x 2.
    const std::string mat = (dir / "big.mat").string();
    write_mat(mat, MAT_FT_MAT5, "cube", {4, 5, 3}, MAT_C_DOUBLE, MAT_T_DOUBLE, std::vector<double>(60, 0.5));
    std::string bytes = slurp(mat);
    REQUIRE(bytes.size() > 176);
    auto put32 = [&](std::size_t at, std::uint32_t v) {
      for (int i = 0; i < 4; ++i) bytes[at + std::size_t(i)] = char((v >> (8 * i)) & 0xff);
    };
    // 128-byte header, miMATRIX tag (8), array flags (16), dims tag (8): dims at byte 160.
    put32(160, 32768);
    put32(164, 32768);
    put32(168, 2);
    spit(mat, bytes);
    const std::string em = input_error([&] { read_cube(mat, {}); });
    CAPTURE(em);
    CHECK(has(em, mat));
    // Regression (fuzz_mat, fuzz/corpus/mat/crash-dims-tag-oom.mat): a dims tag declaring
    // 587 MB made libmatio allocate 1.2 GB while merely listing the variables. Now refused from
    // the array header, uncompressed and inside a compressed (zlib) variable.
    write_mat(mat, MAT_FT_MAT5, "cube", {4, 5, 3}, MAT_C_DOUBLE, MAT_T_DOUBLE, std::vector<double>(60, 0.5));
    bytes = slurp(mat);
    put32(156, 0x2300000c);  // the dims tag's byte count
    spit(mat, bytes);
    for (const auto& read : std::vector<std::function<void()>>{[&] { read_cube(mat, {}); }, [&] { load_scene(mat, "auto", 0); },
                                                               [&] { probe_scene(mat, "auto", 3); }}) {
      const std::string e = input_error(read);
      CAPTURE(e);
      CHECK(has(e, mat));
      CHECK(has(e, "dimensions"));
    }
    {
      // The same element deflated into a miCOMPRESSED (type 15) element.
      const std::string element = bytes.substr(128);
      uLongf zlen = compressBound(uLong(element.size()));
      std::string z(zlen, '\0');
      REQUIRE(compress2(reinterpret_cast<Bytef*>(&z[0]), &zlen, reinterpret_cast<const Bytef*>(element.data()), uLong(element.size()), 6) == Z_OK);
      z.resize(zlen);
      std::string file = bytes.substr(0, 128) + std::string(8, '\0') + z;
      for (int i = 0; i < 4; ++i) {
        file[128 + std::size_t(i)] = char((15u >> (8 * i)) & 0xff);
        file[132 + std::size_t(i)] = char((std::uint32_t(zlen) >> (8 * i)) & 0xff);
      }
      spit(mat, file);
      const std::string e = input_error([&] { load_scene(mat, "auto", 0); });
      CAPTURE(e);
      CHECK(has(e, "dimensions"));
    }
    // PNG: a valid 60-byte file whose header declares 1,000,000 x 1,000,000 16-bit pixels.
    const std::string pdir = (dir / "pngs").string();
    fs::create_directories(pdir);
    spit(pdir + "/band_1.png", png_claiming(1000000, 1000000));
    const std::string ep = input_error([&] { read_png_band_folder(pdir, 0); });
    CAPTURE(ep);
    CHECK(has(ep, "band_1.png"));
    CHECK(has(ep, "declares"));
    spit(pdir + "/band_1.png", png_claiming(40000, 40000));
    CHECK(has(input_error([&] { read_png_band_folder(pdir, 0); }), "declares"));
    CHECK(has(input_error([&] { load_scene(pdir, "auto", 0); }), "declares"));
    fs::remove_all(dir);
  }

  TEST_CASE(".mat v5 and v7.3: truncated, corrupt, wrong classes and shapes [cpu]") {
    const auto dir = temp_dir("stress_mat");
    const std::string v5 = (dir / "v5.mat").string(), v5z = (dir / "v5z.mat").string(), v73 = (dir / "v73.mat").string();
    std::vector<std::uint16_t> u16(4 * 5 * 3);
    for (std::size_t i = 0; i < u16.size(); ++i) u16[i] = std::uint16_t(i * 997);
    write_mat(v5, MAT_FT_MAT5, "cube", {4, 5, 3}, MAT_C_UINT16, MAT_T_UINT16, u16);
    write_mat(v5z, MAT_FT_MAT5, "cube", {4, 5, 3}, MAT_C_UINT16, MAT_T_UINT16, u16, MAT_COMPRESSION_ZLIB);
    write_mat(v73, MAT_FT_MAT73, "cube", {4, 5, 3}, MAT_C_UINT16, MAT_T_UINT16, u16);
    const std::string bad = (dir / "bad.mat").string();
    for (const std::string& good : {v5, v5z, v73}) {
      CAPTURE(good);
      CHECK(mutate_and_read(bad, slurp(good), [&] {
              const RealStack c = read_cube(bad, {});
              CHECK(all_finite(c.data));
              load_scene(bad, "auto", 0);
            }) > 30);
    }
    // Wrong classes: char, complex, logical is fine (0/1), 2-D.
    write_mat(bad, MAT_FT_MAT5, "cube", {4, 5, 3}, MAT_C_CHAR, MAT_T_UINT8, std::vector<std::uint8_t>(60, 'a'));
    CHECK(has(input_error([&] { read_cube(bad, {}); }), bad));
    CHECK(has(input_error([&] { read_cube(bad, {"cube", "auto", 0, 0, {}, false}); }), "not a real numeric"));
    write_mat(bad, MAT_FT_MAT5, "cube", {4, 15}, MAT_C_DOUBLE, MAT_T_DOUBLE, std::vector<double>(60, 0.5));
    CHECK(has(input_error([&] { read_cube(bad, {"cube", "auto", 0, 0, {}, false}); }), "not a 3-D cube"));
    {
      std::unique_ptr<mat_t, MatCloser> m(Mat_CreateVer(bad.c_str(), nullptr, MAT_FT_MAT5));
      std::vector<double> re(60, 1.0), im(60, 2.0);
      mat_complex_split_t z{re.data(), im.data()};
      std::size_t dims[3] = {4, 5, 3};
      std::unique_ptr<matvar_t, MatVarFreer> v(Mat_VarCreate("cube", MAT_C_DOUBLE, MAT_T_DOUBLE, 3, dims, &z, MAT_F_COMPLEX | MAT_F_DONT_COPY_DATA));
      REQUIRE(Mat_VarWrite(m.get(), v.get(), MAT_COMPRESSION_NONE) == 0);
    }
    CHECK(has(input_error([&] { read_cube(bad, {"cube", "auto", 0, 0, {}, false}); }), "complex"));
    CHECK(has(input_error([&] { read_cube(v5, {"nope", "auto", 0, 0, {}, false}); }), "'nope'"));
    // Regression (fuzz_mat, fuzz/corpus/mat/crash-v4-fallback-timeout.mat): a file without the
    // v5 / v7.3 header made libmatio fall back to its v4 reader, which allocated what the first
    // bytes declared (12 s, half a gigabyte). Only v5 and v7.3 are accepted now.
    std::string v4 = "\x00\x00\x00\x00\x20\x00\x00\x00\x01\x00\x00\x00\x00\x00\x00\x00\xff\xff\xff\x7f";
    v4.resize(208, 'x');
    spit(bad, v4);
    CHECK(has(input_error([&] { read_cube(bad, {}); }), "v5 or v7.3"));
    CHECK(has(input_error([&] { load_scene(bad, "auto", 0); }), "v5 or v7.3"));
    std::string wrong_version = slurp(v5);
    wrong_version[124] = 0x03;
    spit(bad, wrong_version);
    CHECK(has(input_error([&] { read_cube(bad, {}); }), "v5 or v7.3"));
    CHECK(has(input_error([&] { read_cube(v5, {"", "auto", 0, 7, {}, false}); }), "no band axis of length 7"));
    fs::remove_all(dir);
  }

  TEST_CASE("PNG band folders and CSV tables: truncated, corrupt, unbounded streams [cpu]") {
    const auto dir = temp_dir("stress_png");
    const std::string pdir = (dir / "scene").string();
    fs::create_directories(pdir);
    const std::string band = pdir + "/scene_ms_01.png";
    for (bool sixteen : {false, true}) {
      write_png_gray(band, 7, 5, sixteen);
      const std::string good = slurp(band);
      CHECK(mutate_and_read(band, good, [&] {
              const RealStack c = read_png_band_folder(pdir, 0);
              for (double v : c.data) CHECK((v >= 0 && v <= 1));
            }) > 30);
      spit(band, good);
    }
    // A second band of another size, and a band that is not a PNG at all.
    write_png_gray(pdir + "/scene_ms_02.png", 6, 5, true);
    CHECK(has(input_error([&] { read_png_band_folder(pdir, 0); }), "scene_ms_02.png"));
    spit(pdir + "/scene_ms_02.png", "not a png");
    CHECK(has(input_error([&] { read_png_band_folder(pdir, 0); }), "scene_ms_02.png"));
    // CSV: the parser takes anything and names the origin; the file reader refuses what is not
    // a regular file or is too large (regression: it used to read /dev/zero until memory ran out).
    for (const std::string t : {"", "# only\n", ",a\n", "a,a\n", "a,b\n1\n", "a,b\n1,2,3\n"}) {
      CAPTURE(t);
      const std::string e = input_error([&] { parse_csv(t, "t.csv"); });
      CHECK(has(e, "t.csv"));
    }
    const CsvTable odd = parse_csv("x,y\n1e999,nan\n0x10,abc\n\xff\xfe,\0\n", "odd.csv");  // cells that are not numbers are NaN
    CHECK(std::isinf(odd.columns[0][0]));
    CHECK(std::isnan(odd.columns[1][1]));
    CHECK(has(input_error([&] { read_csv("/dev/zero"); }), "/dev/zero"));
    CHECK(has(input_error([&] { read_csv(dir.string()); }), dir.string()));
    CHECK(has(input_error([&] { read_csv((dir / "missing.csv").string()); }), "missing.csv"));
    const std::string huge = (dir / "huge.csv").string();
    {
      std::ofstream out(huge, std::ios::binary);
      out << "wavelength_nm,R,G,B\n";
      const std::string row = "500,1,1,1\n";
      for (std::size_t i = 0; i < (70u << 20) / row.size(); ++i) out << row;
    }
    CHECK(has(input_error([&] { read_csv(huge); }), "huge.csv"));
    // A camera CSV with a non-numeric or negative response is refused naming the file.
    SystemConfig c = tiny_config(32, 3);
    c.camera = (dir / "cam.csv").string();
    spit(c.camera, "wavelength_nm,R,G,B\n450,1,1,1\n500,x,1,1\n550,1,1,1\n");
    CHECK(has(input_error([&] { sensor_response(c); }), "cam.csv"));
    spit(c.camera, "wavelength_nm,R,G,B\n450,1,1,1\n500,-1,1,1\n550,1,1,1\n");
    CHECK(has(input_error([&] { sensor_response(c); }), "cam.csv"));
    fs::remove_all(dir);
  }

  TEST_CASE("CSV camera tables: a missing column is named with its file [cpu]") {
    // Regression: the error used to lack the file; CsvTable now keeps its origin.
    const auto dir = temp_dir("stress_csvcol");
    SystemConfig c = tiny_config(32, 3);
    c.camera = (dir / "cam.csv").string();
    spit(c.camera, "wavelength_nm,red,G,B\n450,1,1,1\n550,1,1,1\n");
    CHECK(has(input_error([&] { sensor_response(c); }), "cam.csv"));
    fs::remove_all(dir);
  }

  TEST_CASE("CSV camera tables with unsorted or repeated wavelengths are refused, not misinterpolated [cpu]") {
    // Regression: with srf_interpolate an unsorted table (400, 600, 500, 700) used to interpolate
    // 450 nm between 400 and 600 although the table holds 500 nm = 100; now it is refused.
    const auto dir = temp_dir("stress_csvsort");
    SystemConfig c = tiny_config(32, 3);
    c.camera = (dir / "cam.csv").string();
    spit(c.camera, "wavelength_nm,R,G,B\n400,1,1,1\n600,1,1,1\n500,100,1,1\n700,1,1,1\n");
    CHECK(has(input_error([&] { sensor_response(c); }), "increasing"));
    fs::remove_all(dir);
  }

  TEST_CASE("a run killed between its log write and its checkpoint keeps every log row after resuming") {
    // Regression: the checkpoint used to be saved before log.csv, so a kill between the two lost
    // the rows in between for good. Now the log is written first; a kill in the new window
    // leaves the log ahead of the checkpoint, and the resume redoes those rows. Reproduced here
    // by restoring the previous checkpoint after a completed segment.
    const auto dir = temp_dir("stress_logloss");
    DesignRunOptions o;
    o.cfg = tiny_config(32, 3);
    o.objective = Objective::PsfTarget;
    o.target = target_spec_from_string("lens:500");
    o.design.steps_per_epoch = 2;
    o.design.t0_epochs = 1;
    o.design.t1_epochs = 3;
    o.epochs = 6;
    o.checkpoint_every = 3;
    o.out = (dir / "run").string();
    o.quiet = true;
    o.max_steps = 3;
    run_design(runtime(), o, false);
    const std::string old_ckpt = slurp(o.out + "/checkpoint.h5");
    o.max_steps = 6;
    run_design(runtime(), o, true);  // log rows up to step 5 written ...
    spit(o.out + "/checkpoint.h5", old_ckpt);  // ... and killed before the step-6 checkpoint was
    o.max_steps = -1;
    run_design(runtime(), o, true);
    std::istringstream in(slurp(o.out + "/log.csv"));
    std::size_t lines = 0;
    for (std::string l; std::getline(in, l);) ++lines;
    CHECK(lines == 1 + 12);  // header + one row per step
    fs::remove_all(dir);
  }

  TEST_CASE("a run folder with a corrupt log.csv resumes or fails with an InputError naming it") {
    // Regression: a damaged log.csv used to throw std::invalid_argument ("stol"); now an
    // InputError names RUN/log.csv and the line.
    const auto dir = temp_dir("stress_log");
    DesignRunOptions o;
    o.cfg = tiny_config(32, 3);
    o.objective = Objective::PsfTarget;
    o.target = target_spec_from_string("lens:500");
    o.design.steps_per_epoch = 2;
    o.design.t0_epochs = 1;
    o.design.t1_epochs = 2;
    o.epochs = 3;
    o.checkpoint_every = 2;
    o.max_steps = 2;
    o.out = (dir / "run").string();
    o.quiet = true;
    run_design(runtime(), o, false);
    spit(o.out + "/log.csv", "step,loss\ngarbage\n");
    o.max_steps = -1;
    CHECK(has(input_error([&] { run_design(runtime(), o, true); }), "log.csv"));
    fs::remove_all(dir);
  }

  // =====================================================================================
  // 4. Long runs, large grids, interrupted runs ([slow]: CTest label "stress")
  // =====================================================================================

  TEST_CASE("10,000 design steps: no drift in the invariants; same seed, same bits; a mid-run resume is bit-identical [slow]") {
    // N = 32, 3 bands, float32 (the design default), qdo+a with offsets, L_aq, height noise and
    // a constant learning rate, so the design keeps moving for all 10,000 steps.
    const SystemConfig c = tiny_config(32, 3);
    RealStack target;
    {
      Simulator t(runtime(), c, Precision::F32);
      t.set_heights(lens_design(c, 500));
      t.compute_psf();
      target = t.psf_sensor();
    }
    const PsfObjective obj = psf_target_objective(target);
    DesignOptions o;
    o.mode = DesignMode::QDOA;
    o.parameterization = Parameterization::Radial;
    o.quantizer.levels = 4;
    o.steps_per_epoch = 100;
    o.t0_epochs = 5;
    o.t1_epochs = 40;
    o.lr_optics = 2e-3;
    o.lr_offsets = 2e-3;
    o.lr_decay_per_epoch = 1.0;
    o.beta_aq = 0.01;
    o.height_noise_m = 5e-9;
    o.seed = 11;
    const long steps = 10000, half = 5000;
    std::vector<double> start(parameter_count(o.parameterization, c.n));
    {
      std::mt19937_64 rng(5);
      for (double& v : start) v = (0.2 + 0.6 * double(rng() >> 11) * 0x1.0p-53) * c.h_max_m();
    }
    Simulator sim(runtime(), c, Precision::F32);
    Designer d(sim, o);
    DesignState s = d.initial_state(start);
    double first_loss = 0, last_loss = 0;
    std::size_t nonfinite = 0;
    for (long k = 0; k < steps; ++k) {
      const StepReport r = d.step(s, obj);
      if (k == 0) first_loss = r.loss;
      last_loss = r.loss;
      nonfinite += !std::isfinite(r.loss) || !std::isfinite(r.loss_aq);
      if ((k + 1) % 1000 == 0) {
        CAPTURE(k + 1);
        CHECK(s.step == k + 1);
        CHECK(s.adam_w.t == k + 1);
        CHECK(std::all_of(s.w.begin(), s.w.end(), [](double w) { return w >= -1 && w <= 1; }));
        CHECK(s.offsets[0] == 0.0);
        CHECK(std::all_of(s.offsets.begin(), s.offsets.end(), [](double a) { return std::fabs(a) <= 1; }));
        CHECK(std::all_of(s.adam_w.v.begin(), s.adam_w.v.end(), [](double v) { return v >= 0 && std::isfinite(v); }));
        CHECK(all_finite(s.adam_w.m));
        sim.set_heights(d.training_heights(s));
        sim.compute_psf();
        check_unit_planes(sim.psf_sensor(), 2e-5, "design PSF");
        const Map2D fab = d.fabricated_heights(s);
        const std::set<double> distinct(fab.data.begin(), fab.data.end());
        CHECK(distinct.size() <= 4);
      }
    }
    CHECK(nonfinite == 0);
    CAPTURE(first_loss);
    CAPTURE(last_loss);
    CHECK(last_loss < first_loss);
    MESSAGE("loss " << first_loss << " -> " << last_loss << " after " << steps << " steps");
    // Gradients at the final state still match central differences (float64 kernels).
    {
      Simulator s64(runtime(), c, Precision::F64);
      DesignOptions o64 = o;
      o64.height_noise_m = 0;
      Designer d64(s64, o64);
      const auto g = d64.gradient(s, obj);
      for (std::size_t k : {2ul, 7ul, 12ul}) {
        DesignState a = s, b = s;
        a.w[k] = std::min(1.0, a.w[k] + 1e-7);
        b.w[k] = std::max(-1.0, b.w[k] - 1e-7);
        const double fd = (d64.gradient(a, obj).report.loss - d64.gradient(b, obj).report.loss) / (a.w[k] - b.w[k]);
        CAPTURE(k);
        CHECK(std::fabs(fd - g.g_w[k]) <= 1e-4 * std::fabs(g.g_w[k]) + 1e-8);
      }
    }
    // Same seed, same device and build: bit-identical, also across a checkpoint round trip and
    // a fresh Simulator / Designer at step 5,000.
    const auto dir = temp_dir("stress_long");
    const std::string ck = (dir / "checkpoint.h5").string();
    {
      Simulator sim2(runtime(), c, Precision::F32);
      Designer d2(sim2, o);
      DesignState s2 = d2.initial_state(start);
      for (long k = 0; k < half; ++k) d2.step(s2, obj);
      save_checkpoint(ck, s2);
    }
    Simulator sim3(runtime(), c, Precision::F32);
    Designer d3(sim3, o);
    DesignState s3 = load_checkpoint(ck, s.w.size(), 4);
    for (long k = half; k < steps; ++k) d3.step(s3, obj);
    CHECK(s3.step == s.step);
    CHECK(s3.w == s.w);
    CHECK(s3.offsets == s.offsets);
    CHECK(s3.adam_w.m == s.adam_w.m);
    CHECK(s3.adam_w.v == s.adam_w.v);
    CHECK(s3.adam_a.v == s.adam_a.v);
    fs::remove_all(dir);
  }

  TEST_CASE("large grids: N = 1024 (31 bands), 2048 (3 bands), 4096 (1 band) against the CPU reference [slow]") {
    // The envelope's upper end on PoCL (8 GiB device memory, 4 GiB per allocation, 2 cores):
    // N = 4096 with N/4 padding is a 6144^2 field per band (302 MiB in float32).
    struct Size {
      std::size_t n, bands;
    };
    for (const Size& z : {Size{1024, 31}, Size{2048, 3}, Size{4096, 1}}) {
      SystemConfig c = preset_config("paper");
      c.n = z.n;
      c.padding_px = z.n / 4;
      c.bands = z.bands;
      if (z.bands < 31) {
        c.wavelength_start_nm = 450;
        c.wavelength_step_nm = 100;
      }
      c.sensor_distance_m = 0.05 * double(z.n) / 1024.0;  // the paper's NA and sampling ratio
      c.read_noise_sigma = 0;
      c.validate();
      CAPTURE(describe(c));
      const Map2D h = lens_design(c, 550);
      auto t0 = std::chrono::steady_clock::now();
      auto secs = [&t0] {
        const double v = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        t0 = std::chrono::steady_clock::now();
        return v;
      };
      const RealStack want = ref::psf_sensor_stack(c, h);
      MESSAGE("N = " << c.n << ": CPU reference " << secs() << " s");
      for (Precision p : {Precision::F32, Precision::F64}) {
        CAPTURE(to_string(p));
        Simulator sim(runtime(), c, p);
        sim.set_heights(h);
        sim.compute_psf();
        MESSAGE("N = " << c.n << " " << to_string(p) << ": set-up and PSF " << secs() << " s (includes building FFT kernels)");
        const RealStack got = sim.psf_sensor();
        check_unit_planes(got, p == Precision::F64 ? 1e-11 : 1e-4, "large N");
        const double e = rel_l2(got.data, want.data);
        CAPTURE(e);
        MESSAGE("N = " << c.n << " " << to_string(p) << ": rel. L2 vs CPU reference " << e << "; "
                       << sim.sampling().summary());
        CHECK(e <= (p == Precision::F64 ? 1e-9 : 1e-4));
        for (const auto& b : sim.sampling().bands) {
          CHECK(b.aliased_energy_fraction >= 0);
          CHECK(b.aliased_energy_fraction <= 1);
          CHECK(b.energy_outside_window >= 0);
          CHECK(b.energy_outside_window <= 1);
        }
      }
    }
  }

  TEST_CASE("kill -9 of `qdo design` at any point: the last checkpoint loads and resumes bit-identically, no half-written file [slow]") {
    const auto dir = temp_dir("stress_kill");
    const std::string cfg = (dir / "cfg.json").string();
    write_text_atomic(cfg, config_to_json_text(tiny_config(32, 3)));
    auto args = [&](const std::string& out, bool resume) {
      std::vector<std::string> a = {QDO_QDO_BINARY, "design", "--config", cfg, "--mode", "qdo+a", "--levels", "4",
                                    "--objective", "psf-target", "--target", "lens:500", "--init", "random", "--seed", "3",
                                    "--epochs", "30", "--steps-per-epoch", "10", "--t0", "3", "--t1", "20",
                                    "--checkpoint-every", "7", "--precision", "f64", "--out", out};
      if (resume) a.push_back("--resume");
      return a;
    };
    const std::string log = (dir / "log.txt").string();
    const std::string ref_run = (dir / "ref").string(), run = (dir / "run").string();
    {
      Child ref(args(ref_run, false), log);
      REQUIRE(ref.exit_code() == 0);
    }
    const long total = 300;
    // Everything in the run folder that is not a temporary file is complete and readable.
    auto check_folder = [&](int round) {
      CAPTURE(round);
      std::size_t temps = 0;
      if (!fs::exists(run)) return;  // killed before the folder was made
      for (const auto& e : fs::directory_iterator(run)) {
        const std::string f = e.path().string(), name = e.path().filename().string();
        CAPTURE(name);
        if (name.find(".tmp-") != std::string::npos) {
          ++temps;  // a write the kill interrupted: never under the final name
          continue;
        }
        if (name == "checkpoint.h5") {
          CHECK(input_error([&] { load_checkpoint(f, 16, 4); }).empty());
        } else if (name == "design.h5" || name == "design_full.h5") {
          CHECK(input_error([&] { read_design(f); }).empty());
        } else if (name == "psf.h5") {
          CHECK(input_error([&] { h5_read(f, "/psf"); }).empty());
        } else if (name == "prior.h5") {
          CHECK(input_error([&] { h5_has(f, "/cov"); }).empty());
        } else if (name == "config.json") {
          CHECK(input_error([&] { design_run_options_from_json(slurp(f), f); }).empty());
        } else if (name == "log.csv") {
          const std::string text = slurp(f);
          CHECK((!text.empty() && text.back() == '\n'));
          std::istringstream in(text);
          std::string line;
          std::getline(in, line);
          CHECK(line.rfind("step,", 0) == 0);
          long prev = -1, rows = 0;  // rows are numbered from step 0
          while (std::getline(in, line)) {
            const long st = std::stol(line.substr(0, line.find(',')));
            CHECK(st > prev);  // complete rows, in order, none repeated
            CHECK(std::count(line.begin(), line.end(), ',') == 6);
            prev = st;
            ++rows;
          }
          // After the last resume every step has exactly one row (the log is written before the
          // checkpoint, so no kill leaves a gap).
          if (round == 99) CHECK(rows == total);
        } else if (e.path().extension() == ".png") {
          png_image img;
          std::memset(&img, 0, sizeof img);
          img.version = PNG_IMAGE_VERSION;
          bool ok = png_image_begin_read_from_file(&img, f.c_str()) != 0;
          if (ok) {
            img.format = PNG_FORMAT_RGB;
            std::vector<unsigned char> buf(PNG_IMAGE_SIZE(img));
            ok = png_image_finish_read(&img, nullptr, buf.data(), 0, nullptr) != 0;
          }
          png_image_free(&img);
          CHECK(ok);
        }
      }
      if (temps) MESSAGE("round " << round << ": " << temps << " temporary file(s) left by the kill (ignored by resume)");
    };
    // Kill after a growing delay past the latest checkpoint (round 0 also before the first
    // one), resuming from whatever is on disk, until the run completes on its own.
    int kills = 0;
    for (int round = 0; round < 12; ++round) {
      const bool resume = fs::exists(fs::path(run) / "checkpoint.h5");
      long before = -1;
      if (resume) before = load_checkpoint((fs::path(run) / "checkpoint.h5").string(), 16, 4).step;
      Child child(args(run, resume), log);
      if (round < 8) {
        const auto ck = fs::path(run) / "checkpoint.h5";
        // Wait for the process to make progress (a new checkpoint), or to finish.
        for (int t = 0; t < 6000 && child.running(); ++t) {
          std::error_code ec;
          if (round == 0 && t >= 5) break;  // round 0: early, during start-up
          if (fs::exists(ck, ec) && load_checkpoint_step_changed(ck.string(), before)) break;
          std::this_thread::sleep_for(std::chrono::milliseconds(5));
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(3 * round * round));
        if (child.running()) {
          child.kill9();
          ++kills;
          check_folder(round);
          continue;
        }
      }
      CHECK(child.exit_code() == 0);
      break;
    }
    CHECK(kills >= 4);
    check_folder(99);
    const DesignState a = load_checkpoint(ref_run + "/checkpoint.h5", 16, 4), b = load_checkpoint(run + "/checkpoint.h5", 16, 4);
    CHECK(b.step == total);
    CHECK(a.w == b.w);
    CHECK(a.offsets == b.offsets);
    CHECK(a.adam_w.v == b.adam_w.v);
    CHECK(read_design(ref_run + "/design.h5").height_m.data == read_design(run + "/design.h5").height_m.data);
    fs::remove_all(dir);
  }

  // =====================================================================================
  // 5. Workflow: one sweep folder, several processes, kills, changed options
  // =====================================================================================

  TEST_CASE("two `qdo sweep` at once on one folder: one writer per run folder; the other is refused naming the holder's pid, or both finish alike") {
    // What the code guarantees: the sweep takes no lock of its own; run_design holds RUN/.lock
    // (RunLock) while it writes a run folder, so a run folder has one writer at a time. A sweep
    // that finds one locked stops, exit 2, naming the holder's pid. One that comes to a run
    // folder after the other has released it goes on (resuming a finished run does no steps)
    // and finishes with the same values; if the other made the checkpoint between this one's
    // look and its lock, it stops, exit 2, asking for --resume (rerunning the sweep goes on).
    // Cells are written atomically (temporary file + rename) by either, with the same values.
    const ReferenceSweep& ref = reference_sweep();
    const auto dir = temp_dir("stress_sweep_two");
    const fs::path out = dir / "sweep";
    const std::string log_a = (dir / "a.txt").string(), log_b = (dir / "b.txt").string();
    const auto t0 = std::chrono::steady_clock::now();
    Child a(sweep_args(ref.cfg.string(), out.string()), log_a);
    Child b(sweep_args(ref.cfg.string(), out.string()), log_b);
    const pid_t pa = a.pid(), pb = b.pid();
    const int ca = a.exit_code(), cb = b.exit_code();
    const double both_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    const std::string ta = slurp(log_a), tb = slurp(log_b);
    CAPTURE(ta);
    CAPTURE(tb);
    auto refused_by = [&](const std::string& text, pid_t holder) {
      return has(text, "locked by pid " + std::to_string(holder) + " ") || has(text, "this one holds one: continue it with --resume");
    };
    CHECK((ca == 0 || ca == 2));
    CHECK((cb == 0 || cb == 2));
    CHECK((ca == 0 || cb == 0));
    if (ca == 2) CHECK(refused_by(ta, pb));
    if (cb == 2) CHECK(refused_by(tb, pa));
    MESSAGE("two sweeps at once: exit codes " << ca << " and " << cb << " (" << both_s << " s; one alone: " << ref.seconds << " s)");
    // Nothing half-written; the tables parse and hold the values of an uninterrupted sweep.
    CHECK(temp_files(out) == 0);
    CHECK(sweep_table_values(out) == ref.values);
    for (const char* run : {"do", "qdo_L2"}) {
      const fs::path r = out / "runs" / run;
      CHECK(fs::exists(r / "DONE"));
      CHECK(input_error([&] { load_resume_state(r.string()); }).empty());
    }
    // The refused one, run again, finds everything done and writes the same tables.
    Child again(sweep_args(ref.cfg.string(), out.string()), (dir / "again.txt").string());
    CHECK(again.exit_code() == 0);
    CHECK(sweep_table_values(out) == ref.values);
    CHECK(temp_files(out) == 0);
    fs::remove_all(dir);
  }

  TEST_CASE("kill -9 of `qdo sweep` during a run, between runs and during the second run: the rerun completes with the values of an uninterrupted sweep") {
    const ReferenceSweep& ref = reference_sweep();
    const auto dir = temp_dir("stress_sweep_kill");
    const fs::path out = dir / "sweep";
    const std::string log = (dir / "log.txt").string();
    // Kill as soon as each of these appears: the DO run's step-10 checkpoint (2 steps left, to be
    // resumed), the DO run finished, the qdo run's step-10 checkpoint.
    const std::vector<fs::path> kill_when = {out / "runs" / "do" / "checkpoint.h5", out / "runs" / "do" / "DONE",
                                             out / "runs" / "qdo_L2" / "checkpoint.h5"};
    int kills = 0;
    const auto t0 = std::chrono::steady_clock::now();
    for (const fs::path& when : kill_when) {
      CAPTURE(when.string());
      Child c(sweep_args(ref.cfg.string(), out.string()), log);
      while (c.running() && !fs::exists(when)) std::this_thread::sleep_for(std::chrono::milliseconds(1));
      if (c.running()) {
        c.kill9();
        ++kills;
      } else {
        CHECK(c.exit_code() == 0);  // finished before the kill point: nothing to kill
      }
    }
    Child last(sweep_args(ref.cfg.string(), out.string()), log);
    const int code = last.exit_code();
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    INFO(slurp(log));
    REQUIRE(code == 0);
    CHECK(kills >= 2);
    MESSAGE(kills << " kills, then the completing run: " << seconds << " s in all (one uninterrupted sweep: " << ref.seconds << " s); "
                  << temp_files(out) << " temporary file(s) left by the kills (ignored)");
    CHECK(sweep_table_values(out) == ref.values);
    for (const char* run : {"do", "qdo_L2"}) {
      const ResumeState st = load_resume_state((out / "runs" / run).string());
      CHECK(st.state.step == 12);
      CHECK(st.log_rows.size() == 12);  // one log row per step, none lost or repeated by the kills
    }
    fs::remove_all(dir);
  }

  TEST_CASE("`qdo sweep` with other --epochs on a finished sweep folder: exit 2 naming the field, nothing deleted or rewritten") {
    const ReferenceSweep& ref = reference_sweep();
    const auto dir = temp_dir("stress_sweep_opts");
    const fs::path out = dir / "sweep";
    fs::copy(ref.out, out, fs::copy_options::recursive);
    const auto before = folder_listing(out);
    const std::string log = (dir / "log.txt").string();
    Child c(sweep_args(ref.cfg.string(), out.string(), "5"), log);
    const int code = c.exit_code();
    const std::string text = slurp(log);
    CAPTURE(text);
    CHECK(code == 2);
    CHECK(has(text, "design.epochs: stored 4, given 5"));
    CHECK(has(text, (out / "runs" / "do" / "config.json").string()));
    CHECK(folder_listing(out) == before);  // every file still there, same size, same time
    fs::remove_all(dir);
  }
}
