// GDSII stream files: a writer, a reader (for round-trip checks), and the merging of pixel
// masks into Manhattan polygons on an integer grid.
//
// Stream format (Calma GDSII, release 6): records of [u16 length][u8 type][u8 data type][data],
// big-endian, even lengths. We write HEADER (600), BGNLIB, LIBNAME, UNITS, one structure
// (BGNSTR, STRNAME, BOUNDARY elements: LAYER, DATATYPE, XY, ENDEL), ENDSTR, ENDLIB. UNITS holds
// two 8-byte GDSII reals (excess-64, base-16 exponent, 56-bit mantissa): the size of a database
// unit in user units (1e-3: user unit 1 µm, database unit 1 nm) and in metres (1e-9).
// Coordinates are int32 database units. Every BOUNDARY is closed (the first point repeated at the end) and holds at most
// kMaxBoundaryPoints points (8191: a record is at most 65535 bytes, 8 bytes per point).
//
// Polygon merging works on pixel masks in grid units: pixel (row r, col c) is the unit square
// [c, c+1] x [r, r+1]. Each row's horizontal runs of set pixels are stacked into vertical
// chains: a run continues the chain of an overlapping run in the row above (positive overlap),
// so each chain is a y-monotone rectilinear polygon: simple (no self-intersections or
// self-touching), no holes, every horizontal line meets it in one interval. Polygons of one
// mask are interior-disjoint; their union is exactly the set pixels. Chains are cut before they
// exceed the point limit.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

namespace qdo::gds {

constexpr std::size_t kMaxBoundaryPoints = 8191;

struct Point {
  std::int64_t x = 0, y = 0;
  bool operator==(const Point& o) const { return x == o.x && y == o.y; }
  bool operator!=(const Point& o) const { return !(*this == o); }
};
using Polygon = std::vector<Point>;  // closed: front() == back()

struct Boundary {
  int layer = 0;       // 0 .. 32767 (GDSII int16)
  int datatype = 0;
  Polygon points;      // database units; closed
};

struct Library {
  std::string name = "QDO";             // LIBNAME
  std::string structure = "DOE";        // STRNAME of the single structure
  double db_in_user_units = 1e-3;       // UNITS[0]: 1 nm in µm
  double db_in_metres = 1e-9;           // UNITS[1]: 1 nm
  std::vector<Boundary> boundaries;
  // Time stamps of BGNLIB/BGNSTR (year, month, day, hour, minute, second); all zero = now (UTC).
  int timestamp[6] = {0, 0, 0, 0, 0, 0};
};

// 8-byte GDSII real <-> double. Encoding rounds the mantissa to nearest; 0 encodes as 0.
std::uint64_t encode_real(double v);
double decode_real(std::uint64_t bits);

// The stream bytes of a library. Throws InputError for points outside int32, layers outside
// [0, 32767], open or degenerate boundaries (< 4 points) or boundaries over the point limit.
std::vector<std::uint8_t> encode(const Library& lib);
// Writes atomically (temp file + rename).
void write(const std::string& path, const Library& lib);

// Parses a stream: every BOUNDARY of every structure (structure names are not kept; the last
// STRNAME is). PATH, TEXT, SREF, AREF, BOX and NODE elements are skipped. Throws InputError
// naming `origin`, the byte offset and the problem for truncated or malformed streams.
Library decode(const std::vector<std::uint8_t>& bytes, const std::string& origin);
Library read(const std::string& path);

// --- Pixel masks <-> polygons (grid units) ---------------------------------------------------

// mask: rows x cols, row-major, non-zero = set. Returns closed, simple, y-monotone rectilinear
// polygons (grid units, see above) with at most max_points points each (>= 9), without
// collinear vertices. Deterministic order (by top row, then left edge).
std::vector<Polygon> merge_pixels(const std::vector<std::uint8_t>& mask, std::size_t rows, std::size_t cols,
                                  std::size_t max_points = kMaxBoundaryPoints);

// Fills polygons (grid units, closed, rectilinear with edges on integer lines) into a rows x
// cols mask: a pixel is set when its centre lies inside (even-odd rule per polygon; overlapping
// polygons OR together). Throws InputError for non-Manhattan edges or coordinates off the grid.
std::vector<std::uint8_t> rasterize(const std::vector<Polygon>& polygons, std::size_t rows, std::size_t cols);

// Signed area (shoelace; positive counter-clockwise with y up) of a closed polygon.
double signed_area(const Polygon& p);
// True when no two non-adjacent edges of the closed polygon intersect or touch and adjacent
// edges meet only at their shared vertex (O(E^2); for tests).
bool is_simple(const Polygon& p);

}  // namespace qdo::gds
