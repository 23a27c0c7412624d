#include "qdo/fab/gds.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <unistd.h>

#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"

namespace qdo::gds {
namespace {

// Record types (first byte) and data types (second byte) of the records we use.
enum : std::uint8_t {
  kHeader = 0x00, kBgnLib = 0x01, kLibName = 0x02, kUnits = 0x03, kEndLib = 0x04, kBgnStr = 0x05, kStrName = 0x06,
  kEndStr = 0x07, kBoundary = 0x08, kPath = 0x09, kSref = 0x0A, kAref = 0x0B, kText = 0x0C, kLayer = 0x0D,
  kDatatype = 0x0E, kXy = 0x10, kEndEl = 0x11, kNode = 0x15, kBox = 0x2D
};
enum : std::uint8_t { kNoData = 0x00, kInt16 = 0x02, kInt32 = 0x03, kReal8 = 0x05, kAscii = 0x06 };

class Writer {
 public:
  void record(std::uint8_t type, std::uint8_t dtype, const std::vector<std::uint8_t>& data = {}) {
    const std::size_t len = data.size() + 4;
    if (len > 65534) reject("GDSII record", len, "at most 65534 bytes");
    put16(static_cast<std::uint16_t>(len));
    out_.push_back(type);
    out_.push_back(dtype);
    out_.insert(out_.end(), data.begin(), data.end());
  }
  void int16s(std::uint8_t type, const std::vector<int>& v) {
    std::vector<std::uint8_t> d;
    for (int x : v) {
      const auto u = static_cast<std::uint16_t>(static_cast<std::int16_t>(x));
      d.push_back(static_cast<std::uint8_t>(u >> 8));
      d.push_back(static_cast<std::uint8_t>(u & 0xFF));
    }
    record(type, kInt16, d);
  }
  void ascii(std::uint8_t type, const std::string& s) {
    std::vector<std::uint8_t> d(s.begin(), s.end());
    if (d.size() % 2) d.push_back(0);
    record(type, kAscii, d);
  }
  void reals(std::uint8_t type, const std::vector<double>& v) {
    std::vector<std::uint8_t> d;
    for (double x : v) {
      const std::uint64_t b = encode_real(x);
      for (int k = 7; k >= 0; --k) d.push_back(static_cast<std::uint8_t>((b >> (8 * k)) & 0xFF));
    }
    record(type, kReal8, d);
  }
  void xy(const Polygon& p) {
    std::vector<std::uint8_t> d;
    d.reserve(p.size() * 8);
    for (const Point& q : p)
      for (std::int64_t c : {q.x, q.y}) {
        const auto u = static_cast<std::uint32_t>(static_cast<std::int32_t>(c));
        for (int k = 3; k >= 0; --k) d.push_back(static_cast<std::uint8_t>((u >> (8 * k)) & 0xFF));
      }
    record(kXy, kInt32, d);
  }
  std::vector<std::uint8_t>& bytes() { return out_; }

 private:
  void put16(std::uint16_t v) {
    out_.push_back(static_cast<std::uint8_t>(v >> 8));
    out_.push_back(static_cast<std::uint8_t>(v & 0xFF));
  }
  std::vector<std::uint8_t> out_;
};

std::vector<int> timestamp12(const Library& lib) {
  int t[6];
  std::copy(lib.timestamp, lib.timestamp + 6, t);
  if (std::all_of(t, t + 6, [](int v) { return v == 0; })) {
    const std::time_t now = std::time(nullptr);
    std::tm tm{};
    gmtime_r(&now, &tm);
    t[0] = tm.tm_year + 1900;
    t[1] = tm.tm_mon + 1;
    t[2] = tm.tm_mday;
    t[3] = tm.tm_hour;
    t[4] = tm.tm_min;
    t[5] = tm.tm_sec;
  }
  std::vector<int> v(t, t + 6);
  v.insert(v.end(), t, t + 6);  // modification time, then access time
  return v;
}

void check_boundary(const Boundary& b, std::size_t index) {
  const std::string what = "boundary " + std::to_string(index) + " (layer " + std::to_string(b.layer) + ")";
  if (b.layer < 0 || b.layer > 32767) reject(what + " layer", b.layer, "in [0, 32767]");
  if (b.datatype < 0 || b.datatype > 32767) reject(what + " datatype", b.datatype, "in [0, 32767]");
  if (b.points.size() < 4) reject(what + " points", b.points.size(), "at least 4 (a closed polygon of 3 vertices)");
  if (b.points.size() > kMaxBoundaryPoints) reject(what + " points", b.points.size(), "at most 8191 (GDSII XY record limit)");
  if (b.points.front() != b.points.back()) reject(what, "open", "closed polygons (first point repeated last)");
  for (const Point& p : b.points)
    for (std::int64_t c : {p.x, p.y})
      if (c < std::numeric_limits<std::int32_t>::min() || c > std::numeric_limits<std::int32_t>::max())
        reject(what + " coordinate", c, "within int32 database units");
}

}  // namespace

std::uint64_t encode_real(double v) {
  if (!std::isfinite(v)) reject("GDSII real", v, "finite");
  if (v == 0) return 0;
  const std::uint64_t sign = v < 0 ? 1 : 0;
  double m = std::fabs(v);
  int e = 64;
  while (m >= 1.0) {
    m /= 16.0;  // exact: a power of two
    ++e;
  }
  while (m < 1.0 / 16.0) {
    m *= 16.0;
    --e;
  }
  // m in [1/16, 1): m * 2^56 in [2^52, 2^56) is an integer for any double m (53-bit mantissa).
  std::uint64_t mant = static_cast<std::uint64_t>(std::ldexp(m, 56));
  if (mant >= (std::uint64_t(1) << 56)) {
    mant >>= 4;
    ++e;
  }
  if (e < 0 || e > 127) reject("GDSII real", v, "within 16^-64 .. 16^63");
  return (sign << 63) | (std::uint64_t(e) << 56) | mant;
}

double decode_real(std::uint64_t bits) {
  const bool neg = (bits >> 63) != 0;
  const int e = static_cast<int>((bits >> 56) & 0x7F);
  const std::uint64_t mant = bits & ((std::uint64_t(1) << 56) - 1);
  const double v = std::ldexp(static_cast<double>(mant), 4 * (e - 64) - 56);
  return neg ? -v : v;
}

std::vector<std::uint8_t> encode(const Library& lib) {
  for (std::size_t i = 0; i < lib.boundaries.size(); ++i) check_boundary(lib.boundaries[i], i);
  if (!(lib.db_in_user_units > 0) || !(lib.db_in_metres > 0))
    reject("GDSII units", to_str(lib.db_in_user_units) + ", " + to_str(lib.db_in_metres), "positive");
  Writer w;
  const std::vector<int> ts = timestamp12(lib);
  w.int16s(kHeader, {600});
  w.int16s(kBgnLib, ts);
  w.ascii(kLibName, lib.name);
  w.reals(kUnits, {lib.db_in_user_units, lib.db_in_metres});
  w.int16s(kBgnStr, ts);
  w.ascii(kStrName, lib.structure);
  for (const Boundary& b : lib.boundaries) {
    w.record(kBoundary, kNoData);
    w.int16s(kLayer, {b.layer});
    w.int16s(kDatatype, {b.datatype});
    w.xy(b.points);
    w.record(kEndEl, kNoData);
  }
  w.record(kEndStr, kNoData);
  w.record(kEndLib, kNoData);
  return std::move(w.bytes());
}

void write(const std::string& path, const Library& lib) {
  const std::vector<std::uint8_t> bytes = encode(lib);
  const std::string tmp = path + ".tmp-" + std::to_string(::getpid());
  {
    std::ofstream f(tmp, std::ios::binary | std::ios::trunc);
    if (!f) throw InputError("file '" + path + "': cannot open '" + tmp + "' for writing");
    f.write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
    f.flush();
    if (!f) {
      std::error_code ec;
      std::filesystem::remove(tmp, ec);
      throw InputError("file '" + path + "': write failed");
    }
  }
  try {
    commit_output(tmp, path);
  } catch (...) {
    std::error_code ec;
    std::filesystem::remove(tmp, ec);
    throw;
  }
}

Library decode(const std::vector<std::uint8_t>& b, const std::string& origin) {
  auto fail = [&](std::size_t at, const std::string& msg) -> void {
    throw InputError("GDSII '" + origin + "' at byte " + std::to_string(at) + ": " + msg);
  };
  auto u16 = [&](std::size_t at) { return static_cast<std::uint16_t>((b[at] << 8) | b[at + 1]); };
  auto i16 = [&](std::size_t at) { return static_cast<int>(static_cast<std::int16_t>(u16(at))); };
  auto i32 = [&](std::size_t at) {
    const std::uint32_t u = (std::uint32_t(b[at]) << 24) | (std::uint32_t(b[at + 1]) << 16) | (std::uint32_t(b[at + 2]) << 8) |
                            std::uint32_t(b[at + 3]);
    return static_cast<std::int64_t>(static_cast<std::int32_t>(u));
  };
  auto ascii = [&](std::size_t at, std::size_t len) {
    std::string s(b.begin() + static_cast<long>(at), b.begin() + static_cast<long>(at + len));
    while (!s.empty() && s.back() == '\0') s.pop_back();
    return s;
  };
  Library lib;
  lib.structure.clear();
  lib.name.clear();
  std::size_t pos = 0;
  bool seen_header = false, ended = false, in_boundary = false, in_other = false, have_units = false;
  Boundary cur;
  while (pos < b.size()) {
    if (pos + 4 > b.size()) fail(pos, "truncated record header");
    const std::size_t len = u16(pos);
    const std::uint8_t type = b[pos + 2], dtype = b[pos + 3];
    if (len < 4 || len % 2) fail(pos, "record length " + std::to_string(len) + " (must be even and >= 4)");
    if (pos + len > b.size()) fail(pos, "record of " + std::to_string(len) + " bytes runs past the end of the file");
    const std::size_t d = pos + 4, n = len - 4;
    if (!seen_header && type != kHeader) fail(pos, "the stream does not start with a HEADER record");
    auto need = [&](std::uint8_t dt, std::size_t min_bytes) {
      if (dtype != dt || n < min_bytes) fail(pos, "record type " + std::to_string(type) + " with data type " + std::to_string(dtype) +
                                                     " and " + std::to_string(n) + " data bytes");
    };
    switch (type) {
      case kHeader: seen_header = true; break;
      case kLibName: need(kAscii, 0); lib.name = ascii(d, n); break;
      case kStrName: need(kAscii, 0); lib.structure = ascii(d, n); break;
      case kUnits: {
        need(kReal8, 16);
        std::uint64_t r[2] = {0, 0};
        for (int k = 0; k < 2; ++k)
          for (int j = 0; j < 8; ++j) r[k] = (r[k] << 8) | b[d + std::size_t(8 * k + j)];
        lib.db_in_user_units = decode_real(r[0]);
        lib.db_in_metres = decode_real(r[1]);
        have_units = true;
        break;
      }
      case kBoundary:
        if (in_boundary || in_other) fail(pos, "BOUNDARY inside another element (missing ENDEL)");
        in_boundary = true;
        cur = Boundary{};
        break;
      case kPath: case kSref: case kAref: case kText: case kNode: case kBox:
        if (in_boundary || in_other) fail(pos, "element inside another element (missing ENDEL)");
        in_other = true;
        break;
      case kLayer:
        if (in_boundary) {
          need(kInt16, 2);
          cur.layer = i16(d);
        }
        break;
      case kDatatype:
        if (in_boundary) {
          need(kInt16, 2);
          cur.datatype = i16(d);
        }
        break;
      case kXy:
        if (in_boundary) {
          need(kInt32, 8);
          if (n % 8) fail(pos, "XY record of " + std::to_string(n) + " bytes (not whole points)");
          cur.points.clear();
          for (std::size_t k = 0; k < n; k += 8) cur.points.push_back({i32(d + k), i32(d + k + 4)});
        }
        break;
      case kEndEl:
        if (in_boundary) {
          if (cur.points.empty()) fail(pos, "BOUNDARY without XY");
          lib.boundaries.push_back(cur);
        }
        in_boundary = in_other = false;
        break;
      case kEndLib: ended = true; break;
      default: break;  // BGNLIB, BGNSTR, ENDSTR and properties carry nothing we need
    }
    pos += len;
    if (ended) break;
  }
  if (!seen_header) fail(0, "empty stream");
  if (!ended) fail(pos, "no ENDLIB record (truncated file?)");
  if (!have_units) fail(pos, "no UNITS record");
  return lib;
}

Library read(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  if (!f) throw InputError("file '" + path + "': cannot open for reading");
  const std::vector<std::uint8_t> bytes((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  return decode(bytes, path);
}

std::vector<Polygon> merge_pixels(const std::vector<std::uint8_t>& mask, std::size_t rows, std::size_t cols,
                                  std::size_t max_points) {
  if (mask.size() != rows * cols) reject("mask.size()", mask.size(), "rows x cols = " + std::to_string(rows * cols));
  if (max_points < 9 || max_points > kMaxBoundaryPoints) reject("max_points", max_points, "in [9, 8191]");
  struct Run {
    std::int64_t x0, x1;
    std::size_t chain;
  };
  struct Chain {
    std::int64_t y0 = 0;
    std::vector<std::pair<std::int64_t, std::int64_t>> runs;  // [x0, x1) per row from y0 down
    std::size_t points = 0;                                   // vertices, closing point excluded
  };
  std::vector<Chain> chains;
  std::vector<Run> prev, cur;
  for (std::size_t r = 0; r < rows; ++r) {
    cur.clear();
    const std::uint8_t* row = mask.data() + r * cols;
    for (std::size_t c = 0; c < cols;) {
      if (!row[c]) {
        ++c;
        continue;
      }
      std::size_t e = c;
      while (e < cols && row[e]) ++e;
      cur.push_back({std::int64_t(c), std::int64_t(e), 0});
      c = e;
    }
    std::vector<char> continued(prev.size(), 0);
    std::size_t p = 0;
    for (Run& run : cur) {
      while (p < prev.size() && prev[p].x1 <= run.x0) ++p;
      bool found = false;
      for (std::size_t q = p; q < prev.size() && prev[q].x0 < run.x1; ++q) {
        if (continued[q]) continue;
        Chain& ch = chains[prev[q].chain];
        const auto& last = ch.runs.back();
        const std::size_t add = (last.first != run.x0 ? 2u : 0u) + (last.second != run.x1 ? 2u : 0u);
        if (ch.points + add + 1 > max_points) continue;  // full: this run starts a new chain
        ch.points += add;
        ch.runs.push_back({run.x0, run.x1});
        run.chain = prev[q].chain;
        continued[q] = 1;
        found = true;
        break;
      }
      if (!found) {
        Chain ch;
        ch.y0 = std::int64_t(r);
        ch.runs.push_back({run.x0, run.x1});
        ch.points = 4;
        run.chain = chains.size();
        chains.push_back(std::move(ch));
      }
    }
    std::swap(prev, cur);
  }
  std::vector<Polygon> out;
  out.reserve(chains.size());
  for (const Chain& ch : chains) {
    const auto& R = ch.runs;
    const std::size_t n = R.size();
    Polygon pg;
    pg.reserve(ch.points + 1);
    pg.push_back({R[0].first, ch.y0});
    pg.push_back({R[0].second, ch.y0});
    for (std::size_t k = 0; k + 1 < n; ++k)
      if (R[k].second != R[k + 1].second) {
        const std::int64_t y = ch.y0 + std::int64_t(k) + 1;
        pg.push_back({R[k].second, y});
        pg.push_back({R[k + 1].second, y});
      }
    const std::int64_t yend = ch.y0 + std::int64_t(n);
    pg.push_back({R[n - 1].second, yend});
    pg.push_back({R[n - 1].first, yend});
    for (std::size_t k = n - 1; k-- > 0;)
      if (R[k].first != R[k + 1].first) {
        const std::int64_t y = ch.y0 + std::int64_t(k) + 1;
        pg.push_back({R[k + 1].first, y});
        pg.push_back({R[k].first, y});
      }
    pg.push_back(pg.front());
    out.push_back(std::move(pg));
  }
  return out;
}

std::vector<std::uint8_t> rasterize(const std::vector<Polygon>& polygons, std::size_t rows, std::size_t cols) {
  std::vector<std::uint8_t> mask(rows * cols, 0);
  std::vector<std::vector<std::int64_t>> cross(rows);
  std::vector<std::size_t> touched;
  for (std::size_t pi = 0; pi < polygons.size(); ++pi) {
    const Polygon& p = polygons[pi];
    const std::string what = "polygon " + std::to_string(pi);
    if (p.size() < 4 || p.front() != p.back()) reject(what, p.size(), "a closed polygon of at least 3 vertices");
    touched.clear();
    for (std::size_t k = 0; k + 1 < p.size(); ++k) {
      const Point a = p[k], b = p[k + 1];
      for (const Point& q : {a, b})
        if (q.x < 0 || q.y < 0 || q.x > std::int64_t(cols) || q.y > std::int64_t(rows))
          reject(what + " vertex", "(" + std::to_string(q.x) + ", " + std::to_string(q.y) + ")",
                 "inside the " + std::to_string(cols) + " x " + std::to_string(rows) + " pixel grid");
      if (a.x != b.x && a.y != b.y) reject(what + " edge " + std::to_string(k), "diagonal", "Manhattan (axis-parallel) edges");
      if (a.x != b.x) continue;  // horizontal edges never cross a pixel-centre line
      const std::int64_t y0 = std::min(a.y, b.y), y1 = std::max(a.y, b.y);
      for (std::int64_t y = y0; y < y1; ++y) {
        auto& v = cross[std::size_t(y)];
        if (v.empty()) touched.push_back(std::size_t(y));
        v.push_back(a.x);
      }
    }
    for (std::size_t y : touched) {
      auto& v = cross[y];
      std::sort(v.begin(), v.end());
      for (std::size_t k = 0; k + 1 < v.size(); k += 2)
        for (std::int64_t x = v[k]; x < v[k + 1]; ++x) mask[y * cols + std::size_t(x)] = 1;
      v.clear();
    }
  }
  return mask;
}

double signed_area(const Polygon& p) {
  double a = 0;
  for (std::size_t k = 0; k + 1 < p.size(); ++k)
    a += double(p[k].x) * double(p[k + 1].y) - double(p[k + 1].x) * double(p[k].y);
  return 0.5 * a;
}

bool is_simple(const Polygon& p) {
  if (p.size() < 5 || p.front() != p.back()) return false;
  const std::size_t e = p.size() - 1;  // edges k: p[k] -> p[k+1]
  for (std::size_t k = 0; k < e; ++k) {
    const Point a = p[k], b = p[k + 1];
    if (a == b || (a.x != b.x && a.y != b.y)) return false;  // zero-length or not rectilinear
  }
  auto box_overlap = [&](std::size_t i, std::size_t j) {
    const Point a = p[i], b = p[i + 1], c = p[j], d = p[j + 1];
    return std::max(std::min(a.x, b.x), std::min(c.x, d.x)) <= std::min(std::max(a.x, b.x), std::max(c.x, d.x)) &&
           std::max(std::min(a.y, b.y), std::min(c.y, d.y)) <= std::min(std::max(a.y, b.y), std::max(c.y, d.y));
  };
  for (std::size_t i = 0; i < e; ++i)
    for (std::size_t j = i + 1; j < e; ++j) {
      const bool adjacent = j == i + 1 || (i == 0 && j == e - 1);
      if (!adjacent) {
        if (box_overlap(i, j)) return false;  // axis-parallel segments: they meet iff their boxes do
      } else {
        // Adjacent edges share one vertex; they must not overlap beyond it (collinear fold-back).
        const Point a = p[i], b = p[i + 1], c = p[j], d = p[j + 1];
        const bool both_h = a.y == b.y && c.y == d.y, both_v = a.x == b.x && c.x == d.x;
        if (both_h || both_v) return false;  // collinear consecutive edges: not a proper vertex
      }
    }
  return true;
}

}  // namespace qdo::gds
