// qdo recipe: what a training recipe sets (recipe.hpp): every item's option, its value in each
// recipe and what it decides, and what of the authors' release no option reproduces; --json for
// a machine-readable form (the text is recipe.hpp's: recipe_table_text, recipe_json_text). The
// command is this file: it registers itself below.
#include <cstdio>

#include "cli.hpp"
#include "qdo/design/recipe.hpp"

namespace qdo::cli {

static int cmd_recipe(const Args& a) {
  const std::string name = a.get("name");
  std::fputs((a.has("json") ? recipe_json_text(name, "--name") : recipe_table_text(name, "--name")).c_str(), stdout);
  return 0;
}

// qdo recipe: its entry in the command table (help order 105, after design).
const RegisterCommand registered_recipe(105, [] {
  using namespace opts;
  return CommandSpec{"recipe", "what a training recipe (--recipe of qdo design and qdo sweep) sets: each item's option, its value "
                          "in each recipe and what it decides", "", "",
                {opt("name", "one recipe: release or qdo (default: both side by side)"),
                 flag("json", "print JSON: {recipes: {NAME: {option: value}}, what: {option: text}, not_reproduced: [...]}")},
                cmd_recipe};
});

}  // namespace qdo::cli
