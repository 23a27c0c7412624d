// Shared pieces of the qdo command line: option parsing, configuration and design loading,
// and a registry so each command can live in its own file (src/cli/*.cpp).
#pragma once
#include <chrono>
#include <functional>
#include <map>
#include <set>
#include <string>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/design/design_run_options.hpp"
#include "qdo/design/psf_spec.hpp"
#include "qdo/fab/fab_outputs.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/physics/camera.hpp"
#include "qdo/runtime/parse.hpp"
#include "qdo/runtime/types.hpp"
#include "qdo/runtime/util.hpp"

namespace qdo {
struct GradcheckRow;  // qdo/design/gradcheck.hpp
}  // namespace qdo

namespace qdo::cli {

// The parsed command line of one command. `opt` holds exactly the options given on the command
// line (flags as "yes"), so has() means "given explicitly" (check_resume_options relies on it);
// get() falls back to the command table's default, then to `def`.
struct Args {
  std::map<std::string, std::string> opt;                 // given explicitly
  std::map<std::string, std::string> defaults;            // the command table's defaults
  std::map<std::string, std::vector<std::string>> multi;  // repeatable options, every value in order
  std::string positional;                                 // RUN, RUN|DESIGN.h5 (commands that take one)
  std::string command;                                    // the command's name ("psf", "design", ...)
  std::string get(const std::string& k, const std::string& def = "") const {
    auto it = opt.find(k);
    if (it != opt.end()) return it->second;
    auto d = defaults.find(k);
    return d != defaults.end() && !d->second.empty() ? d->second : def;
  }
  bool has(const std::string& k) const { return opt.count(k) > 0; }
};

// --- The command table ------------------------------------------------------------------------
// Every command declares itself in its own file (src/cli/cmd_*.cpp) with a RegisterCommand: its
// name, one-line summary, positional argument (if any) and each option once: name (without --), a
// one-line description with units and allowed values, the default ("" = none, or computed by the
// command as described), and whether it is a flag (--name alone) or repeatable (--name V1 --name V2).
// Options several commands share are in options.hpp. main() (commands.cpp) only dispatches.
struct OptionSpec {
  std::string name, help, def;
  bool flag = false;
  bool repeat = false;
};
struct CommandSpec {
  std::string name, summary;
  std::string positional, positional_help;  // e.g. "RUN": a required positional argument
  std::vector<OptionSpec> options;
  std::function<int(const Args&)> run;
  bool writes_as_it_goes = false;  // long, resumable commands; the others stage their outputs (OutputStage)
  std::string memory_advice{};     // what to reduce when the command runs out of host memory ("" = the general advice)
};
// Registers a command at static initialisation: `const RegisterCommand r(order, [] { return
// CommandSpec{...}; });` in the command's file. `order` places it in `qdo --help`; the spec is
// made on the first look-up. Every command whose options include --out also gets --into-existing.
struct RegisterCommand {
  RegisterCommand(int order, std::function<CommandSpec()> make);
};
// The registered commands in help order (a std::logic_error names a name registered twice).
const std::vector<CommandSpec>& command_table();
const CommandSpec* find_command(const std::string& name);
// Parses argv[2..] (argv[1] is the command) against the command's table entry with CLI11.
// Returns false when --help / -h was given (the command's help printed to stdout). An unknown
// option, a missing value or a stray argument is an InputError naming it and what is allowed.
bool parse_command_line(const CommandSpec& c, int argc, char** argv, Args& out);
// The command's help text (usage, options with descriptions and defaults).
std::string command_help(const CommandSpec& c);
// Registers the on-demand loader of the LibTorch plugin (net_plugin.cpp).
void register_net_plugin_loader();

// The gradient check's table on stdout (parameter group, max relative error, tolerance, ok/FAIL);
// 0 when every group passes, 5 otherwise (cmd_gradcheck.cpp; also qdo design --check-gradients).
int print_gradcheck(const std::vector<GradcheckRow>& rows);

// The configuration from --config or --preset (default small), the camera response checked too.
// A configuration of several object points is refused unless allow_points (qdo design: a design
// over a range of points).
SystemConfig load_config(const Args& a, bool allow_points = false);
// --scene builtin (the configuration's chart scene, the default), a cube file (.mat / .h5,
// read_cube with --key) or a folder of PNG bands, checked to have cfg.bands bands: bands x H x W.
// A band axis stored in the file must match cfg's (refused naming both grids; interpolated
// with --resample-bands); the radiance rule (conform_radiance) applies.
RealStack scene_from_args(const SystemConfig& cfg, const Args& a);
// (A path given otherwise, qdo reconstruct --truth: read_scene, scenes.hpp.)
// Numbers and on/off switches of options: parse_int, parse_double, parse_on_off (qdo/runtime/parse.hpp).
// The scene sources of option `name` (comma-separated): dataset names resolved under the data root
// (data_root.hpp), paths checked to exist; an InputError naming --name otherwise. Empty when the
// option is not given and has no default.
std::vector<std::string> scene_paths(const Args& a, const std::string& name);
// lens:NM, flat, or an HDF5 design file matching the configuration's grid.
Map2D load_design(const SystemConfig& cfg, const std::string& spec);
struct QuantSpec {
  bool active = false;
  Quantizer q;
};
QuantSpec load_quantizer(const Args& a);
Map2D design_heights(const SystemConfig& cfg, const Args& a, QuantSpec* qs_out = nullptr);
// The PSF of simulate and image, decided and checked before any device work (psf_spec.hpp):
// --psf FILE (the file's stack, checked against the configuration's bands and sensor grid) or
// --design (heights, quantized by --levels when given, simulated once the device is up). Exactly
// one of the two.
PsfInput psf_input(const SystemConfig& cfg, const Args& a);
// RUN|DESIGN.h5 (the positional) of export, tolerance and fabricate: a run folder, whose
// config.json leaves no room for --preset or --config, or a design .h5 file read with the
// configuration they give (fab_outputs.hpp: read_design_source).
fab::DesignSource fab_source(const Args& a, bool check_grid);
// The command's --out folder under the one rule for output folders (claim_output_dir, io.hpp:
// new, empty or the same command's; another's or a user's only with --into-existing).
std::string out_dir(const Args& a, const std::string& def = "");
// The same rule for a folder the command takes from another option or computes.
void claim_out(const Args& a, const std::string& dir);
// The options of `qdo design` (also used by gradcheck and sweep); --mode and --out as given.
// The defaults written in the shared helpers (here, load_config, load_quantizer, scene_from_args)
// apply only to options a command's table entry does not declare (e.g. --levels in qdo sweep);
// otherwise the table's default is what a.get() returns.
// With `range` (qdo design): a configuration of several object points is taken, and
// --object-distances (metres or inf), --field-angles (degrees: A or X:Y, comma-separated) and
// --points-per-step build and sample them (range_options).
DesignRunOptions design_options(const Args& a, bool range = false);
// qdo design's object-point options on o.cfg and o.design.points_per_step: --object-distances and
// --field-angles replace the configuration's points by object_point_grid(distances, angles)
// (distances default to the configuration's one distance, angles to 0); each distance > 0 m or
// inf, each angle within max_field_angle_deg at every distance (the refusal names the limit),
// --points-per-step in 1 .. P. InputError naming the option otherwise, before any work.
void range_options(const Args& a, DesignRunOptions& o);
// --object-distances and --field-angles into c.object_points (every distance under every angle,
// each angle checked against the sampling at each distance); refused when c already lists points.
void object_point_options(const Args& a, SystemConfig& c);
// With --resume: every option given explicitly that differs from RUN/config.json is an
// InputError listing "--option: stored X, given Y" (--max-steps, --device, --out,
// --check-gradients may differ).
void check_resume_options(const Args& a, const DesignRunOptions& given);

}  // namespace qdo::cli
