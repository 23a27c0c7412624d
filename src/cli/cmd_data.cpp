// qdo data: where qdo looks for datasets and what it finds there (data_root.hpp does the work and
// writes the report).
#include <cstdio>
#include <string>

#include "cli.hpp"
#include "qdo/data/data_root.hpp"

namespace qdo::cli {

static int cmd_data(const Args& a) {
  const std::size_t bands = std::size_t(parse_int("--bands", a.get("bands"), 1, 1024));
  const DataRoot root = data_root();
  std::fputs(data_root_report(root, summarise_datasets(root, bands, !a.has("quick")), !a.has("quick")).c_str(), stdout);
  return 0;
}

// qdo data: its entry in the command table (help order 30).
const RegisterCommand registered_data(30, [] {
  using namespace opts;
  return CommandSpec{"data", "where qdo looks for datasets and what it finds: each dataset's scenes, formats, shapes, value ranges, "
                           "sizes and checksums, and the known ones that are missing", "", "",
                   {data_root(), opt("bands", "bands expected in each scene, an integer in [1, 1024]", "31"),
                    flag("quick", "leave the value ranges out (the cubes are not read; shapes come from the file headers)")},
                   cmd_data};
});

}  // namespace qdo::cli
