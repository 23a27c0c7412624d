// Kernel sources (kernels/*.cl) and small data tables (data/*.csv) embedded at build time.
#pragma once
#include <map>
#include <string>

namespace qdo {
// All embedded files by file name.
const std::map<std::string, std::string>& embedded_files();
// One embedded file by name; throws qdo::Error listing the names when missing.
const std::string& embedded_file(const std::string& name);
}  // namespace qdo
