// CSV tables: parsing (header, comments, numeric and raw cells) and reading a file.
#include <cerrno>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>

#include "data/io_internal.hpp"
#include "qdo/error.hpp"
#include "qdo/io.hpp"

namespace qdo {
using namespace io_detail;
namespace {
namespace fs = std::filesystem;
}  // namespace

// =========================================================================================
// CSV
// =========================================================================================

const std::vector<double>& CsvTable::column(const std::string& name) const {
  for (std::size_t c = 0; c < header.size(); ++c)
    if (header[c] == name) return columns[c];
  std::string h;
  for (const auto& x : header) h += (h.empty() ? "" : ", ") + x;
  throw InputError((origin.empty() ? std::string() : "file '" + origin + "': ") + "CSV column '" + name + "' not found (header: " + h + ")");
}

CsvTable parse_csv(const std::string& text, const std::string& origin) {
  auto trim = [](const std::string& s) {
    const std::size_t b = s.find_first_not_of(" \t\r\n");
    if (b == std::string::npos) return std::string();
    return s.substr(b, s.find_last_not_of(" \t\r\n") - b + 1);
  };
  auto split = [&](const std::string& line) {
    std::vector<std::string> cells;
    std::size_t start = 0;
    for (;;) {
      const std::size_t comma = line.find(',', start);
      cells.push_back(trim(line.substr(start, comma == std::string::npos ? std::string::npos : comma - start)));
      if (comma == std::string::npos) return cells;
      start = comma + 1;
    }
  };
  CsvTable t;
  t.origin = origin;
  std::istringstream in(text);
  std::string line;
  std::size_t line_no = 0;
  bool have_header = false;
  while (std::getline(in, line)) {
    ++line_no;
    const std::string s = trim(line);
    if (s.empty()) continue;
    if (s[0] == '#') {
      t.comments.push_back(trim(s.substr(1)));
      continue;
    }
    std::vector<std::string> cells = split(s);
    if (!have_header) {
      for (std::size_t c = 0; c < cells.size(); ++c) {
        if (cells[c].empty()) throw InputError(origin + ": line " + std::to_string(line_no) + ": empty column name in the header");
        for (std::size_t e = 0; e < c; ++e)
          if (cells[e] == cells[c])
            throw InputError(origin + ": line " + std::to_string(line_no) + ": duplicate column '" + cells[c] + "'");
      }
      t.header = cells;
      t.columns.assign(cells.size(), {});
      t.raw.assign(cells.size(), {});
      have_header = true;
      continue;
    }
    if (cells.size() != t.header.size())
      throw InputError(origin + ": line " + std::to_string(line_no) + ": " + std::to_string(cells.size()) +
                       " cells, but the header has " + std::to_string(t.header.size()) + " columns");
    for (std::size_t c = 0; c < cells.size(); ++c) {
      const std::string& cell = cells[c];
      char* end = nullptr;
      errno = 0;
      const double v = cell.empty() ? 0.0 : std::strtod(cell.c_str(), &end);
      const bool numeric = !cell.empty() && end == cell.c_str() + cell.size();
      t.columns[c].push_back(numeric ? v : std::numeric_limits<double>::quiet_NaN());
      t.raw[c].push_back(cell);
    }
  }
  if (!have_header) throw InputError(origin + ": no header line (only comments or blank lines)");
  return t;
}

CsvTable read_csv(const std::string& path) {
  // Spectral tables are kilobytes; refuse devices, pipes and folders (/dev/zero would never
  // end) and anything over 64 MiB before reading.
  constexpr std::uintmax_t kMaxCsvBytes = std::uintmax_t{64} << 20;
  std::error_code ec;
  const fs::file_status st = fs::status(path, ec);
  if (ec || !fs::exists(st)) fail(path, "", "no such CSV file");
  if (!fs::is_regular_file(st)) fail(path, "", "not a regular file (a CSV table is expected)");
  const std::uintmax_t size = fs::file_size(path, ec);
  if (ec || size > kMaxCsvBytes)
    fail(path, "", "a CSV table of " + std::to_string(size) + " bytes; at most 64 MiB is accepted");
  std::ifstream in(path, std::ios::binary);
  if (!in) fail(path, "", "cannot open CSV file");
  std::ostringstream ss;
  ss << in.rdbuf();
  if (in.bad()) fail(path, "", "read error");
  return parse_csv(ss.str(), path);
}

}  // namespace qdo
