// bench_util.hpp: small helpers shared by the benchmark programs (bench/*.cpp, bench/net/*.cpp):
// wall-clock timing (steady clock, repeated runs, medians), comma-list splitting, printf-style
// number formatting and machine facts (CPU model, peak resident memory). Header-only.
#pragma once

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <fstream>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "qdo/runtime/util.hpp"

namespace qdo::bench {

using Clock = std::chrono::steady_clock;

using qdo::seconds_since;  // qdo/runtime/util.hpp: seconds elapsed on the steady clock since t0

// Runs f() `warmup` times unmeasured, then `repeats` times measured; the wall times in seconds, sorted ascending.
template <typename F>
std::vector<double> sorted_seconds(int warmup, int repeats, F&& f) {
  for (int i = 0; i < warmup; ++i) f();
  std::vector<double> t;
  for (int i = 0; i < repeats; ++i) {
    const auto t0 = Clock::now();
    f();
    t.push_back(seconds_since(t0));
  }
  std::sort(t.begin(), t.end());
  return t;
}

// Median in seconds of `repeats` runs of f() after `warmup` unmeasured runs (even count: the upper middle run); repeats >= 1.
template <typename F>
double median_seconds(int warmup, int repeats, F&& f) {
  const std::vector<double> t = sorted_seconds(warmup, repeats, std::forward<F>(f));
  return t[t.size() / 2];
}

// Summary of timed runs, all in seconds.
struct Timing {
  double median = 0, min = 0, max = 0;  // seconds
  int runs = 0;
};

// Median (even count: mean of the two middle runs), min, max and count of run times in seconds; all zero when empty.
inline Timing summarize(std::vector<double> t) {
  Timing s;
  if (t.empty()) return s;
  std::sort(t.begin(), t.end());
  const std::size_t k = t.size();
  s.median = k % 2 ? t[k / 2] : 0.5 * (t[k / 2 - 1] + t[k / 2]);
  s.min = t.front();
  s.max = t.back();
  s.runs = static_cast<int>(k);
  return s;
}

// summarize() (seconds) of `repeats` runs of f() after `warmup` unmeasured runs.
template <typename F>
Timing time_it(int warmup, int repeats, F&& f) {
  return summarize(sorted_seconds(warmup, repeats, std::forward<F>(f)));
}

using qdo::split_items;  // qdo/runtime/util.hpp: the items between the separators, empty ones dropped

// v formatted by the printf format f (one double conversion, e.g. "%.3f"); at most 63 characters.
inline std::string fmt(const char* f, double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, f, v);
  return buf;
}

// The first "model name" of /proc/cpuinfo without its label and leading blanks; "unknown CPU" when there is none.
inline std::string cpu_model() {
  std::ifstream in("/proc/cpuinfo");
  for (std::string line; std::getline(in, line);)
    if (line.rfind("model name", 0) == 0) {
      const auto c = line.find(':');
      if (c == std::string::npos) continue;
      const auto b = line.find_first_not_of(" \t", c + 1);
      return b == std::string::npos ? std::string() : line.substr(b);
    }
  return "unknown CPU";
}

// Peak resident memory of this process in KiB (VmHWM of /proc/self/status); -1 when unavailable.
inline long peak_rss_kib() {
  std::ifstream f("/proc/self/status");
  for (std::string line; std::getline(f, line);)
    if (line.rfind("VmHWM:", 0) == 0) return std::stol(line.substr(6));
  return -1;
}

}  // namespace qdo::bench
