// Shared pieces of the qdo command line: option parsing, configuration and design loading,
// and a registry so each command can live in its own file (src/cli/*.cpp).
#pragma once
#include <chrono>
#include <functional>
#include <map>
#include <set>
#include <string>
#include <vector>

#include "qdo/config.hpp"
#include "qdo/design_run.hpp"
#include "qdo/doe.hpp"
#include "qdo/imaging.hpp"
#include "qdo/types.hpp"

namespace qdo::cli {

struct Args {
  std::map<std::string, std::string> opt;
  std::string get(const std::string& k, const std::string& def = "") const {
    auto it = opt.find(k);
    return it == opt.end() ? def : it->second;
  }
  bool has(const std::string& k) const { return opt.count(k) > 0; }
};

// Options take a value (--name VALUE or --name=VALUE), except those in `flags` (--name alone).
// argv[1] is the command; parsing starts at argv[2]. Unknown options are an InputError.
Args parse_args(int argc, char** argv, const std::set<std::string>& allowed, const std::string& cmd,
                const std::set<std::string>& flags = {});
// The configuration from --config or --preset (default small), the camera response checked too.
SystemConfig load_config(const Args& a);
// --scene builtin (the configuration's chart scene, the default), a cube file (.mat / .h5,
// read_cube with --key) or a folder of PNG bands, checked to have cfg.bands bands: bands x H x W.
// A band axis stored in the file must match cfg's (refused naming both grids; interpolated
// with --resample-bands); the radiance rule (conform_radiance) applies.
RealStack scene_from_args(const SystemConfig& cfg, const Args& a);
int parse_int(const std::string& name, const std::string& v, int lo, int hi);
double parse_double(const std::string& name, const std::string& v);
std::vector<std::string> split_list(const std::string& s);  // comma-separated
// lens:NM, flat, or an HDF5 design file matching the configuration's grid.
Map2D load_design(const SystemConfig& cfg, const std::string& spec);
struct QuantSpec {
  bool active = false;
  Quantizer q;
};
QuantSpec load_quantizer(const Args& a);
Map2D design_heights(const SystemConfig& cfg, const Args& a, QuantSpec* qs_out = nullptr);
std::string out_dir(const Args& a, const std::string& def = "");  // creates it (make_output_dir)
// "sensor: 0.12 % of values clipped at full scale (max 1.3 before clipping)" or "... none clipped".
std::string clip_summary(const SensorClip& c);
double seconds_since(std::chrono::steady_clock::time_point t0);
// The options of `qdo design` (also used by gradcheck and sweep); --mode and --out as given.
DesignRunOptions design_options(const Args& a);
// With --resume: every option given explicitly that differs from RUN/config.json is an
// InputError listing "--option: stored X, given Y" (--max-steps, --device, --out,
// --check-gradients may differ).
void check_resume_options(const Args& a, const DesignRunOptions& given);

// Command registry: a file registers its commands with a static Registrar, e.g.
//   static const qdo::cli::Registrar reg("export", cmd_export, "qdo export RUN|DESIGN.h5 ...");
using Command = std::function<int(int argc, char** argv)>;
struct CommandInfo {
  Command run;
  std::string usage;
};
std::map<std::string, CommandInfo>& registry();
struct Registrar {
  Registrar(const std::string& name, Command run, const std::string& usage) { registry()[name] = {std::move(run), usage}; }
};

}  // namespace qdo::cli
