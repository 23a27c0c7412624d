// Helpers shared by the test files.
#pragma once
#include "qdo/runtime/error.hpp"
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <complex>
#include <cstdlib>
#include <fstream>
#include <sstream>
#include <sys/wait.h>
#include <filesystem>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "qdo/physics/camera.hpp"
#include "qdo/data/config.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo::test {

// One Runtime for the whole test binary (device from QDO_DEVICE, PoCL in CI).
inline Runtime& runtime() {
  static Runtime rt;
  return rt;
}

constexpr double kEps32 = 1.1920929e-7;  // float32 unit roundoff x 2 (machine epsilon)
constexpr double kEps64 = 2.220446e-16;

inline double eps(Precision p) { return p == Precision::F64 ? kEps64 : kEps32; }

// ||a - b|| / ||b|| over all elements, and the index of the worst element (for reports).
template <typename T>
struct Diff {
  double rel_l2 = 0, max_abs = 0;
  std::size_t worst = 0;
};
template <typename T>
Diff<T> diff(const std::vector<T>& a, const std::vector<T>& b) {
  Diff<T> d;
  double num = 0, den = 0;
  REQUIRE(a.size() == b.size());
  for (std::size_t i = 0; i < a.size(); ++i) {
    const double e = std::abs(a[i] - b[i]);
    num += e * e;
    den += std::abs(b[i]) * std::abs(b[i]);
    if (e > d.max_abs) {
      d.max_abs = e;
      d.worst = i;
    }
  }
  d.rel_l2 = den > 0 ? std::sqrt(num / den) : std::sqrt(num);
  return d;
}

// The largest |v_i|, and the largest |a_i - b_i| (same sizes required).
inline double max_abs(const std::vector<double>& v) {
  double m = 0;
  for (double e : v) m = std::max(m, std::fabs(e));
  return m;
}
inline double max_abs_diff(const std::vector<double>& a, const std::vector<double>& b) {
  REQUIRE(a.size() == b.size());
  double m = 0;
  for (std::size_t i = 0; i < a.size(); ++i) m = std::max(m, std::fabs(a[i] - b[i]));
  return m;
}

// Seeded radial starting parameters for design tests: N/2 ring heights, uniform in
// [0.15, 0.85] h_max (metres).
inline std::vector<double> start_params(const SystemConfig& c, unsigned seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0.15, 0.85);
  std::vector<double> p(c.n / 2);
  for (double& v : p) v = u(rng) * c.h_max_m();
  return p;
}

// A small configuration for kernel-vs-reference tests: N x N grid, few bands.
// The camera's options that skip nothing (SkipOptions::exact): images of the unskipped camera
// operator, to the rounding of the precision.
inline SkipOptions no_skipping() {
  SkipOptions o;
  o.exact = true;
  return o;
}

inline SystemConfig tiny_config(std::size_t n = 32, std::size_t bands = 3) {
  SystemConfig c = preset_config("small");
  c.n = n;
  c.padding_px = n / 4;
  c.bands = bands;
  c.wavelength_start_nm = 450;
  c.wavelength_step_nm = bands > 1 ? 100.0 / double(bands - 1) : 10.0;
  c.sensor_distance_m = 0.0125 * double(n) / 256.0;
  c.srf_interpolate = true;
  c.validate();
  return c;
}

inline Map2D random_heights(std::size_t n, double h_max, unsigned seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0.0, h_max);
  Map2D h(n, n);
  for (auto& v : h.data) v = u(rng);
  return h;
}

inline RealStack random_cube(std::size_t b, std::size_t h, std::size_t w, unsigned seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  RealStack c(b, h, w);
  for (auto& v : c.data) v = u(rng);
  return c;
}

// Uniform random stack in [lo, hi] (seeded).
inline RealStack uniform_stack(std::size_t p, std::size_t r, std::size_t c, unsigned seed, double lo = -1, double hi = 1) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(lo, hi);
  RealStack s(p, r, c);
  for (auto& v : s.data) v = u(rng);
  return s;
}

// A smooth design well inside (0, h_max) so finite differences never hit the clamp.
inline Map2D smooth_heights(const SystemConfig& c, unsigned seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0, 2 * M_PI);
  const double a = u(rng), b = u(rng);
  Map2D h(c.n, c.n);
  for (std::size_t i = 0; i < c.n; ++i)
    for (std::size_t j = 0; j < c.n; ++j)
      h(i, j) = c.h_max_m() * (0.5 + 0.3 * std::sin(0.37 * double(i) + a) * std::cos(0.23 * double(j) + b));
  return h;
}

// Largest |phase| the DOE stage evaluates: source term plus DOE term at the shortest band.
inline double max_phase(const SystemConfig& c) {
  const double r = c.aperture_radius();
  const double k = 2 * M_PI / (c.wavelength_start_nm * 1e-9);
  const double src = c.scene_at_infinity ? 0 : r * r / (std::sqrt(r * r + c.scene_distance_m * c.scene_distance_m) + c.scene_distance_m);
  return k * (src + 0.6 * 2 * c.h_max_m());
}

inline std::filesystem::path temp_dir(const std::string& tag) {
  auto p = std::filesystem::temp_directory_path() / ("qdo_test_" + tag + "_" + std::to_string(std::random_device{}()));
  std::filesystem::create_directories(p);
  return p;
}

inline const char* shared_dir() { return QDO_SHARED_DIR; }
inline bool have_shared() { return std::filesystem::exists(std::string(QDO_SHARED_DIR) + "/data/hsi/cave"); }

// The qdo tool run as a user would: `env_prefix qdo args` in a shell, stdout and stderr captured.
struct Run {
  int code = -1;  // exit status, -1 if the process did not exit normally
  std::string out;
};
inline Run qdo_run(const std::string& args, const std::string& env_prefix = "") {
  const auto dir = temp_dir("qdo_run");
  const std::string log = (dir / "log.txt").string();
  const std::string cmd = env_prefix + " " + std::string(QDO_QDO_BINARY) + " " + args + " > " + log + " 2>&1";
  const int status = std::system(cmd.c_str());
  Run r;
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  std::ifstream f(log);
  std::stringstream ss;
  ss << f.rdbuf();
  r.out = ss.str();
  std::filesystem::remove_all(dir);
  return r;
}

// --- Missing prerequisites (../shared data, KLayout, a float64 device) ----------------------
// A test that cannot run (all or part of itself) for a missing prerequisite says so through
// skip_unless(): the case prints "SKIPPED: <why>", and the test binary then exits with
// kSkipExitCode (CTest's SKIP_RETURN_CODE) unless a case failed, so CTest shows the entry as
// skipped instead of passed. With QDO_REQUIRE_ALL=1 (CI sets it) a missing prerequisite is a
// failure instead. Never `return` from a test without one of these.
constexpr int kSkipExitCode = 77;
inline int& skipped_parts() {
  static int n = 0;
  return n;
}
inline bool require_all() {
  const char* e = std::getenv("QDO_REQUIRE_ALL");
  return e != nullptr && std::string(e) == "1";
}
// True when `have`; otherwise records a skip (or fails under QDO_REQUIRE_ALL=1) and returns false.
// Use as `if (!skip_unless(have_shared(), "no CAVE scenes in ../shared")) return;` or to guard
// one part of a case.
inline bool skip_unless(bool have, const std::string& why) {
  if (have) return true;
  if (require_all()) {
    FAIL_CHECK("missing prerequisite with QDO_REQUIRE_ALL=1: " << why);
    return false;
  }
  ++skipped_parts();
  MESSAGE("SKIPPED: " << why);
  return false;
}

// The precisions a kernel test runs in: float32, and float64 where the device has it (a
// missing float64 is a reported skip, a failure under QDO_REQUIRE_ALL=1).
inline std::vector<Precision> device_precisions(const Runtime& rt) {
  std::vector<Precision> ps{Precision::F32};
  if (skip_unless(rt.has_fp64(), "float64 cases: the device has no float64")) ps.push_back(Precision::F64);
  return ps;
}

// A file's bytes ("" when it cannot be read).
inline std::string slurp(const std::filesystem::path& p) {
  std::ifstream f(p, std::ios::binary);
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

// The message of the InputError that f throws, or a marker when it throws none.
template <typename F>
std::string input_error_of(F&& f) {
  try {
    f();
  } catch (const InputError& e) {
    return e.what();
  }
  return "<no InputError thrown>";
}

}  // namespace qdo::test
