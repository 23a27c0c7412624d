// qdo data: where qdo looks for datasets and what it finds there (data_root.hpp does the work).
#include <cstdio>
#include <string>

#include "cli.hpp"
#include "options.hpp"
#include "qdo/data/data_root.hpp"

namespace qdo::cli {

static int cmd_data(const Args& a) {
  const std::size_t bands = std::size_t(parse_int("--bands", a.get("bands"), 1, 1024));
  const DataRoot root = data_root();
  std::printf("data root: %s (%s)%s\n", root.path.empty() ? "(none)" : root.path.c_str(), root.source.c_str(),
              root.exists ? "" : ", does not exist");
  std::printf("places considered, in order:\n");
  for (const std::string& l : root.looked) std::printf("  %s\n", l.c_str());
  std::printf("\n");
  const auto sets = summarise_datasets(root, bands, !a.has("quick"));
  std::size_t missing = 0;
  for (const DatasetSummary& s : sets) {
    if (!s.present) {
      ++missing;
      continue;
    }
    std::printf("%s  %s\n", s.name.c_str(), s.path.c_str());
    if (!s.problem.empty()) {
      std::printf("  unreadable: %s\n", s.problem.c_str());
      continue;
    }
    std::printf("  %zu scene%s, %s, bands x rows x cols %s, %.1f MiB, %s\n", s.scenes, s.scenes == 1 ? "" : "s", s.formats.c_str(),
                s.shapes.c_str(), double(s.bytes) / 1048576.0, s.checksum.c_str());
    if (!a.has("quick") && s.scenes > 0) std::printf("  values in [%.4g, %.4g] as qdo reads them\n", s.min_value, s.max_value);
  }
  if (missing > 0) {
    std::printf("\nnot found (put them in the data root under these names):\n");
    for (const DatasetSummary& s : sets)
      if (!s.present) std::printf("  %-11s %s: %s\n", s.name.c_str(), s.path.c_str(), s.what.c_str());
  }
  return 0;
}

namespace {
// qdo data: its entry in the command table (help order 30).
const RegisterCommand registered_data(30, [] {
  using namespace opts;
  CommandSpec c{"data", "where qdo looks for datasets and what it finds: each dataset's scenes, formats, shapes, value ranges, "
                           "sizes and checksums, and the known ones that are missing", "", "",
                   {data_root(), opt("bands", "bands expected in each scene, an integer in [1, 1024]", "31"),
                    flag("quick", "leave the value ranges out (the cubes are not read; shapes come from the file headers)")},
                   cmd_data};
  return c;
});
}  // namespace

}  // namespace qdo::cli
