// The options several of qdo's commands share, declared once (options.cpp): a command's
// registration (cmd_*.cpp) lists them beside its own. Each returns the option's name (without --),
// its one-line description with units and allowed values, and its default.
#pragma once
#include <string>
#include <vector>

#include "cli.hpp"

namespace qdo::cli::opts {

// A value option (def "": no default, or one the command computes as its description says) and a flag.
OptionSpec opt(const std::string& name, const std::string& help, const std::string& def = "");
OptionSpec flag(const std::string& name, const std::string& help);

OptionSpec preset();
OptionSpec config();
OptionSpec device();
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
OptionSpec noise_sigma(const std::string& help, const std::string& def);
OptionSpec seed();
OptionSpec psf_path();
OptionSpec mode();
OptionSpec parameterization();
OptionSpec objective();
OptionSpec target();
// The options of the optimisation (qdo design; qdo sweep, qdo demo and qdo gradcheck take some).
std::vector<OptionSpec> training_options();
std::vector<OptionSpec> concat(std::vector<OptionSpec> a, const std::vector<OptionSpec>& b);

}  // namespace qdo::cli::opts
