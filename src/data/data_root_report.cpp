// The data root and its datasets described as text (data_root.hpp; what `qdo data` prints).
#include "qdo/data/data_root.hpp"

#include "qdo/runtime/strprintf.hpp"

namespace qdo {

std::string data_root_report(const DataRoot& root, const std::vector<DatasetSummary>& sets, bool values) {
  std::string s = strprintf("data root: %s (%s)%s\n", root.path.empty() ? "(none)" : root.path.c_str(),
                            root.source.c_str(), root.exists ? "" : ", does not exist");
  s += strprintf("places considered, in order:\n");
  for (const std::string& l : root.looked) s += strprintf("  %s\n", l.c_str());
  s += strprintf("\n");
  std::size_t missing = 0;
  for (const DatasetSummary& d : sets) {
    if (!d.present) {
      ++missing;
      continue;
    }
    s += strprintf("%s  %s\n", d.name.c_str(), d.path.c_str());
    if (!d.problem.empty()) {
      s += strprintf("  unreadable: %s\n", d.problem.c_str());
      continue;
    }
    s += strprintf("  %zu scene%s, %s, bands x rows x cols %s, %.1f MiB, %s\n", d.scenes, d.scenes == 1 ? "" : "s",
                   d.formats.c_str(), d.shapes.c_str(), double(d.bytes) / 1048576.0, d.checksum.c_str());
    if (values && d.scenes > 0)
      s += strprintf("  values in [%.4g, %.4g] as qdo reads them\n", d.min_value, d.max_value);
  }
  if (missing > 0) {
    s += strprintf("\nnot found (put them in the data root under these names):\n");
    for (const DatasetSummary& d : sets)
      if (!d.present) s += strprintf("  %-11s %s: %s\n", d.name.c_str(), d.path.c_str(), d.what.c_str());
  }
  return s;
}

}  // namespace qdo
