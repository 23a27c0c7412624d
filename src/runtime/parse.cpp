// Numbers and switches read from text a user typed (parse.hpp).
#include "qdo/runtime/parse.hpp"

#include <cmath>
#include <cstdlib>

#include "qdo/runtime/error.hpp"

namespace qdo {

int parse_int(const std::string& name, const std::string& v, int lo, int hi) {
  char* end = nullptr;
  const long x = std::strtol(v.c_str(), &end, 10);
  if (v.empty() || *end || x < lo || x > hi) reject(name, v, "an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]");
  return int(x);
}

double parse_double(const std::string& name, const std::string& v) {
  char* end = nullptr;
  const double x = std::strtod(v.c_str(), &end);
  if (v.empty() || *end || !std::isfinite(x)) reject(name, v, "a number");
  return x;
}

double parse_double(const std::string& name, const std::string& v, double lo, double hi, const std::string& unit, bool lo_open) {
  const double x = parse_double(name, v);
  if (x < lo || x > hi || (lo_open && x == lo)) {
    const std::string u = unit.empty() ? "" : " " + unit;
    reject(name, v + u, "a number in " + std::string(lo_open ? "(" : "[") + to_str(lo) + ", " + to_str(hi) + "]" + u);
  }
  return x;
}

bool parse_on_off(const std::string& name, const std::string& v) {
  if (v == "on") return true;
  if (v == "off") return false;
  reject(name, v, "on or off");
}

}  // namespace qdo
