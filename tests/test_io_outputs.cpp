// Tests of the file I/O layer (src/data/io_*.cpp), writing outputs: an output stage takes files from
// several threads, and a failed write leaves no file behind (nor a temporary one).
#include <doctest/doctest.h>

#include <filesystem>
#include <fstream>
#include <string>
#include <thread>
#include <vector>

#include "common.hpp"
#include "io_common.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"

namespace fs = std::filesystem;
using namespace qdo;
using namespace qdo::test::io_suite;
using qdo::test::input_error_of;
using qdo::test::slurp;

TEST_SUITE("io") {
  TEST_CASE("an output stage takes files from several threads at once (figures written beside HDF5 files)") {
    // Temporary files made first, then committed from 4 threads in a tight loop: the stage's
    // list is shared, so unguarded appends lose or corrupt entries.
    const auto dir = qdo::test::temp_dir("io_stage_threads");
    constexpr int kThreads = 4, kFiles = 2000;
    auto name = [&](int k, int i) { return (dir / ("f" + std::to_string(k) + "_" + std::to_string(i) + ".txt")).string(); };
    for (int k = 0; k < kThreads; ++k)
      for (int i = 0; i < kFiles; ++i) std::ofstream(name(k, i) + ".tmp") << "x\n";
    {
      OutputStage stage(true);
      std::vector<std::thread> threads;
      for (int k = 0; k < kThreads; ++k)
        threads.emplace_back([&, k] {
          for (int i = 0; i < kFiles; ++i) commit_output(name(k, i) + ".tmp", name(k, i));
        });
      for (auto& th : threads) th.join();
      CHECK_FALSE(std::filesystem::exists(name(0, 0)));  // deferred until the stage commits
      stage.commit();
    }
    std::size_t n = 0;
    for (const auto& e : std::filesystem::directory_iterator(dir)) n += e.path().extension() == ".txt";
    CHECK(n == std::size_t(kThreads * kFiles));
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("a failed write leaves no file behind") {
    TmpDir tmp;
    const std::string missing_dir = tmp / "no_such_dir/out.h5";
    CHECK_THROWS_AS(h5_write(missing_dir, {H5Dataset{"/a", {1}, {1.0}, {}, {}}}), InputError);
    CHECK_THROWS_AS(write_png(tmp / "no_such_dir/x.png", 1, 1, 1, {0}), InputError);
    CHECK_THROWS_AS(write_text_atomic(tmp / "no_such_dir/x.txt", "x"), InputError);
    CHECK(tmp.entries() == 0);

    // The second dataset's shape does not match its data: the file was already being written.
    const std::string target = tmp / "half.h5";
    const std::string msg = input_error_of([&] {
      h5_write(target, {H5Dataset{"/good", {2, 2}, {1, 2, 3, 4}, {}, {}}, H5Dataset{"/bad", {3, 3}, {1, 2}, {}, {}}});
    });
    CHECK(contains(msg, "/bad"));
    CHECK(contains(msg, "half.h5"));
    CHECK(tmp.entries() == 0);  // neither target nor temp file

    // An existing file is untouched by a failed overwrite.
    write_text_atomic(target, "old");
    CHECK_THROWS_AS(h5_write(target, {H5Dataset{"/bad", {2}, {1}, {}, {}}}), InputError);
    CHECK(slurp(target) == "old");
    CHECK(tmp.entries() == 1);
  }
}
