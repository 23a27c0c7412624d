// Shared pieces of the qdo command line: the parsed options (Args), a registry so each command can
// live in its own file (src/cli/cmd_*.cpp), the output-folder rule, and the options several
// commands share, declared once (options.cpp: each returns the option's name without --, its
// one-line description with units and allowed values, and its default).
#pragma once
#include <functional>
#include <map>
#include <string>
#include <vector>

#include "qdo/design/option_inputs.hpp"
#include "qdo/runtime/parse.hpp"
#include "qdo/runtime/types.hpp"
#include "qdo/runtime/util.hpp"

namespace qdo::cli {

// The parsed command line of one command: the options as typed (TextOptions: `opt` holds exactly
// the options given, flags as "yes"; `defaults` the command table's; `multi` every value of a
// repeatable option), the positional argument and the command's name.
struct Args : TextOptions {
  std::string positional;                                 // RUN, RUN|DESIGN.h5 (commands that take one)
  std::string command;                                    // the command's name ("psf", "design", ...)
};

// --- The command table ------------------------------------------------------------------------
// Every command declares itself in its own file (src/cli/cmd_*.cpp) with a RegisterCommand: its
// name, one-line summary, positional argument (if any) and each option once: name (without --), a
// one-line description with units and allowed values, the default ("" = none, or computed by the
// command as described), and whether it is a flag (--name alone) or repeatable (--name V1 --name V2).
// Options several commands share are declared once (opts, below). main() (commands.cpp) only dispatches.
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
// (The table, its parsing with CLI11 and the help are commands.cpp's.)
// Registers the on-demand loader of the LibTorch plugin (net_plugin.cpp).
void register_net_plugin_loader();

// The shared inputs are read by the library (qdo/design/option_inputs.hpp: config_from_options,
// scene_from_options, design_heights_from_options, psf_input_from_options, ...); numbers and
// switches by qdo/runtime/parse.hpp.
// The command's --out folder under the one rule for output folders (claim_output_dir, io.hpp:
// new, empty or the same command's; another's or a user's only with --into-existing).
std::string out_dir(const Args& a, const std::string& def = "");
// The same rule for a folder the command takes from another option or computes.
void claim_out(const Args& a, const std::string& dir);

}  // namespace qdo::cli

namespace qdo::cli::opts {

// A value option (def "": no default, or one the command computes as its description says) and a flag.
OptionSpec opt(const std::string& name, const std::string& help, const std::string& def = "");
OptionSpec flag(const std::string& name, const std::string& help);

OptionSpec preset();
OptionSpec config();
OptionSpec device();
// --model-padding (qdo fit, qdo fabricate): the built camera's model window (apply_model_padding).
OptionSpec model_padding();
OptionSpec precision();
OptionSpec placement();
OptionSpec design_spec();
OptionSpec psf_file();
OptionSpec levels_post();
OptionSpec out_dir_opt();
OptionSpec save_opt();
OptionSpec compress();
OptionSpec scene();
OptionSpec key();
OptionSpec resample_bands();
OptionSpec data(const std::string& what);
OptionSpec object_distances(const std::string& what, const std::string& role);
OptionSpec field_angles(const std::string& what);
OptionSpec data_root();
OptionSpec synthetic_scenes(const std::string& def);
OptionSpec seed();
OptionSpec parameterization();
OptionSpec objective();
OptionSpec target();
// The options of the optimisation (qdo design; qdo sweep, qdo demo and qdo gradcheck take some).
std::vector<OptionSpec> training_options();
// How raw point-source frames are reduced (qdo calibrate, qdo fit --frames): hot-sigma, min-snr, min-response.
std::vector<OptionSpec> frame_reduction_options();
std::vector<OptionSpec> concat(std::vector<OptionSpec> a, const std::vector<OptionSpec>& b);

}  // namespace qdo::cli::opts
