// JSON parsing for qdo's readers: nlohmann::json keeps the last of two equal keys in one
// object silently ({"n": 64, "n": 4096} read as 4096), so a hand-edited file could mean
// something other than it shows. parse_json_strict refuses duplicate keys within an object,
// naming the key (with its enclosing keys, e.g. "design.levels") and the origin (file name).
#pragma once
#include <set>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include "qdo/error.hpp"

namespace qdo {

// Throws InputError "<origin>: duplicate key ..." for a repeated key; nlohmann's own
// exceptions (syntax errors) propagate unchanged for the caller to report.
inline nlohmann::json parse_json_strict(const std::string& text, const std::string& origin) {
  // One entry per open object or array: the keys seen so far and the dotted path.
  struct Open {
    std::set<std::string> keys;
    std::string path;
  };
  std::vector<Open> open;
  std::string pending;  // the key whose value comes next
  bool has_pending = false;
  auto join = [](const std::string& a, const std::string& b) { return a.empty() ? b : a + "." + b; };
  const nlohmann::json::parser_callback_t check = [&](int, nlohmann::json::parse_event_t event, nlohmann::json& parsed) {
    using E = nlohmann::json::parse_event_t;
    const std::string parent = open.empty() ? std::string() : open.back().path;
    switch (event) {
      case E::object_start:
      case E::array_start:
        open.push_back(Open{{}, has_pending ? join(parent, pending) : (open.empty() ? std::string() : parent + "[]")});
        has_pending = false;
        break;
      case E::object_end:
      case E::array_end:
        if (!open.empty()) open.pop_back();
        break;
      case E::key: {
        const std::string key = parsed.get<std::string>();
        if (!open.empty() && !open.back().keys.insert(key).second)
          throw InputError((origin.empty() ? std::string() : origin + ": ") + "duplicate key '" + join(parent, key) +
                           "' in one JSON object (each key may appear once)");
        pending = key;
        has_pending = true;
        break;
      }
      case E::value:
        has_pending = false;
        break;
    }
    return true;
  };
  return nlohmann::json::parse(text, check);
}

}  // namespace qdo
