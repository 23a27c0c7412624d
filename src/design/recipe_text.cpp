// The training recipes described as text and JSON (recipe.hpp; what `qdo recipe` prints).
#include "qdo/design/recipe.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>

#include "qdo/runtime/error.hpp"
#include "qdo/runtime/strprintf.hpp"

namespace qdo {

namespace {

// The recipes shown: `name` alone, or every recipe when it is empty (an InputError naming `argument`
// for an unknown name).
std::vector<std::string> shown_recipes(const std::string& name, const std::string& argument) {
  const auto& names = recipe_names();
  if (!name.empty() && std::find(names.begin(), names.end(), name) == names.end())
    reject(argument, name, "a recipe name: release or qdo");
  return name.empty() ? names : std::vector<std::string>{name};
}

}  // namespace

std::string recipe_table_text(const std::string& name, const std::string& argument) {
  const std::vector<std::string> shown = shown_recipes(name, argument);
  std::string s = strprintf("%-20s", "option");
  for (const std::string& r : shown) s += strprintf(" %-10s", r.c_str());
  s += " what it decides\n";
  for (const RecipeItem& it : recipe_items()) {
    s += strprintf("--%-18s", it.option.c_str());
    for (const std::string& r : shown) s += strprintf(" %-10s", recipe_value(r, it.option, argument).c_str());
    s += strprintf(" %s\n", it.what.c_str());
  }
  s += "\nWhat the authors' release does that no option reproduces:\n";
  for (const std::string& g : recipe_gaps()) s += strprintf("  - %s\n", g.c_str());
  s += "\nA run takes a recipe with --recipe NAME; an option given on the command line overrides its item.\n";
  return s;
}

std::string recipe_json_text(const std::string& name, const std::string& argument) {
  const std::vector<std::string> shown = shown_recipes(name, argument);
  nlohmann::json j;
  for (const std::string& r : shown) {
    nlohmann::json items = nlohmann::json::object();
    for (const RecipeItem& it : recipe_items()) items[it.option] = recipe_value(r, it.option, argument);
    j["recipes"][r] = items;
  }
  for (const RecipeItem& it : recipe_items()) j["what"][it.option] = it.what;
  j["not_reproduced"] = recipe_gaps();
  return j.dump(2) + "\n";
}

}  // namespace qdo
