// qdo recipe: what a training recipe sets (recipe.hpp): every item's option, its value in each
// recipe and what it decides, and what of the authors' release no option reproduces; --json for
// a machine-readable form. The whole command is this file: it registers itself below.
#include <algorithm>
#include <cstdio>
#include <string>

#include <nlohmann/json.hpp>

#include "cli.hpp"
#include "options.hpp"
#include "qdo/design/recipe.hpp"
#include "qdo/runtime/error.hpp"

namespace qdo::cli {

static int cmd_recipe(const Args& a) {
  const std::string name = a.get("name");
  const auto& names = recipe_names();
  if (!name.empty() && std::find(names.begin(), names.end(), name) == names.end())
    reject("--name", name, "a recipe name: release or qdo");
  const std::vector<std::string> shown = name.empty() ? names : std::vector<std::string>{name};
  if (a.has("json")) {
    nlohmann::json j;
    for (const std::string& r : shown) {
      nlohmann::json items = nlohmann::json::object();
      for (const RecipeItem& it : recipe_items()) items[it.option] = recipe_value(r, it.option, "--name");
      j["recipes"][r] = items;
    }
    for (const RecipeItem& it : recipe_items()) j["what"][it.option] = it.what;
    j["not_reproduced"] = recipe_gaps();
    std::printf("%s\n", j.dump(2).c_str());
    return 0;
  }
  std::printf("%-20s", "option");
  for (const std::string& r : shown) std::printf(" %-10s", r.c_str());
  std::printf(" what it decides\n");
  for (const RecipeItem& it : recipe_items()) {
    std::printf("--%-18s", it.option.c_str());
    for (const std::string& r : shown) std::printf(" %-10s", recipe_value(r, it.option, "--name").c_str());
    std::printf(" %s\n", it.what.c_str());
  }
  std::printf("\nWhat the authors' release does that no option reproduces:\n");
  for (const std::string& g : recipe_gaps()) std::printf("  - %s\n", g.c_str());
  std::printf("\nA run takes a recipe with --recipe NAME; an option given on the command line overrides its item.\n");
  return 0;
}

namespace {
// qdo recipe: its entry in the command table (help order 105, after design).
const RegisterCommand registered_recipe(105, [] {
  using namespace opts;
  CommandSpec c{"recipe", "what a training recipe (--recipe of qdo design and qdo sweep) sets: each item's option, its value "
                          "in each recipe and what it decides",
                "", "",
                {opt("name", "one recipe: release or qdo (default: both side by side)"),
                 flag("json", "print JSON: {recipes: {NAME: {option: value}}, what: {option: text}, not_reproduced: [...]}")},
                cmd_recipe};
  return c;
});
}  // namespace

}  // namespace qdo::cli
