// The data root and named datasets (data_root.hpp).
#include "qdo/data/data_root.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <sstream>

#include "qdo/data/datasets.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/hash.hpp"

#ifndef QDO_SOURCE_DATA_ROOT
#define QDO_SOURCE_DATA_ROOT ""
#endif

namespace fs = std::filesystem;

namespace qdo {

namespace {

std::mutex root_mutex;
std::string process_root;  // set_data_root's folder, absolute; empty: not set

std::string env(const char* name) {
  const char* v = std::getenv(name);
  return v ? std::string(v) : std::string();
}

// $XDG_<kind>_HOME (absolute, as the XDG spec requires) or ~/<fallback>; empty without a home.
std::string xdg_home(const char* variable, const char* fallback) {
  const std::string v = env(variable);
  if (!v.empty() && fs::path(v).is_absolute()) return v;
  const std::string home = env("HOME");
  return home.empty() ? std::string() : (fs::path(home) / fallback).string();
}

std::string absolute_of(const std::string& p) { return fs::absolute(fs::path(p)).lexically_normal().string(); }

bool is_folder(const std::string& p) {
  std::error_code ec;
  return fs::is_directory(p, ec);
}

// "data_root" of the user settings file, or "" when the file does not exist. A file that is not
// a JSON object, holds another key, or a data_root that is not a non-empty string is refused.
std::string settings_root(const std::string& file) {
  std::error_code ec;
  if (file.empty() || !fs::exists(file, ec)) return "";
  std::ifstream in(file);
  if (!in) throw InputError("settings file '" + file + "': cannot be read");
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(in);
  } catch (const nlohmann::json::exception& e) {
    throw InputError("settings file '" + file + "': not valid JSON (" + e.what() + ")");
  }
  if (!j.is_object()) throw InputError("settings file '" + file + "': must be a JSON object such as {\"data_root\": \"/data/hsi\"}");
  for (const auto& [k, v] : j.items())
    if (k != "data_root") throw InputError("settings file '" + file + "': unknown key '" + k + "' (allowed: data_root)");
  if (!j.contains("data_root")) return "";
  if (!j["data_root"].is_string() || j["data_root"].get<std::string>().empty())
    throw InputError("settings file '" + file + "': data_root must be a non-empty string (a folder)");
  std::string r = j["data_root"].get<std::string>();
  // A relative root in the settings file is relative to the file, never to the working directory.
  if (!fs::path(r).is_absolute()) r = (fs::path(file).parent_path() / r).string();
  return r;
}

}  // namespace

void set_data_root(const std::string& path, const std::string& argument) {
  if (!path.empty() && !is_folder(path))
    throw InputError(argument + " '" + path + "': not a folder (the folder that holds the datasets, e.g. cave/ and cave_train/)");
  const std::lock_guard<std::mutex> lock(root_mutex);
  process_root = path.empty() ? std::string() : absolute_of(path);
}

DataRoot data_root() {
  DataRoot r;
  std::string given;
  {
    const std::lock_guard<std::mutex> lock(root_mutex);
    given = process_root;
  }
  auto taken = [&](const std::string& path, const std::string& source, bool must_exist) {
    r.path = absolute_of(path);
    r.source = source;
    r.exists = is_folder(r.path);
    if (must_exist && !r.exists) throw InputError(source + " names '" + path + "', which is not a folder (the data root: the folder that holds the datasets)");
    r.looked.push_back(source + ": " + r.path + " (used)");
    return r;
  };
  if (!given.empty()) return taken(given, "--data-root", true);
  r.looked.push_back("--data-root: not given");
  const std::string e = env("QDO_DATA");
  if (!e.empty()) return taken(e, "QDO_DATA", true);
  r.looked.push_back("QDO_DATA: not set");
  const std::string config_home = xdg_home("XDG_CONFIG_HOME", ".config");
  const std::string settings = config_home.empty() ? std::string() : (fs::path(config_home) / "qdo" / "settings.json").string();
  const std::string s = settings_root(settings);
  if (!s.empty()) return taken(s, "settings file " + settings, true);
  r.looked.push_back("settings file " + (settings.empty() ? std::string("(no home folder)") : settings) + ": no data_root");
  const std::string data_home = xdg_home("XDG_DATA_HOME", ".local/share");
  const std::string user = data_home.empty() ? std::string() : (fs::path(data_home) / "qdo").string();
  if (!user.empty() && is_folder(user)) return taken(user, "user data folder", false);
  r.looked.push_back("user data folder " + (user.empty() ? std::string("(no home folder)") : user) + ": absent");
  const std::string source_tree = QDO_SOURCE_DATA_ROOT;
  if (!source_tree.empty() && is_folder(source_tree)) return taken(source_tree, "source tree", false);
  r.looked.push_back("source tree " + (source_tree.empty() ? std::string("(not configured)") : source_tree) + ": absent");
  r.path = user.empty() ? std::string() : absolute_of(user);
  r.source = "none found";
  r.exists = false;
  return r;
}

bool is_dataset_name(const std::string& item) {
  if (item.empty() || item == "none") return false;
  return std::all_of(item.begin(), item.end(), [](char c) {
    return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '_' || c == '-';
  });
}

const std::vector<KnownDataset>& known_datasets() {
  static const std::vector<KnownDataset> k = {
      {"cave", "CAVE test scenes: .mat cubes (key any 3-D variable, 31 bands) or CAVE PNG band folders"},
      {"cave_train", "CAVE training scenes, as cave/"},
      {"cave_png", "CAVE scenes in the native layout: one folder of 31 16-bit PNG bands per scene"},
      {"icvl", "ICVL .mat files (HDF5, key rad, divided by 4095)"},
      {"harvard", "Harvard .mat files (key ref)"},
      {"kaist", "KAIST .mat files (key HSI)"},
  };
  return k;
}

std::string resolve_dataset(const std::string& item, const std::string& argument) {
  if (!is_dataset_name(item)) return item;
  const DataRoot r = data_root();
  const fs::path p = fs::path(r.path) / item;
  std::error_code ec;
  if (!r.path.empty() && fs::exists(p, ec)) return p.string();
  std::string looked;
  for (const std::string& l : r.looked) looked += "\n  " + l;
  throw InputError(argument + ": dataset '" + item + "' not found: looked for " +
                   (r.path.empty() ? std::string("a data root and found none") : p.string()) + " (data root from " + r.source +
                   "). Set QDO_DATA or --data-root to the folder that holds '" + item +
                   "', or give a path (with a '/'); `qdo data` lists what qdo finds. Places considered:" + looked);
}

std::vector<std::string> resolve_datasets(const std::vector<std::string>& items, const std::string& argument) {
  std::vector<std::string> out;
  out.reserve(items.size());
  for (const std::string& i : items) out.push_back(resolve_dataset(i, argument));
  return out;
}

std::vector<DatasetSummary> summarise_datasets(const DataRoot& root, std::size_t expected_bands, bool read_values) {
  std::vector<DatasetSummary> out;
  std::vector<std::string> names;
  for (const KnownDataset& k : known_datasets()) names.push_back(k.name);
  std::error_code ec;
  if (root.exists) {
    std::vector<std::string> others;
    for (const auto& e : fs::directory_iterator(root.path, ec))
      if (e.is_directory() && std::find(names.begin(), names.end(), e.path().filename().string()) == names.end())
        others.push_back(e.path().filename().string());
    std::sort(others.begin(), others.end());
    names.insert(names.end(), others.begin(), others.end());
  }
  for (const std::string& name : names) {
    DatasetSummary s;
    s.name = name;
    s.path = root.path.empty() ? name : (fs::path(root.path) / name).string();
    for (const KnownDataset& k : known_datasets())
      if (k.name == name) s.what = k.what;
    s.present = !root.path.empty() && is_folder(s.path);
    if (!s.present) {
      out.push_back(s);
      continue;
    }
    // Checksum and size: every regular file under the folder, by relative path in sorted order.
    std::vector<fs::path> files;
    for (const auto& e : fs::recursive_directory_iterator(s.path, ec))
      if (e.is_regular_file()) files.push_back(e.path());
    std::sort(files.begin(), files.end());
    Fnv1a64 h;
    std::vector<char> buf(1 << 16);
    for (const fs::path& f : files) {
      h.add(fs::relative(f, s.path).generic_string());
      std::ifstream in(f, std::ios::binary);
      while (in) {
        in.read(buf.data(), std::streamsize(buf.size()));
        h.add(buf.data(), std::size_t(in.gcount()));
        s.bytes += std::size_t(in.gcount());
      }
    }
    s.checksum = h.hex();
    try {
      const SceneIndex idx({s.path}, "auto", expected_bands);
      s.scenes = idx.size();
      std::map<std::string, std::size_t> formats, shapes;
      double lo = INFINITY, hi = -INFINITY;
      for (std::size_t i = 0; i < idx.size(); ++i) {
        const SceneEntry& e = idx[i];
        ++formats[e.format];
        ++shapes[std::to_string(e.shape.bands) + " x " + std::to_string(e.shape.rows) + " x " + std::to_string(e.shape.cols)];
        if (read_values) {
          const RealStack c = idx.load(i);
          for (double v : c.data) {
            lo = std::min(lo, v);
            hi = std::max(hi, v);
          }
        }
      }
      for (const auto& [f, n] : formats) s.formats += (s.formats.empty() ? "" : ", ") + f;
      for (const auto& [sh, n] : shapes)
        s.shapes += (s.shapes.empty() ? "" : ", ") + sh + (shapes.size() > 1 ? " (" + std::to_string(n) + ")" : "");
      if (read_values && idx.size() > 0) {
        s.min_value = lo;
        s.max_value = hi;
      }
    } catch (const Error& e) {
      s.problem = e.what();
    }
    out.push_back(s);
  }
  return out;
}

}  // namespace qdo
