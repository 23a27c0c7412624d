// Where datasets live: one data root, and named datasets resolved under it.
//
// The root is the first of, in this order:
//   1. a root set for this process (set_data_root: the command line's --data-root),
//   2. the environment variable QDO_DATA,
//   3. "data_root" in the user settings file ($XDG_CONFIG_HOME/qdo/settings.json, by default
//      ~/.config/qdo/settings.json),
//   4. the user data folder ($XDG_DATA_HOME/qdo, by default ~/.local/share/qdo) when it exists,
//   5. the data of the source tree this binary was built from (the hyperspectral folder beside the
//      repository, set at configure time) when it exists.
// 1–3 are taken as set (a root that does not exist is an error naming it and where it was set);
// 4 and 5 only when present. With none, the root is the user data folder, which does not exist,
// and every named dataset is missing.
//
// A dataset name is a bare word: letters, digits, '_' and '-' only (cave, cave_train, icvl,
// kaist, my_scenes). It resolves to ROOT/NAME; a missing one is an InputError naming the place
// looked and where the root came from. Anything else (a path with '/' or a '.', synthetic:N,
// none) is left as it is. No default anywhere is a path relative to the working directory.
#pragma once
#include <cstddef>
#include <string>
#include <vector>

namespace qdo {

struct DataRoot {
  std::string path;    // absolute; may not exist (then no dataset resolves)
  std::string source;  // "--data-root", "QDO_DATA", "settings file PATH", "user data folder", "source tree", "none found"
  bool exists = false;
  // Every place considered, in order, with what was found there ("not set", "absent", "used").
  std::vector<std::string> looked;
};

// The process-wide root (1. above); empty clears it. InputError when `path` is given and is not
// a folder, naming `argument`.
void set_data_root(const std::string& path, const std::string& argument = "--data-root");
DataRoot data_root();

bool is_dataset_name(const std::string& item);

// Each item of `items` (a comma-separated option's values): a dataset name becomes ROOT/NAME,
// anything else is kept. InputError naming `argument`, the name, the folder looked in and the
// root's source when a named dataset is missing.
std::vector<std::string> resolve_datasets(const std::vector<std::string>& items, const std::string& argument);
std::string resolve_dataset(const std::string& item, const std::string& argument);

// Datasets qdo knows by name, with what to put in the folder (for `qdo data` and errors).
struct KnownDataset {
  std::string name, what;
};
const std::vector<KnownDataset>& known_datasets();

// One dataset folder under the root, as `qdo data` reports it.
struct DatasetSummary {
  std::string name, path, what;  // what: from known_datasets, or "" for a folder qdo does not know
  bool present = false;
  std::size_t scenes = 0;
  std::string formats;  // the resolved formats of its scenes, comma-separated ("cave, cave-png")
  std::string shapes;   // "31 x 256 x 256" or "31 x 256 x 256 (18), 31 x 512 x 512 (1)"
  double min_value = 0, max_value = 0;  // over every scene as load_scene returns it (values read)
  std::size_t bytes = 0;                // the scene files' sizes
  std::string checksum;                 // fnv1a64 over every file's relative path and bytes, in sorted order
  std::string problem;                  // non-empty when a scene could not be read (the error's text)
};

// Every known dataset (present or not) and every other folder under the root. read_values =
// false skips loading the cubes (no value range); the checksum always reads the bytes.
std::vector<DatasetSummary> summarise_datasets(const DataRoot& root, std::size_t expected_bands = 31,
                                               bool read_values = true);

// What `qdo data` prints: the data root and where it comes from, the places considered in order,
// each dataset found (its scenes, formats, shapes, size, checksum; with `values` the value range)
// or why it is unreadable, then the known datasets not found. Lines end with "\n".
std::string data_root_report(const DataRoot& root, const std::vector<DatasetSummary>& sets, bool values);

}  // namespace qdo
