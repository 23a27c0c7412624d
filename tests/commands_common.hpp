// Helpers shared by the end-to-end tests of the qdo commands (doctest suite "commands",
// tests/test_commands_*.cpp), which run every command on a tiny configuration (N = 32, 3 bands)
// as a user would (the qdo binary through the shell).
//
// One qdo+a run (`qdo design --max-steps 2`) is made on first use and shared by the cases that
// consume a run folder (eval, sweep-psf --adaptive-from, tolerance, export, simulate).
// No case needs ../shared. Warm, the suite takes about 15-25 s on 2 CPU cores (PoCL).
#pragma once
#include <nlohmann/json.hpp>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <system_error>
#include <vector>

#include "common.hpp"
#include "qdo/data/config.hpp"
#include "qdo/data/io.hpp"

namespace qdo::test::commands_suite {

inline nlohmann::json read_json(const std::filesystem::path& p) { return nlohmann::json::parse(slurp(p)); }

// Data rows of a CSV file (lines after the header, empty lines ignored).
inline std::size_t csv_rows(const std::filesystem::path& p) {
  std::istringstream s(slurp(p));
  std::string line;
  std::size_t n = 0;
  std::getline(s, line);
  while (std::getline(s, line))
    if (!line.empty()) ++n;
  return n;
}

// The tiny system of the other tests (tiny_config: N = 32, 3 bands), as a --config file.
inline SystemConfig tiny() { return tiny_config(32, 3); }

// A temporary folder removed when the test binary exits (for the files shared between cases).
struct ScratchDir {
  std::filesystem::path dir;
  explicit ScratchDir(const std::string& tag) : dir(temp_dir(tag)) {}
  ScratchDir(const ScratchDir&) = delete;
  ScratchDir& operator=(const ScratchDir&) = delete;
  ~ScratchDir() {
    std::error_code ec;
    std::filesystem::remove_all(dir, ec);
  }
};

inline const std::filesystem::path& tiny_config_file() {
  static const ScratchDir d("cmd_cfg");
  static const std::filesystem::path p = [] {
    const std::filesystem::path f = d.dir / "tiny.json";
    std::ofstream(f) << config_to_json_text(tiny()) << "\n";
    return f;
  }();
  return p;
}

inline std::string cfg_arg() { return "--config " + tiny_config_file().string(); }

constexpr int kSteps = 2;   // --max-steps of the shared run
constexpr int kLevels = 4;

// The shared qdo+a run: `qdo design --max-steps 2` on the tiny configuration, made once. Recipe qdo
// (random initial heights, no height noise): the commands' tests need a design that uses every
// level and a noiseless evaluation; the release recipe has its own suite (recipe).
struct SharedRun {
  std::filesystem::path dir;
  Run result;
};
inline const SharedRun& shared_run() {
  static const ScratchDir d("cmd_run");
  static const SharedRun r = [] {
    SharedRun s;
    s.dir = d.dir / "run";
    s.result = qdo_run("design " + cfg_arg() + " --recipe qdo --mode qdo+a --levels " + std::to_string(kLevels) +
                       " --epochs 5 --steps-per-epoch 2 --t0 1 --t1 4 --synthetic-scenes 3 --seed 3 --max-steps " +
                       std::to_string(kSteps) + " --out " + s.dir.string());
    return s;
  }();
  return r;
}

// Sum of each plane of a planes x rows x cols dataset.
inline std::vector<double> plane_sums(const H5Dataset& d) {
  REQUIRE(d.shape.size() == 3);
  const std::size_t plane = d.shape[1] * d.shape[2];
  std::vector<double> s(d.shape[0], 0.0);
  for (std::size_t p = 0; p < d.shape[0]; ++p)
    for (std::size_t i = 0; i < plane; ++i) s[p] += d.data[p * plane + i];
  return s;
}

}  // namespace qdo::test::commands_suite
