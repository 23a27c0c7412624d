// JSON parsing for qdo's readers: nlohmann::json keeps the last of two equal keys in one
// object silently ({"n": 64, "n": 4096} read as 4096), so a hand-edited file could mean
// something other than it shows. parse_json_strict refuses duplicate keys within an object,
// naming the key (with its enclosing keys, e.g. "design.levels") and the origin (file name).
#pragma once
#include <set>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "qdo/runtime/error.hpp"

namespace qdo {

// Throws InputError "<origin>: duplicate key ..." for a repeated key; nlohmann's own
// exceptions (syntax errors) propagate unchanged for the caller to report.
inline nlohmann::json parse_json_strict(const std::string& text, const std::string& origin) {
  // One entry per open object or array: the keys seen so far (objects) and the key it was
  // entered by ("" inside arrays). The dotted path is built only for the message, so memory
  // stays linear in the document even 300,000 levels deep.
  struct Open {
    std::set<std::string> keys;
    std::string entered_by;
    bool array = false;
  };
  std::vector<Open> open;
  std::string pending;  // the key whose value comes next
  bool has_pending = false;
  const nlohmann::json::parser_callback_t check = [&](int, nlohmann::json::parse_event_t event, nlohmann::json& parsed) {
    using E = nlohmann::json::parse_event_t;
    switch (event) {
      case E::object_start:
      case E::array_start:
        open.push_back(Open{{}, has_pending ? pending : std::string(), event == E::array_start});
        has_pending = false;
        break;
      case E::object_end:
      case E::array_end:
        if (!open.empty()) open.pop_back();
        break;
      case E::key: {
        std::string key = parsed.get<std::string>();
        if (!open.empty() && !open.back().keys.insert(key).second) {
          std::string path;
          for (std::size_t i = 1; i < open.size(); ++i) {  // the outermost object has no key
            if (!open[i].entered_by.empty()) path += (path.empty() ? "" : ".") + open[i].entered_by;
            if (open[i - 1].array) path += "[]";
          }
          path += (path.empty() ? "" : ".") + key;
          throw InputError((origin.empty() ? std::string() : origin + ": ") + "duplicate key '" + path +
                           "' in one JSON object (each key may appear once)");
        }
        pending = std::move(key);
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
