// The data root (data_root.hpp): the order of the places it comes from, dataset names resolved
// under it, missing datasets named with where qdo looked, the summary `qdo data` prints, and the
// command line (qdo data, qdo demo) run from a folder that is not the repository.
#include <doctest/doctest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <initializer_list>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "common.hpp"
#include "qdo/data/data_root.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"

namespace fs = std::filesystem;
using namespace qdo;
using namespace qdo::test;

namespace {

// Sets (or unsets, with nullptr) the variables the data root reads for one scope, restoring them after.
class ScopedEnv {
 public:
  explicit ScopedEnv(std::initializer_list<std::pair<const char*, const char*>> vars) {
    for (const auto& [k, v] : vars) {
      const char* old = std::getenv(k);
      saved_.emplace(k, old ? std::optional<std::string>(old) : std::nullopt);
      if (v) setenv(k, v, 1);
      else unsetenv(k);
    }
    set_data_root("");
  }
  ~ScopedEnv() {
    for (const auto& [k, v] : saved_) {
      if (v) setenv(k.c_str(), v->c_str(), 1);
      else unsetenv(k.c_str());
    }
    set_data_root("");
  }
  ScopedEnv(const ScopedEnv&) = delete;
  ScopedEnv& operator=(const ScopedEnv&) = delete;

 private:
  std::map<std::string, std::optional<std::string>> saved_;
};

std::string error_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

// A small cube file: bands x rows x cols, values v0 + k / 1000 for element k.
void write_small_cube(const fs::path& p, std::size_t bands, std::size_t rows, std::size_t cols, double v0) {
  RealStack c(bands, rows, cols);
  for (std::size_t k = 0; k < c.data.size(); ++k) c.data[k] = v0 + double(k) / 1000.0;
  std::vector<double> wl(bands);
  for (std::size_t b = 0; b < bands; ++b) wl[b] = 400.0 + 10.0 * double(b);
  write_cube(p.string(), c, wl);
}

}  // namespace

TEST_SUITE("datasets") {
  TEST_CASE("data root: QDO_DATA, then the settings file, then the user data folder; --data-root before all") {
    const fs::path t = temp_dir("data_root_order");
    for (const char* d : {"env/cave", "settings_root/cave", "xdg_data/qdo/cave", "given/cave", "cfg/qdo"}) fs::create_directories(t / d);
    std::ofstream(t / "cfg/qdo/settings.json") << "{\"data_root\": \"../../settings_root\"}";
    const std::string env = (t / "env").string(), cfg = (t / "cfg").string(), data = (t / "xdg_data").string();
    {
      ScopedEnv e({{"QDO_DATA", env.c_str()}, {"XDG_CONFIG_HOME", cfg.c_str()}, {"XDG_DATA_HOME", data.c_str()}});
      CHECK(data_root().source == "QDO_DATA");
      CHECK(resolve_dataset("cave", "--data") == (fs::absolute(t / "env") / "cave").lexically_normal().string());
      set_data_root((t / "given").string());
      CHECK(data_root().source == "--data-root");
      CHECK(resolve_dataset("cave", "--data") == (t / "given" / "cave").lexically_normal().string());
    }
    {
      ScopedEnv e({{"QDO_DATA", nullptr}, {"XDG_CONFIG_HOME", cfg.c_str()}, {"XDG_DATA_HOME", data.c_str()}});
      const DataRoot r = data_root();
      // A relative data_root in the settings file is relative to the file, not to the working directory.
      CHECK(r.path == (t / "settings_root").lexically_normal().string());
      CHECK(r.source.find("settings file") == 0);
      CHECK(r.looked.size() == 3);  // --data-root, QDO_DATA, then the settings file used
    }
    {
      ScopedEnv e({{"QDO_DATA", nullptr}, {"XDG_CONFIG_HOME", (t / "nowhere").string().c_str()}, {"XDG_DATA_HOME", data.c_str()}});
      CHECK(data_root().source == "user data folder");
      CHECK(data_root().path == (t / "xdg_data" / "qdo").lexically_normal().string());
    }
    fs::remove_all(t);
  }

  TEST_CASE("data root: names resolve under it, paths are kept, a missing name says where qdo looked") {
    const fs::path t = temp_dir("data_root_names");
    fs::create_directories(t / "cave");
    const std::string root = t.string();
    ScopedEnv e({{"QDO_DATA", root.c_str()}});
    CHECK(is_dataset_name("cave"));
    CHECK(is_dataset_name("my-set_2"));
    for (const char* kept : {"./cave", "scenes/cave", "x.mat", "synthetic:4", "none", "/abs/cave"}) {
      CAPTURE(kept);
      CHECK_FALSE(is_dataset_name(kept));
      CHECK(resolve_dataset(kept, "--data") == kept);
    }
    const auto r = resolve_datasets({"cave", "synthetic:2"}, "--data");
    REQUIRE(r.size() == 2);
    CHECK(r[0] == (t / "cave").string());
    CHECK(r[1] == "synthetic:2");
    const std::string msg = error_of([] { resolve_dataset("kaist", "--test-data"); });
    CAPTURE(msg);
    CHECK(msg.find("--test-data") != std::string::npos);
    CHECK(msg.find((t / "kaist").string()) != std::string::npos);
    CHECK(msg.find("QDO_DATA") != std::string::npos);
    fs::remove_all(t);
  }

  TEST_CASE("data root: a root that is set but missing, and a bad settings file, are refused naming them") {
    const fs::path t = temp_dir("data_root_bad");
    const std::string missing = (t / "absent").string();
    {
      ScopedEnv e({{"QDO_DATA", missing.c_str()}});
      const std::string msg = error_of([] { data_root(); });
      CHECK(msg.find("QDO_DATA") != std::string::npos);
      CHECK(msg.find(missing) != std::string::npos);
      CHECK(error_of([&] { set_data_root(missing); }).find("--data-root") != std::string::npos);
    }
    fs::create_directories(t / "cfg/qdo");
    const std::string cfg = (t / "cfg").string();
    for (const auto& [text, expect] : std::vector<std::pair<std::string, std::string>>{
             {"{\"data_root\": 3}", "non-empty string"}, {"{\"dataroot\": \"/x\"}", "unknown key 'dataroot'"}, {"{not json", "not valid JSON"}}) {
      CAPTURE(text);
      std::ofstream(t / "cfg/qdo/settings.json") << text;
      ScopedEnv e({{"QDO_DATA", nullptr}, {"XDG_CONFIG_HOME", cfg.c_str()}});
      const std::string msg = error_of([] { data_root(); });
      CHECK(msg.find((t / "cfg/qdo/settings.json").string()) != std::string::npos);
      CHECK(msg.find(expect) != std::string::npos);
    }
    fs::remove_all(t);
  }

  TEST_CASE("data root: without any setting, the source tree's data when it exists") {
    const fs::path t = temp_dir("data_root_default");
    const std::string nowhere = (t / "nowhere").string();
    ScopedEnv e({{"QDO_DATA", nullptr}, {"XDG_CONFIG_HOME", nowhere.c_str()}, {"XDG_DATA_HOME", nowhere.c_str()}});
    const DataRoot r = data_root();
    if (skip_unless(have_shared(), "../shared/data/hsi (the source tree's data)")) {
      CHECK(r.source == "source tree");
      CHECK(fs::equivalent(r.path, fs::path(shared_dir()) / "data" / "hsi"));
      CHECK(fs::exists(resolve_dataset("cave_train", "--data")));
    }
    fs::remove_all(t);
  }

  TEST_CASE("data root: the summary of each dataset (scenes, shapes, values, checksum) and the known missing ones") {
    const fs::path t = temp_dir("data_root_summary");
    fs::create_directories(t / "mine");
    write_small_cube(t / "mine" / "a.h5", 4, 6, 5, 0.0);
    write_small_cube(t / "mine" / "b.h5", 4, 6, 5, 0.5);
    DataRoot root;
    root.path = t.string();
    root.exists = true;
    const auto sets = summarise_datasets(root, 4);
    const DatasetSummary* mine = nullptr;
    std::size_t missing = 0;
    for (const auto& s : sets) {
      if (s.name == "mine") mine = &s;
      if (!s.present) ++missing;
    }
    CHECK(missing == known_datasets().size());  // none of the known ones is here, and each is listed
    REQUIRE(mine != nullptr);
    CAPTURE(mine->problem);
    CHECK(mine->present);
    CHECK(mine->scenes == 2);
    CHECK(mine->shapes == "4 x 6 x 5");
    CHECK(mine->formats == "h5");
    CHECK(mine->min_value == doctest::Approx(0.0));
    CHECK(mine->max_value == doctest::Approx(0.5 + 119.0 / 1000.0));
    CHECK(mine->bytes == fs::file_size(t / "mine" / "a.h5") + fs::file_size(t / "mine" / "b.h5"));
    const std::string before = mine->checksum;
    write_small_cube(t / "mine" / "b.h5", 4, 6, 5, 0.25);  // other values: another checksum
    const auto again = summarise_datasets(root, 4, false);
    for (const auto& s : again)
      if (s.name == "mine") {
        CHECK(s.checksum != before);
        CHECK(s.max_value == 0.0);  // values not read
      }
    fs::remove_all(t);
  }

  TEST_CASE("qdo data and qdo demo from another folder: the data root, or an error naming where qdo looked") {
    const fs::path t = temp_dir("data_root_cli");
    fs::create_directories(t / "empty_root");
    const std::string cd = "cd " + t.string() + " && env -u QDO_DATA XDG_CONFIG_HOME=" + (t / "nowhere").string() +
                           " XDG_DATA_HOME=" + (t / "nowhere").string();
    const Run missing = qdo_run("demo --decoder resunet --data-root " + (t / "empty_root").string() + " --out " + (t / "demo").string(), cd);
    CAPTURE(missing.out);
    CHECK(missing.code == 2);
    CHECK(missing.out.find((t / "empty_root" / "cave_train").string()) != std::string::npos);
    CHECK(missing.out.find("--data-root") != std::string::npos);
    CHECK_FALSE(fs::exists(t / "demo"));  // refused before anything is written
    const Run listed = qdo_run("data --quick --data-root " + (t / "empty_root").string(), cd);
    CHECK(listed.code == 0);
    CHECK(listed.out.find("not found") != std::string::npos);
    CHECK(listed.out.find((t / "empty_root" / "kaist").string()) != std::string::npos);
    if (skip_unless(have_shared(), "../shared/data/hsi (the source tree's data)")) {
      // From a folder that is not the repository, with nothing set: the source tree's data.
      const Run found = qdo_run("data --quick", cd);
      CAPTURE(found.out);
      CHECK(found.code == 0);
      CHECK(found.out.find("(source tree)") != std::string::npos);
      CHECK(found.out.find("cave_train  ") != std::string::npos);
      CHECK(found.out.find("19 scenes") != std::string::npos);
    }
    fs::remove_all(t);
  }
}
