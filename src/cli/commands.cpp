// The command registry, parsing and help of qdo's commands: each command registers itself (its
// cmd_*.cpp file); CLI11 parses a command line against its entry into an Args; `qdo --help`,
// `qdo <command> --help` and `qdo --version` are generated from the table here; out_dir and
// claim_out apply the output-folder rule; main() dispatches to the command.
#include <CLI/CLI.hpp>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <set>
#include <sstream>

#include "cli.hpp"
#include "qdo/data/data_root.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/mpi.hpp"
#include "qdo/data/io.hpp"
#include "qdo/runtime/runtime.hpp"

#ifndef QDO_VERSION
#define QDO_VERSION "unknown"
#endif
#ifndef QDO_GIT_REVISION
#define QDO_GIT_REVISION "unknown"
#endif

using namespace qdo;
using namespace qdo::cli;

namespace qdo::cli {
namespace {

std::string option_list(const CommandSpec& c) {
  std::string list;
  for (const auto& o : c.options) list += " --" + o.name;
  return list.empty() ? " none besides --help" : list;
}

const OptionSpec* find_option(const CommandSpec& c, const std::string& name) {
  for (const auto& o : c.options)
    if (o.name == name) return &o;
  return nullptr;
}

// The CLI11 app of one command, bound to `values` (one slot per option).
struct Parser {
  CLI::App app;
  std::map<std::string, std::vector<std::string>> values;
  std::string positional;
  explicit Parser(const CommandSpec& c) : app(c.summary, "qdo " + c.name) {
    app.set_help_flag("-h,--help", "print this command's options and exit");
    app.allow_extras(true);  // unknown options and stray arguments are reported below, naming them
    app.footer("Exit codes: 0 ok, 1 internal error, 2 bad input, 3 refused as inaccurate, 4 device error, "
               "5 gradient check failed, 6 file system error, 7 out of host memory.");
    if (!c.positional.empty()) app.add_option(c.positional, positional, c.positional_help)->type_name("");
    for (const auto& o : c.options) {
      std::string help = o.help;
      if (!o.def.empty()) help += " (default: " + o.def + ")";
      if (o.flag) {
        app.add_flag("--" + o.name)->description(help);  // (name, std::string) would bind the string as the target
      } else {
        std::vector<std::string>& v = values[o.name];
        CLI::Option* x = app.add_option("--" + o.name, v, help)->type_name("VALUE")->expected(1);
        x->multi_option_policy(CLI::MultiOptionPolicy::TakeAll);  // a repeated single option is refused below
        x->allow_extra_args(false);
      }
    }
  }
};


// The registrations, filled at static initialisation (a function-local static, so that it exists
// before the first RegisterCommand of any file runs).
std::vector<std::pair<int, std::function<CommandSpec()>>>& registrations() {
  static std::vector<std::pair<int, std::function<CommandSpec()>>> r;
  return r;
}

std::vector<CommandSpec> make_table() {
  auto regs = registrations();
  std::stable_sort(regs.begin(), regs.end(), [](const auto& x, const auto& y) { return x.first < y.first; });
  std::vector<CommandSpec> t;
  std::set<std::string> names;
  for (const auto& r : regs) {
    CommandSpec c = r.second();
    if (!names.insert(c.name).second) throw std::logic_error("qdo command '" + c.name + "' is registered twice");
    // Every command that writes an output folder takes --into-existing (claim_output_dir, io.hpp).
    const bool folder_out = std::any_of(c.options.begin(), c.options.end(), [](const OptionSpec& o) { return o.name == "out"; });
    if (folder_out && c.name != "quantize")
      c.options.push_back(opts::flag("into-existing", "write into an existing --out folder that qdo did not make, or that another "
                                                      "qdo command made (files of the names this command writes are replaced)"));
    t.push_back(std::move(c));
  }
  return t;
}

// The registered commands in help order (a std::logic_error names a name registered twice).
const std::vector<CommandSpec>& command_table() {
  static const std::vector<CommandSpec> t = make_table();
  return t;
}

const CommandSpec* find_command(const std::string& name) {
  for (const auto& c : command_table())
    if (c.name == name) return &c;
  return nullptr;
}

// Parses argv[2..] (argv[1] is the command) against the command's table entry with CLI11.
// Returns false when --help / -h was given (the command's help printed to stdout). An unknown
// option, a missing value or a stray argument is an InputError naming it and what is allowed.
bool parse_command_line(const CommandSpec& c, int argc, char** argv, Args& out) {
  // A value option with nothing after it (or another option after it) names the option here,
  // before CLI11 sees it.
  for (int i = 2; i < argc; ++i) {
    const std::string s = argv[i];
    if (s == "--") break;
    if (s == "-h" || s == "--help") break;
    if (s.rfind("--", 0) != 0) continue;
    const auto eq = s.find('=');
    if (eq != std::string::npos) {  // --name= with nothing after it: an empty value, refused as below
      const OptionSpec* o = find_option(c, s.substr(2, eq - 2));
      if (o && !o->flag && eq + 1 == s.size()) reject(s.substr(0, eq), "\"\"", "a value (it is empty): " + o->help);
      continue;
    }
    const OptionSpec* o = find_option(c, s.substr(2));
    if (!o || o->flag) continue;
    if (i + 1 >= argc) reject(s, "(missing)", "a value after the option: " + o->help);
    const std::string next = argv[i + 1];
    // An empty value ('') is not "the default": CLI11 would drop it and the command would run as if
    // the option were not given.
    if (next.find_first_not_of(" \t") == std::string::npos) reject(s, "\"" + next + "\"", "a value (it is empty): " + o->help);
    if (next.rfind("--", 0) == 0 && next.size() > 2) reject(s, "(missing)", "a value after the option (got the option " + next + "): " + o->help);
    ++i;
  }
  Parser p(c);
  try {
    p.app.parse(argc - 1, argv + 1);  // argv[1], the command, stands in for the program name
  } catch (const CLI::CallForHelp&) {
    std::fputs(p.app.help().c_str(), stdout);
    return false;
  } catch (const CLI::ParseError& e) {
    throw InputError("the command line of 'qdo " + c.name + "': " + e.what() + " (options:" + option_list(c) + ")");
  }
  const std::vector<std::string> extra = p.app.remaining();
  if (!extra.empty()) {
    const std::string& s = extra.front();
    if (s.rfind("-", 0) == 0 && s.size() > 1) {
      std::string name = s, val;
      const auto eq = s.find('=');
      if (eq != std::string::npos) {
        name = s.substr(0, eq);
        val = s.substr(eq + 1);
      } else if (extra.size() > 1 && extra[1].rfind("-", 0) != 0) {
        val = extra[1];
      } else {
        val = "(no value)";
      }
      reject(name, val, "an option of 'qdo " + c.name + "':" + option_list(c) + " (qdo " + c.name + " --help describes them)");
    }
    std::string where = "argument";
    for (int i = 2; i < argc; ++i)
      if (s == argv[i]) {
        where = "argument " + std::to_string(i - 1);
        break;
      }
    reject(where, s,
           c.positional.empty() ? "options of the form --name VALUE (qdo " + c.name + " takes no positional argument)"
                                : "one " + c.positional + " and options of the form --name VALUE");
  }
  Args a;
  a.command = c.name;
  for (const auto& o : c.options) {
    if (!o.def.empty()) a.defaults[o.name] = o.def;
    const CLI::Option* x = p.app.get_option("--" + o.name);
    if (x->count() == 0) continue;
    if (o.flag) {
      a.opt[o.name] = "yes";
    } else if (o.repeat) {
      a.multi[o.name] = p.values[o.name];
      a.opt[o.name] = p.values[o.name].back();
    } else {
      // An option given twice is refused rather than silently taking the last value.
      if (p.values[o.name].size() > 1)
        reject("--" + o.name, p.values[o.name][0] + " and " + p.values[o.name][1], "given once (it is not repeatable)");
      a.opt[o.name] = p.values[o.name].empty() ? std::string() : p.values[o.name].back();
    }
  }
  if (!c.positional.empty()) {
    if (p.positional.empty())
      reject(c.positional, "(missing)", "qdo " + c.name + " " + c.positional + " [options]: the " + c.positional_help);
    a.positional = p.positional;
  }
  out = std::move(a);
  return true;
}

std::string top_help() {
  std::ostringstream s;
  s << "qdo: quantization-aware deep optics simulator (OpenCL)\n\n"
       "usage:\n  qdo <command> [options]      run a command\n  qdo <command> --help         its options, with defaults\n"
       "  qdo --help | --version\n\ncommands:\n";
  for (const auto& c : command_table()) {
    std::string name = c.name + (c.positional.empty() ? "" : " " + c.positional);
    name.resize(std::max<std::size_t>(name.size(), 24), ' ');
    s << "  " << name << " " << c.summary << "\n";
  }
  s << "\nExit codes: 0 ok, 1 internal error, 2 bad input (argument or file, named), 3 refused as\n"
       "inaccurate or not finite, 4 OpenCL/device error, 5 gradient check failed, 6 file system\n"
       "error, 7 out of host memory. A failed command leaves none of its outputs.\n\n"
       "Device selection: --device, else $QDO_DEVICE, else the first GPU, else the first CPU\n"
       "(gpu | cpu | P:D as 'qdo devices' prints | a substring of the device name).\n";
  return s.str();
}

// Version and git revision, then the OpenCL devices and FFT backends (backends_report), CLI11.
int print_version() {
  std::printf("qdo %s (git revision %s)\n%scommand line: CLI11 %s\n", QDO_VERSION, QDO_GIT_REVISION, backends_report().c_str(),
              CLI11_VERSION);
  return 0;
}

}  // namespace

RegisterCommand::RegisterCommand(int order, std::function<CommandSpec()> make) { registrations().emplace_back(order, std::move(make)); }

std::string out_dir(const Args& a, const std::string& def) {
  const std::string d = a.get("out", def);
  if (d.empty()) reject("--out", "(missing)", "an output folder");
  claim_out(a, d);
  return d;
}

void claim_out(const Args& a, const std::string& dir) {
  if (dir.empty()) reject("--out", "(missing)", "an output folder");
  claim_output_dir(dir, "--out", a.command, a.has("into-existing"));
}

}  // namespace qdo::cli

int main(int argc, char** argv) {
  abandon_outputs_on_termination_signals();  // before any other thread exists, so that all inherit the mask
#ifdef QDO_WITH_TORCH
  qdo::cli::register_net_plugin_loader();  // --decoder resunet: libqdo-net.so, loaded on first use (net_plugin.cpp)
#endif
  const std::string first = argc < 2 ? "" : argv[1];
  if (argc < 2 || first == "--help" || first == "-h" || first == "help") {
    std::fputs(top_help().c_str(), argc < 2 ? stderr : stdout);
    return argc < 2 ? 2 : 0;
  }
  if (first == "--version" || first == "-V") return print_version();
  const CommandSpec* c = find_command(first);
  if (!c) {
    std::fprintf(stderr, "qdo: unknown command '%s'\n\n%s", first.c_str(), top_help().c_str());
    return 2;
  }
  const std::string& cmd = c->name;
  // Under mpirun every rank runs this; one whose command fails ends the job (MPI_Abort), since the
  // others may wait on it. Without a launcher the World is inert.
  std::unique_ptr<qdo::mpi::World> world;
  const int rc = [&]() -> int {
  try {
    try {
      world = std::make_unique<qdo::mpi::World>();
      Args a;
      if (!parse_command_line(*c, argc, argv, a)) return 0;  // --help
      if (a.has("data-root")) qdo::set_data_root(a.get("data-root"));  // dataset names resolve there
      // Long, resumable commands write their files as they go; the others stage every output and
      // rename them into place together only when the command succeeds (OutputStage, io.hpp).
      OutputStage stage(!c->writes_as_it_goes);
      const int status = c->run(a);
      qdo::wait_if_abandoned();  // interrupted as it finished: no commit, the signal ends the process
      if (status == 0) stage.commit();
      return status;
    } catch (...) {
      qdo::wait_if_abandoned();  // interrupted: the signal thread ends the process, not this error
      throw;
    }
  } catch (const InputError& e) {
    std::fprintf(stderr, "qdo %s: error: %s\n", cmd.c_str(), e.what());
    return 2;
  } catch (const AccuracyError& e) {
    std::fprintf(stderr, "qdo %s: refused: %s\n", cmd.c_str(), e.what());
    return 3;
  } catch (const DeviceError& e) {
    std::fprintf(stderr, "qdo %s: device error: %s\n", cmd.c_str(), e.what());
    return 4;
  } catch (const cl::Error& e) {
    std::fprintf(stderr, "qdo %s: OpenCL error in %s: %s\n", cmd.c_str(), e.what(), cl_error_name(e.err()).c_str());
    return 4;
  } catch (const std::filesystem::filesystem_error& e) {
    std::fprintf(stderr, "qdo %s: file system error: %s\n", cmd.c_str(), e.what());
    return 6;
  } catch (const std::bad_alloc&) {
    // The advice names what this command takes.
    const std::string advice = c->memory_advice.empty() ? "--preset, n, bands, batch" : c->memory_advice;
    std::fprintf(stderr, "qdo %s: out of host memory (reduce the problem size: %s)\n", cmd.c_str(), advice.c_str());
    return 7;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "qdo %s: internal error (please report): %s\n", cmd.c_str(), e.what());
    return 1;
  }
  }();
  if (rc != 0 && world && world->active() && world->size() > 1) world->abort(rc);
  return rc;
}
