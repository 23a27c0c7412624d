// Training recipes: the settings, beyond the system, the mode and the level count, that decide what
// a design run learns. A recipe is data: a table of items, each with its command-line option, its
// value in every recipe and the DesignRunOptions field it fills (src/design/recipe.cpp). Two:
//   release  the authors' TensorFlow release (wang-lizhi/QuantizationAwareDeepOptics) as it trains:
//            Adam 0.01 (optics, offsets) and 1e-3 (network) decayed by 0.8 every 500 steps,
//            continuously; Keras' Adam (epsilon 1e-7, "epsilon hat" form); 50 epochs of 418 steps,
//            alpha from epoch 5 to 40; every ring at w = 1e-4 (u = 0.5); L_aq over the ring
//            profile; level 0 of its etch-depth axis (qdo's top level) pinned; +-20 nm uniform
//            height noise in training and test; no network weight decay (its L2 is never added).
//   qdo      qdo's earlier defaults: decay 0.8 per epoch (staircase), 10 steps per epoch, textbook
//            Adam (epsilon 1e-8), random initial heights, L_aq over the N x N pixels, level 0
//            (H = 0) pinned, no height noise, network weight decay 1e-4 (Eq. 14 as printed).
// Items of the release not reproduced (named by recipe_gaps()) are listed, not hidden.
// Every run records each item as its own config.json field, and "recipe" its name.
#pragma once
#include <functional>
#include <string>
#include <vector>

#include "qdo/design/design_run_options.hpp"

namespace qdo {

struct RecipeItem {
  std::string option;       // the command-line option (without --) that sets it
  std::string release, qdo;  // its value in each recipe, as the option reads it
  std::string what;         // one line: what it decides
};

// The recipe names ("release", "qdo") and the item table, in a fixed order.
const std::vector<std::string>& recipe_names();
const std::vector<RecipeItem>& recipe_items();
// The value of `option` in recipe `name`; InputError naming `argument` for an unknown recipe, or
// for an option that is not a recipe item.
std::string recipe_value(const std::string& name, const std::string& option, const std::string& argument = "recipe");
// Sets every item of recipe `name` on `o` for which given(option) is false (the caller's own
// choices stay), parsing each value as the command line does, and o.recipe = name. t0 and t1,
// when not given, follow o.epochs (release: 0.1 and 0.8 of the epochs; qdo: min(5, 0.1 epochs)
// and 0.8 epochs). InputError for an unknown recipe name.
void apply_recipe(const std::string& name, DesignRunOptions& o,
                  const std::function<bool(const std::string& option)>& given = [](const std::string&) { return false; });
// What the release does that no qdo option reproduces yet, one line each.
const std::vector<std::string>& recipe_gaps();

// What `qdo recipe` prints: a table of every item (its option, its value in recipe `name`, or in
// every recipe side by side when `name` is empty, and what it decides), then what of the release
// no option reproduces. An InputError naming `argument` for an unknown name. Lines end with "\n".
std::string recipe_table_text(const std::string& name = "", const std::string& argument = "recipe");
// The same as JSON (2-space indent, final newline): {recipes: {NAME: {option: value}}, what:
// {option: text}, not_reproduced: [...]}.
std::string recipe_json_text(const std::string& name = "", const std::string& argument = "recipe");

}  // namespace qdo
