// Helpers shared by the pieces of the stability suite (doctest suite "stress",
// tests/test_stress_*.cpp; the envelope, the invariants and the known limits are in
// STABILITY.md): configurations at the extremes and their invariants, small file helpers for
// hostile input, and a child process running the qdo binary.
#pragma once
#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <complex>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <numeric>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "adjoint_ladder.hpp"  // dot(): the tests' one inner product
#include "common.hpp"
#include "qdo/data/config.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/runtime/types.hpp"

extern char** environ;

namespace qdo::test::stress_suite {

constexpr double kInf = std::numeric_limits<double>::infinity();

// ---------------------------------------------------------------------------------------
// Configurations at the extremes
// ---------------------------------------------------------------------------------------

// tiny_config(n, bands) with the given pitch, scene distance (kInf: plane wave) and sensor
// distance; the sensor pitch is twice the DOE pitch (S = N/2).
inline SystemConfig extreme_config(std::size_t n, double pitch_m, double scene_m, double sensor_m,
                                   std::size_t bands = 3) {
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

inline std::string describe(const SystemConfig& c) {
  return "n=" + to_str(c.n) + " pitch=" + to_str(c.pitch_m) + " d=" + (c.scene_at_infinity ? std::string("inf") : to_str(c.scene_distance_m)) +
         " z=" + to_str(c.sensor_distance_m) + " bands=" + to_str(c.bands) + " pad=" + to_str(c.padding_px) +
         (c.propagator == Propagator::AngularSpectrum ? " asm" : " fresnel");
}

// Every plane finite, non-negative and summing to 1 within sum_tol.
inline void check_unit_planes(const RealStack& s, double sum_tol, const std::string& what) {
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

inline bool all_finite(const std::vector<double>& v) {
  return std::all_of(v.begin(), v.end(), [](double x) { return std::isfinite(x); });
}

inline double rel_l2(const std::vector<double>& a, const std::vector<double>& b) { return diff(a, b).rel_l2; }

inline RealStack random_stack(std::size_t p, std::size_t r, std::size_t c, unsigned seed, double lo = -1,
                              double hi = 1) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(lo, hi);
  RealStack s(p, r, c);
  for (double& v : s.data) v = u(rng);
  return s;
}

// Energy of the propagated field inside the central N x N crop and in the whole window, per band.
inline void window_energies(const ComplexStack& f, const PropagationGeometry& g, std::vector<double>& crop,
                            std::vector<double>& total) {
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

// ---------------------------------------------------------------------------------------
// Files
// ---------------------------------------------------------------------------------------

inline std::string slurp(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}
inline void spit(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out << bytes;
  REQUIRE(out.good());
}

// The InputError message of f(), or "" when f succeeds; any other exception fails the test
// (doctest reports it).
template <typename F>
inline std::string input_error(F&& f) {
  try {
    f();
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}
inline bool has(const std::string& s, const std::string& part) { return s.find(part) != std::string::npos; }

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

// The processes whose parent is `parent` (/proc/PID/stat's fourth field).
inline std::vector<pid_t> children_of(pid_t parent) {
  std::vector<pid_t> out;
  for (const auto& e : std::filesystem::directory_iterator("/proc")) {
    const std::string name = e.path().filename().string();
    if (name.find_first_not_of("0123456789") != std::string::npos) continue;
    std::ifstream f(e.path() / "stat");
    std::string stat((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
    const auto close = stat.rfind(')');
    if (close == std::string::npos) continue;
    std::istringstream rest(stat.substr(close + 2));
    char state = 0;
    long ppid = 0;
    rest >> state >> ppid;
    if (ppid == long(parent)) out.push_back(pid_t(std::stol(name)));
  }
  return out;
}

}  // namespace qdo::test::stress_suite
