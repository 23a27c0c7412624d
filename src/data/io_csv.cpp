// CSV tables: parsing (RFC 4180 quoting; header, comments, numeric and raw cells), reading a
// file, and the one writer every CSV qdo writes goes through (CsvText: quotes what needs it).
#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>

#include "data/io_internal.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"

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

namespace {
// One record of RFC 4180 text from `pos`: cells separated by commas; a cell that starts with a
// double quote runs to the matching quote ("" inside is one quote, commas and line breaks are
// part of the cell). Unquoted cells are trimmed of spaces and tabs; quoted ones kept as written.
// Returns false at the end of the text. `line` counts the text's lines (for messages).
struct CsvRecord {
  std::vector<std::string> cells;
  std::size_t first_line = 0;
  bool comment = false, blank = false;
};
bool next_record(const std::string& text, std::size_t& pos, std::size_t& line, const std::string& origin, CsvRecord& r) {
  r = CsvRecord{};
  if (pos >= text.size()) return false;
  r.first_line = ++line;
  auto trim = [](const std::string& x) {
    const std::size_t b = x.find_first_not_of(" \t\r");
    if (b == std::string::npos) return std::string();
    return x.substr(b, x.find_last_not_of(" \t\r") - b + 1);
  };
  // Comments ('#' first on the line, outside any quote) and blank lines.
  const std::size_t first = text.find_first_not_of(" \t\r", pos);
  if (first == std::string::npos || text[first] == '\n' || text[first] == '#') {
    const std::size_t eol = text.find('\n', pos);
    const std::string body = text.substr(pos, eol == std::string::npos ? std::string::npos : eol - pos);
    pos = eol == std::string::npos ? text.size() : eol + 1;
    if (first != std::string::npos && text[first] == '#') {
      r.comment = true;
      r.cells.push_back(trim(trim(body).substr(1)));
    } else {
      r.blank = true;
    }
    return true;
  }
  std::string cell;
  bool quoted = false;
  for (;;) {
    // At the start of a cell: skip blanks, then a quoted or a plain cell.
    while (pos < text.size() && (text[pos] == ' ' || text[pos] == '\t')) ++pos;
    if (pos < text.size() && text[pos] == '"') {
      quoted = true;
      const std::size_t open_line = line;
      ++pos;
      for (;;) {
        if (pos >= text.size())
          throw InputError(origin + ": line " + std::to_string(open_line) + ": a quoted cell is not closed before the end of the text");
        const char ch = text[pos++];
        if (ch == '"') {
          if (pos < text.size() && text[pos] == '"') {
            cell += '"';
            ++pos;
            continue;
          }
          break;
        }
        if (ch == '\n') ++line;
        cell += ch;
      }
      while (pos < text.size() && (text[pos] == ' ' || text[pos] == '\t' || text[pos] == '\r')) ++pos;
      if (pos < text.size() && text[pos] != ',' && text[pos] != '\n')
        throw InputError(origin + ": line " + std::to_string(line) + ": text after a quoted cell's closing quote (write \"\" for a quote inside one)");
    } else {
      const std::size_t end = text.find_first_of(",\n", pos);
      cell = trim(text.substr(pos, end == std::string::npos ? std::string::npos : end - pos));
      if (cell.find('"') != std::string::npos)
        throw InputError(origin + ": line " + std::to_string(line) + ": a quote inside an unquoted cell ('" + cell.substr(0, 40) +
                         "'); quote the whole cell and double the quote");
      pos = end == std::string::npos ? text.size() : end;
    }
    r.cells.push_back(quoted ? cell : trim(cell));
    cell.clear();
    quoted = false;
    if (pos >= text.size()) return true;
    if (text[pos++] == '\n') return true;  // else a comma: the next cell
  }
}
}  // namespace

std::string csv_field(const std::string& value) {
  const bool plain = !value.empty() && value.find_first_of(",\"\r\n") == std::string::npos && value.front() != ' ' &&
                     value.front() != '\t' && value.back() != ' ' && value.back() != '\t' && value.front() != '#';
  if (plain || value.empty()) return value;
  std::string q = "\"";
  for (char ch : value) {
    if (ch == '"') q += '"';
    q += ch;
  }
  return q + "\"";
}

std::string csv_number(double value, int significant_digits) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.*g", significant_digits, value);
  return buf;
}

CsvText::CsvText(std::vector<std::string> header) : columns_(header.size()) {
  if (header.empty()) throw Error("CsvText: a table needs at least one column");
  row(header);
}

CsvText& CsvText::row(const std::vector<std::string>& cells) {
  if (cells.size() != columns_)
    throw Error("CSV row of " + std::to_string(cells.size()) + " cells for a header of " + std::to_string(columns_) + " columns");
  for (std::size_t c = 0; c < cells.size(); ++c) text_ += (c ? "," : "") + csv_field(cells[c]);
  text_ += '\n';
  return *this;
}

CsvTable parse_csv(const std::string& text, const std::string& origin) {
  CsvTable t;
  t.origin = origin;
  std::size_t pos = 0, line = 0;
  bool have_header = false;
  CsvRecord r;
  while (next_record(text, pos, line, origin, r)) {
    if (r.blank) continue;
    if (r.comment) {
      t.comments.push_back(r.cells[0]);
      continue;
    }
    const std::vector<std::string>& cells = r.cells;
    const std::size_t line_no = r.first_line;
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
