// Numbers and switches read from text a user typed (a command-line option, a NAME=VALUE item of
// one): each is an InputError naming the argument, the value and what is allowed when it is not
// what the caller allows. The CLI and the library's own item parsers (fit starts) share them.
#pragma once
#include <string>

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

}  // namespace qdo
