// Numbers and switches read from text a user typed (a command-line option, a NAME=VALUE item of
// one): each is an InputError naming the argument, the value and what is allowed when it is not
// what the caller allows. The CLI and the library's own item parsers (fit starts) share them.
#pragma once
#include <map>
#include <string>
#include <vector>

namespace qdo {

// An integer in [lo, hi], the whole text (no trailing characters).
int parse_int(const std::string& name, const std::string& v, int lo, int hi);
// A finite number, the whole text.
double parse_double(const std::string& name, const std::string& v);
// A number within [lo, hi] (lo excluded when lo_open), in `unit` (e.g. "nm", "" for none).
double parse_double(const std::string& name, const std::string& v, double lo, double hi, const std::string& unit,
                    bool lo_open = false);
// "on" or "off".
bool parse_on_off(const std::string& name, const std::string& v);

// Options as a user typed them, each by its name without the leading "--" ("levels", "design"):
// `opt` holds exactly the options given (flags as "yes"; a repeatable one's last value, every value
// in order in `multi`), so has() means "given explicitly"; get() falls back to `defaults` (a
// command's declared defaults), then to `def`; all() is every value of a repeatable option. The library's
// readers of such options (config_from_options, design_run_options_from_options, ...) name each
// option in their refusals as "--name", the way the qdo tool's user typed it.
struct TextOptions {
  std::map<std::string, std::string> opt;       // given explicitly
  std::map<std::string, std::string> defaults;  // the defaults of options not given ("" = none)
  std::map<std::string, std::vector<std::string>> multi;  // repeatable options given, every value in order
  std::string get(const std::string& k, const std::string& def = "") const {
    auto it = opt.find(k);
    if (it != opt.end()) return it->second;
    auto d = defaults.find(k);
    return d != defaults.end() && !d->second.empty() ? d->second : def;
  }
  bool has(const std::string& k) const { return opt.count(k) > 0; }
  std::vector<std::string> all(const std::string& k) const {
    auto it = multi.find(k);
    if (it != multi.end()) return it->second;
    return has(k) ? std::vector<std::string>{opt.at(k)} : std::vector<std::string>{};
  }
};

}  // namespace qdo
