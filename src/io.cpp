// File I/O: HDF5 (contract files), MATLAB .mat cubes (libmatio), CSV tables, PNG figures.
// Every writer goes through AtomicFile (temp "<path>.tmp-<pid>" + rename); every reader names
// the file, the dataset/variable and the problem in its InputError.
#include "qdo/io.hpp"

#include <hdf5.h>
#include <matio.h>
#include <png.h>
#include <unistd.h>
#include <zlib.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <limits>
#include <memory>
#include <sstream>

#include "qdo/error.hpp"

namespace qdo {
namespace {

namespace fs = std::filesystem;

// ---------------------------------------------------------------------------------------
// Shared helpers
// ---------------------------------------------------------------------------------------

// "<file>: <what>: <problem>"
[[noreturn]] void fail(const std::string& file, const std::string& what, const std::string& problem) {
  throw InputError("file '" + file + "'" + (what.empty() ? "" : ": " + what) + ": " + problem);
}

std::string shape_str(const std::vector<std::size_t>& shape) {
  std::string s = "[";
  for (std::size_t i = 0; i < shape.size(); ++i) s += (i ? " x " : "") + std::to_string(shape[i]);
  return s + "]";
}

// Product of dims; returns false when it overflows or exceeds max_elements.
bool element_count(const std::vector<std::size_t>& shape, std::size_t max_elements, std::size_t& n) {
  n = 1;
  for (std::size_t d : shape) {
    if (d != 0 && n > max_elements / d) return false;
    n *= d;
  }
  return n <= max_elements;
}

// A reader allocates what a file declares, so a tiny corrupt file must not be able to declare
// gigabytes. Uncompressed data must fit in the file; compressed data (deflate, the strongest
// filter HDF5 and MATLAB files use) expand at most ~1032:1. Checked before any allocation.
constexpr std::uintmax_t kMaxExpansion = 1100;
constexpr std::uintmax_t kSlackBytes = std::uintmax_t{1} << 16;
void check_declared_bytes(const std::string& path, const std::string& what, const std::vector<std::size_t>& shape,
                          std::size_t elements, std::size_t bytes_per_element, bool compressed) {
  std::error_code ec;
  const std::uintmax_t file = fs::file_size(path, ec);
  if (ec) fail(path, what, "cannot read the file size: " + ec.message());
  const std::uintmax_t limit = compressed ? file * kMaxExpansion + kSlackBytes : file;
  const std::uintmax_t bpe = std::max<std::size_t>(bytes_per_element, 1);
  if (elements > limit / bpe)
    fail(path, what,
         "declares shape " + shape_str(shape) + " (" + std::to_string(elements) + " elements of " + std::to_string(bpe) +
             " bytes) but the file holds only " + std::to_string(file) + " bytes" +
             (compressed ? " (more than any compression could expand to)" : " (uncompressed)") +
             ": truncated or corrupt file");
}

std::size_t count_nonfinite(const std::vector<double>& v) {
  return static_cast<std::size_t>(std::count_if(v.begin(), v.end(), [](double x) { return !std::isfinite(x); }));
}

// Writes go to "<path>.tmp-<pid>"; commit() renames onto path; the destructor removes the
// temp file unless committed, so an exception anywhere leaves nothing behind.
class AtomicFile {
 public:
  explicit AtomicFile(std::string path)
      : path_(std::move(path)), tmp_(path_ + ".tmp-" + std::to_string(static_cast<long>(::getpid()))) {
    if (path_.empty()) reject("path", "\"\"", "an output file name is required");
  }
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;
  ~AtomicFile() {
    if (!committed_) std::remove(tmp_.c_str());
  }
  const std::string& tmp() const { return tmp_; }
  void commit() {
    commit_output(tmp_, path_);
    committed_ = true;
  }

 private:
  std::string path_, tmp_;
  bool committed_ = false;
};

void require_file(const std::string& path) {
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) fail(path, "", "no such file");
}

// ---------------------------------------------------------------------------------------
// HDF5
// ---------------------------------------------------------------------------------------

// Owns one hid_t and closes it with the matching H5?close.
class H5Id {
 public:
  using Closer = herr_t (*)(hid_t);
  H5Id(hid_t id, Closer closer) : id_(id), closer_(closer) {}
  H5Id(H5Id&& o) noexcept : id_(o.id_), closer_(o.closer_) { o.id_ = -1; }
  H5Id(const H5Id&) = delete;
  H5Id& operator=(const H5Id&) = delete;
  H5Id& operator=(H5Id&&) = delete;
  ~H5Id() { close(); }
  hid_t get() const { return id_; }
  bool valid() const { return id_ >= 0; }
  // Closes now; returns false when HDF5 reports a failure (e.g. a flush on file close).
  bool close() {
    const hid_t id = id_;
    id_ = -1;
    return id < 0 || closer_(id) >= 0;
  }

 private:
  hid_t id_;
  Closer closer_;
};

void h5_quiet() { H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr); }

// The most specific message on the HDF5 error stack (then clears it), e.g. "unable to open file".
std::string h5_detail() {
  std::string msg;
  H5Ewalk2(
      H5E_DEFAULT, H5E_WALK_UPWARD,
      [](unsigned n, const H5E_error2_t* e, void* out) -> herr_t {
        if (n == 0 && e && e->desc) *static_cast<std::string*>(out) = e->desc;
        return 0;
      },
      &msg);
  H5Eclear2(H5E_DEFAULT);
  return msg.empty() ? "" : " (HDF5: " + msg + ")";
}

H5Id h5_open_read(const std::string& path) {
  h5_quiet();
  require_file(path);
  H5Id f(H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT), H5Fclose);
  if (!f.valid()) fail(path, "", "not a readable HDF5 file" + h5_detail());
  return f;
}

std::string h5_abs(const std::string& name) { return (!name.empty() && name[0] == '/') ? name : "/" + name; }

// True when every link along the absolute path exists and the object is a dataset.
bool h5_is_dataset(hid_t file, const std::string& name) {
  const std::string abs = h5_abs(name);
  if (abs == "/") return false;
  std::size_t pos = 0;
  while (pos != std::string::npos) {
    pos = abs.find('/', pos + 1);
    const std::string prefix = abs.substr(0, pos);
    if (H5Lexists(file, prefix.c_str(), H5P_DEFAULT) <= 0) {
      H5Eclear2(H5E_DEFAULT);
      return false;
    }
  }
  H5Id obj(H5Oopen(file, abs.c_str(), H5P_DEFAULT), H5Oclose);
  if (!obj.valid()) {
    H5Eclear2(H5E_DEFAULT);
    return false;
  }
  return H5Iget_type(obj.get()) == H5I_DATASET;
}

// Numeric type of a dataset, for the automatic cube scale.
struct NumKind {
  bool integer = false;
  double max = 1;  // largest representable value for integers
};

NumKind h5_num_kind(hid_t type) {
  NumKind k;
  if (H5Tget_class(type) == H5T_INTEGER) {
    const double bits = 8.0 * static_cast<double>(H5Tget_size(type));
    k.integer = true;
    k.max = H5Tget_sign(type) == H5T_SGN_NONE ? std::pow(2.0, bits) - 1 : std::pow(2.0, bits - 1) - 1;
  }
  return k;
}

// Reads the scalar numeric and string attributes of an object into ds (others are ignored).
void h5_read_attrs(hid_t obj, const std::string& path, H5Dataset& ds) {
  std::vector<std::string> names;
  hsize_t idx = 0;
  if (H5Aiterate2(obj, H5_INDEX_NAME, H5_ITER_INC, &idx,
                  [](hid_t, const char* n, const H5A_info_t*, void* out) -> herr_t {
                    static_cast<std::vector<std::string>*>(out)->emplace_back(n);
                    return 0;
                  },
                  &names) < 0)
    fail(path, "dataset '" + ds.name + "'", "cannot list attributes" + h5_detail());
  for (const std::string& an : names) {
    const std::string what = "attribute '" + an + "' of '" + ds.name + "'";
    H5Id attr(H5Aopen(obj, an.c_str(), H5P_DEFAULT), H5Aclose);
    if (!attr.valid()) fail(path, what, "cannot open" + h5_detail());
    H5Id type(H5Aget_type(attr.get()), H5Tclose);
    H5Id space(H5Aget_space(attr.get()), H5Sclose);
    if (!type.valid() || !space.valid()) fail(path, what, "cannot read type" + h5_detail());
    if (H5Sget_simple_extent_npoints(space.get()) != 1) continue;  // arrays: not part of the contract
    const H5T_class_t cls = H5Tget_class(type.get());
    if (cls == H5T_INTEGER || cls == H5T_FLOAT) {
      double v = 0;
      if (H5Aread(attr.get(), H5T_NATIVE_DOUBLE, &v) < 0) fail(path, what, "cannot read" + h5_detail());
      ds.num_attrs[an] = v;
    } else if (cls == H5T_STRING) {
      if (H5Tis_variable_str(type.get()) > 0) {
        H5Id mem(H5Tcopy(H5T_C_S1), H5Tclose);
        H5Tset_size(mem.get(), H5T_VARIABLE);
        char* raw = nullptr;
        if (H5Aread(attr.get(), mem.get(), &raw) < 0) fail(path, what, "cannot read" + h5_detail());
        const std::unique_ptr<char, herr_t (*)(void*)> owned(raw, H5free_memory);
        ds.str_attrs[an] = raw ? std::string(raw) : std::string();
      } else {
        const std::size_t len = H5Tget_size(type.get());
        if (len == 0 || len > (std::size_t{1} << 20)) fail(path, what, "string of " + std::to_string(len) + " bytes (at most 1 MiB)");
        H5Id mem(H5Tcopy(type.get()), H5Tclose);
        std::string buf(len + 1, '\0');
        if (H5Aread(attr.get(), mem.get(), buf.data()) < 0) fail(path, what, "cannot read" + h5_detail());
        ds.str_attrs[an] = std::string(buf.c_str());
      }
    }
  }
}

// Checks, before any read, that a numeric dataset's storage can hold its shape: element size
// 1..16 bytes, declared data within what the file can hold (check_declared_bytes), compact and
// contiguous data stored in one piece of exactly n x size bytes (a corrupt layout message that
// stores less, a compact dataset with no data, crashed libhdf5's read with a NULL memcpy: found
// by fuzz_cube_h5; storage never written holds no data at all), and no virtual layouts.
void check_h5_storage(const std::string& path, const std::string& what, hid_t dset, hid_t type,
                      const std::vector<std::size_t>& shape, std::size_t n) {
  const std::size_t tsize = H5Tget_size(type);
  if (tsize == 0 || tsize > 16) fail(path, what, "elements of " + std::to_string(tsize) + " bytes (a corrupt datatype)");
  H5Id dcpl(H5Dget_create_plist(dset), H5Pclose);
  if (!dcpl.valid()) fail(path, what, "cannot read the storage layout" + h5_detail());
  const int filters = H5Pget_nfilters(dcpl.get());
  if (filters < 0) fail(path, what, "cannot read the storage filters" + h5_detail());
  check_declared_bytes(path, what, shape, n, tsize, filters > 0);
  const H5D_layout_t layout = H5Pget_layout(dcpl.get());
  if (n > 0 && (layout == H5D_COMPACT || layout == H5D_CONTIGUOUS)) {
    const hsize_t stored = H5Dget_storage_size(dset);
    if (stored != hsize_t(n) * tsize)
      fail(path, what, "stores " + std::to_string(stored) + " bytes for shape " + shape_str(shape) + " of " +
                           std::to_string(tsize) + "-byte values (" + std::to_string(n * tsize) +
                           " bytes expected): truncated, unwritten or corrupt");
  } else if (n > 0 && layout != H5D_CHUNKED) {
    fail(path, what, "unsupported storage layout (virtual or unknown); expected compact, contiguous or chunked data");
  }
}

// Reads one numeric dataset (converted to float64, C order) plus its attributes.
H5Dataset h5_read_impl(const std::string& path, const std::string& name, std::size_t max_elements,
                       NumKind* kind) {
  H5Id file = h5_open_read(path);
  H5Dataset ds;
  ds.name = h5_abs(name);
  const std::string what = "dataset '" + ds.name + "'";
  if (!h5_is_dataset(file.get(), ds.name)) fail(path, what, "missing (no such dataset)");
  H5Id dset(H5Dopen2(file.get(), ds.name.c_str(), H5P_DEFAULT), H5Dclose);
  if (!dset.valid()) fail(path, what, "cannot open" + h5_detail());
  H5Id type(H5Dget_type(dset.get()), H5Tclose);
  H5Id space(H5Dget_space(dset.get()), H5Sclose);
  if (!type.valid() || !space.valid()) fail(path, what, "cannot read type/shape" + h5_detail());
  const H5T_class_t cls = H5Tget_class(type.get());
  if (cls != H5T_INTEGER && cls != H5T_FLOAT) fail(path, what, "not numeric (integer or float) data");
  const int rank = H5Sget_simple_extent_ndims(space.get());
  if (rank < 0) fail(path, what, "cannot read shape" + h5_detail());
  std::vector<hsize_t> dims(static_cast<std::size_t>(rank));
  H5Sget_simple_extent_dims(space.get(), dims.data(), nullptr);
  ds.shape.assign(dims.begin(), dims.end());
  std::size_t n = 0;
  if (!element_count(ds.shape, max_elements, n))
    fail(path, what, "shape " + shape_str(ds.shape) + " exceeds the limit of " + std::to_string(max_elements) +
                         " elements");
  check_h5_storage(path, what, dset.get(), type.get(), ds.shape, n);
  ds.data.resize(n);
  if (n > 0 && H5Dread(dset.get(), H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, ds.data.data()) < 0)
    fail(path, what, "read failed" + h5_detail());
  h5_read_attrs(dset.get(), path, ds);
  if (kind) *kind = h5_num_kind(type.get());
  return ds;
}

void h5_write_str_attr(hid_t obj, const std::string& file, const std::string& name, const std::string& value) {
  H5Id type(H5Tcopy(H5T_C_S1), H5Tclose);
  H5Id space(H5Screate(H5S_SCALAR), H5Sclose);
  if (!type.valid() || !space.valid() || H5Tset_size(type.get(), value.size() + 1) < 0 ||
      H5Tset_strpad(type.get(), H5T_STR_NULLTERM) < 0)
    fail(file, "attribute '" + name + "'", "cannot create string type" + h5_detail());
  H5Id attr(H5Acreate2(obj, name.c_str(), type.get(), space.get(), H5P_DEFAULT, H5P_DEFAULT), H5Aclose);
  if (!attr.valid() || H5Awrite(attr.get(), type.get(), value.c_str()) < 0)
    fail(file, "attribute '" + name + "'", "cannot write" + h5_detail());
}

void h5_write_num_attr(hid_t obj, const std::string& file, const std::string& name, double value) {
  H5Id space(H5Screate(H5S_SCALAR), H5Sclose);
  H5Id attr(H5Acreate2(obj, name.c_str(), H5T_IEEE_F64LE, space.get(), H5P_DEFAULT, H5P_DEFAULT), H5Aclose);
  if (!attr.valid() || H5Awrite(attr.get(), H5T_NATIVE_DOUBLE, &value) < 0)
    fail(file, "attribute '" + name + "'", "cannot write" + h5_detail());
}

// One dataset, shape in C order, float64 on disk; validates shape against data size first.
void h5_write_dataset(hid_t file, const std::string& path, const H5Dataset& d) {
  const std::string what = "dataset '" + d.name + "'";
  if (d.name.size() < 2 || d.name[0] != '/') fail(path, what, "name must be an absolute path like \"/psf\"");
  std::size_t n = 0;
  if (!element_count(d.shape, std::numeric_limits<std::size_t>::max(), n) || n != d.data.size())
    fail(path, what, "shape " + shape_str(d.shape) + " does not match the data size " + std::to_string(d.data.size()));
  const std::vector<hsize_t> dims(d.shape.begin(), d.shape.end());
  H5Id space(d.shape.empty() ? H5Screate(H5S_SCALAR)
                             : H5Screate_simple(static_cast<int>(dims.size()), dims.data(), nullptr),
             H5Sclose);
  H5Id lcpl(H5Pcreate(H5P_LINK_CREATE), H5Pclose);
  if (!space.valid() || !lcpl.valid() || H5Pset_create_intermediate_group(lcpl.get(), 1) < 0)
    fail(path, what, "cannot create dataspace" + h5_detail());
  H5Id dset(H5Dcreate2(file, d.name.c_str(), H5T_IEEE_F64LE, space.get(), lcpl.get(), H5P_DEFAULT, H5P_DEFAULT),
            H5Dclose);
  if (!dset.valid()) fail(path, what, "cannot create" + h5_detail());
  if (n > 0 && H5Dwrite(dset.get(), H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, d.data.data()) < 0)
    fail(path, what, "write failed" + h5_detail());
  for (const auto& kv : d.num_attrs) h5_write_num_attr(dset.get(), path, kv.first, kv.second);
  for (const auto& kv : d.str_attrs) h5_write_str_attr(dset.get(), path, kv.first, kv.second);
}

// ---------------------------------------------------------------------------------------
// MATLAB .mat (libmatio)
// ---------------------------------------------------------------------------------------

struct MatCloser {
  void operator()(mat_t* m) const { Mat_Close(m); }
};
struct MatVarFreer {
  void operator()(matvar_t* v) const { Mat_VarFree(v); }
};
using MatFile = std::unique_ptr<mat_t, MatCloser>;
using MatVar = std::unique_ptr<matvar_t, MatVarFreer>;

// matio reports problems through a log callback; keep the last message for our errors.
thread_local std::string g_matio_last;
void matio_log(int, char* message) { g_matio_last = message ? message : ""; }

std::string matio_detail() {
  std::string s = g_matio_last.empty() ? "" : " (matio: " + g_matio_last + ")";
  g_matio_last.clear();
  return s;
}

bool mat_numeric(const matvar_t& v) {
  return v.class_type >= MAT_C_DOUBLE && v.class_type <= MAT_C_UINT64 && !v.isComplex;
}

std::vector<std::size_t> mat_dims(const matvar_t& v) {
  return std::vector<std::size_t>(v.dims, v.dims + std::max(v.rank, 0));
}

const char* mat_class_name(matio_classes c) {
  static const char* names[] = {"empty", "cell",  "struct", "object", "char",   "sparse", "double", "single", "int8",
                                "uint8", "int16", "uint16", "int32",  "uint32", "int64",  "uint64", "function",
                                "opaque"};
  const int i = static_cast<int>(c);
  return (i >= 0 && i < static_cast<int>(sizeof(names) / sizeof(names[0]))) ? names[i] : "unknown";
}

NumKind mat_num_kind(const matvar_t& v) {
  NumKind k;
  k.integer = v.class_type >= MAT_C_INT8;
  switch (v.class_type) {
    case MAT_C_INT8: k.max = 127; break;
    case MAT_C_UINT8: k.max = v.isLogical ? 1 : 255; break;
    case MAT_C_INT16: k.max = 32767; break;
    case MAT_C_UINT16: k.max = 65535; break;
    case MAT_C_INT32: k.max = 2147483647.0; break;
    case MAT_C_UINT32: k.max = 4294967295.0; break;
    case MAT_C_INT64: k.max = 9223372036854775807.0; break;
    case MAT_C_UINT64: k.max = 18446744073709551615.0; break;
    default: k.max = 1; break;
  }
  return k;
}

template <typename T>
void mat_convert(const void* src, std::size_t n, std::vector<double>& out) {
  const T* p = static_cast<const T*>(src);
  out.resize(n);
  for (std::size_t i = 0; i < n; ++i) out[i] = static_cast<double>(p[i]);
}

// A raw array as read from a file: dims in reading order, data in that file's memory order.
// A 1 x n, n x 1 or n-element shape holding n elements.
bool is_vector_shape(const std::vector<std::size_t>& dims, std::size_t n) {
  if (dims.empty() || dims.size() > 2 || n == 0) return false;
  return dims.size() == 1 || dims[0] == 1 || dims[1] == 1;
}

struct RawArray {
  std::string key;
  std::vector<std::size_t> dims;
  std::vector<double> data;
  bool column_major = false;  // MATLAB order (first index fastest) vs C order
  NumKind kind;
};

// libmatio reads a truncated v5 file without complaint (the missing data come back as
// zeros), and it allocates whatever the tags inside a variable declare (a dims tag claiming
// 500 MB became a 1 GB allocation while merely listing the variables: found by fuzz_mat). So
// before matio sees a v5 file, check that every top-level data element fits inside the file and
// that each variable's array header (flags, dims, name) fits inside its element, with at most
// 32 dimensions; for compressed elements the header is inflated (zlib) and checked the same way.
// v5 layout: a 128-byte header (endian mark "IM" at byte 126 for little-endian files), then
// elements of an 8-byte tag (uint32 type, uint32 nbytes) and nbytes of data, padded to 8
// bytes unless compressed (type 15). A sub-element tag in "small" format packs nbytes (<= 4)
// into the upper 16 bits of its first word and its data into the second.
void check_mat5_array_header(const std::string& path, std::uintmax_t pos, const unsigned char* p, std::size_t avail,
                             std::uintmax_t element_bytes, const std::function<std::uint32_t(const unsigned char*)>& u32) {
  const std::string where = "the variable at byte " + std::to_string(pos);
  std::uintmax_t off = 0;
  // Returns the sub-element's declared data size and advances off past it.
  auto sub = [&](const char* what, std::uint32_t& type) -> std::uintmax_t {
    if (off + 8 > element_bytes || off + 8 > avail)
      fail(path, "", "corrupt MATLAB v5 file: " + where + " ends inside its " + what + " tag");
    const std::uint32_t w0 = u32(p + off), w1 = u32(p + off + 4);
    if (w0 >> 16) {  // small data element
      type = w0 & 0xffff;
      off += 8;
      if ((w0 >> 16) > 4) fail(path, "", "corrupt MATLAB v5 file: " + where + " has a malformed " + what + " tag");
      return w0 >> 16;
    }
    type = w0;
    const std::uintmax_t padded = (std::uintmax_t(w1) + 7) / 8 * 8;
    if (off + 8 + w1 > element_bytes)
      fail(path, "", "corrupt MATLAB v5 file: " + where + " declares a " + what + " of " + std::to_string(w1) +
                         " bytes in an element of " + std::to_string(element_bytes) + " bytes");
    off += 8 + padded;
    return w1;
  };
  std::uint32_t type = 0;
  if (sub("array flags", type) != 8 || type != 6)
    fail(path, "", "corrupt MATLAB v5 file: " + where + " has malformed array flags");
  const std::uintmax_t dims = sub("dimensions", type);
  if (type != 5 || dims % 4 != 0 || dims > 4 * 32)
    fail(path, "", "corrupt MATLAB v5 file: " + where + " declares " + std::to_string(dims / 4) +
                       " dimensions of type " + std::to_string(type) + " (int32, at most 32 expected)");
  sub("name", type);
}

// The variable's name from an inflated array header (flags, dims, name sub-elements), or
// "at byte <pos>" when the header is too short or malformed to hold one.
std::string mat5_variable_label(std::uintmax_t pos, const unsigned char* p, std::size_t avail,
                                const std::function<std::uint32_t(const unsigned char*)>& u32) {
  const std::string fallback = "the variable at byte " + std::to_string(pos);
  std::size_t off = 0;
  for (int k = 0; k < 3; ++k) {
    if (off + 8 > avail) return fallback;
    const std::uint32_t w0 = u32(p + off), w1 = u32(p + off + 4);
    std::size_t len = 0, data = off + 8, next = 0;
    if (w0 >> 16) {  // small data element: data in the tag's second word
      len = w0 >> 16;
      data = off + 4;
      next = off + 8;
    } else {
      len = w1;
      next = off + 8 + (std::size_t(w1) + 7) / 8 * 8;
    }
    if (k == 2) {
      if (len == 0 || len > 255 || data + len > avail) return fallback;
      std::string name(reinterpret_cast<const char*>(p + data), len);
      for (char c : name)
        if (static_cast<unsigned char>(c) < 32 || static_cast<unsigned char>(c) > 126) return fallback;
      return "variable '" + name + "' (at byte " + std::to_string(pos) + ")";
    }
    off = next;
  }
  return fallback;
}

// A compressed (miCOMPRESSED) element is inflated in full before libmatio sees it: libmatio
// ignores zlib errors, so a few corrupted payload bytes loaded silently as different data
// (the scene mean changed and `qdo simulate` exited 0). Every byte of the element must
// inflate, the stream must end (Z_STREAM_END, which includes zlib's adler32 check of the
// decoded bytes) exactly at the element's end, and the decoded size must match the inner
// element's tag. The header is checked as for uncompressed variables. Memory stays bounded:
// the stream is decoded in chunks and only the first bytes (the header) are kept.
void check_mat5_compressed(const std::string& path, std::ifstream& in, std::uintmax_t pos, std::uint32_t nbytes,
                           const std::function<std::uint32_t(const unsigned char*)>& u32) {
  constexpr std::size_t kHeader = 256;  // enough for flags, 32 dims and a name tag
  constexpr std::size_t kChunk = std::size_t{1} << 16;
  std::vector<unsigned char> zin(kChunk), zout(kChunk), head;
  head.reserve(8 + kHeader);
  z_stream zs{};
  if (inflateInit(&zs) != Z_OK) fail(path, "", "zlib initialisation failed");
  struct End {
    z_stream* z;
    ~End() { inflateEnd(z); }
  } end{&zs};
  const std::string at = "the compressed variable at byte " + std::to_string(pos);
  auto label = [&] {
    return head.size() >= 8 ? mat5_variable_label(pos, head.data() + 8, head.size() - 8, u32) : at;
  };
  std::uintmax_t left = nbytes, decoded = 0;
  const std::uintmax_t cap = std::uintmax_t(nbytes) * kMaxExpansion + kSlackBytes;
  int rc = Z_OK;
  bool declared_checked = false;
  while (rc != Z_STREAM_END) {
    if (zs.avail_in == 0) {
      if (left == 0) break;
      const std::size_t want = static_cast<std::size_t>(std::min<std::uintmax_t>(left, kChunk));
      in.read(reinterpret_cast<char*>(zin.data()), static_cast<std::streamsize>(want));
      if (static_cast<std::size_t>(in.gcount()) != want)
        fail(path, label(), "truncated MATLAB v5 file: " + at + " ends before its " + std::to_string(nbytes) +
                                " compressed bytes");
      left -= want;
      zs.next_in = zin.data();
      zs.avail_in = static_cast<uInt>(want);
    }
    zs.next_out = zout.data();
    zs.avail_out = static_cast<uInt>(zout.size());
    rc = inflate(&zs, Z_NO_FLUSH);
    const std::size_t got = zout.size() - zs.avail_out;
    if (head.size() < 8 + kHeader)
      head.insert(head.end(), zout.begin(), zout.begin() + static_cast<std::ptrdiff_t>(std::min(got, 8 + kHeader - head.size())));
    decoded += got;
    if (!declared_checked && head.size() >= 8) {
      declared_checked = true;
      const std::uint32_t declared = u32(head.data() + 4);
      if (u32(head.data()) == 14 && declared > cap)
        fail(path, label(), "corrupt MATLAB v5 file: " + at + " declares " + std::to_string(declared) +
                                " bytes, more than " + std::to_string(nbytes) + " compressed bytes can hold");
    }
    if (rc == Z_NEED_DICT || rc == Z_DATA_ERROR || rc == Z_MEM_ERROR || rc == Z_STREAM_ERROR)
      fail(path, label(), "corrupt MATLAB v5 file: " + at + " does not decompress (zlib: " +
                              (zs.msg ? zs.msg : "error " + std::to_string(rc)) + "; " + std::to_string(decoded) +
                              " bytes decoded); the payload is damaged");
    if (rc == Z_BUF_ERROR && zs.avail_in != 0)
      fail(path, label(), "corrupt MATLAB v5 file: " + at + " does not decompress (zlib made no progress)");
    if (decoded > cap)
      fail(path, label(), "corrupt MATLAB v5 file: " + at + " decompresses to more than " + std::to_string(cap) +
                              " bytes, more than " + std::to_string(nbytes) + " compressed bytes can hold");
  }
  if (rc != Z_STREAM_END)
    fail(path, label(), "corrupt MATLAB v5 file: " + at + " ends inside its zlib stream (" + std::to_string(decoded) +
                            " bytes decoded, no end-of-stream/checksum); the payload is damaged or truncated");
  if (zs.avail_in != 0 || left != 0)
    fail(path, label(), "corrupt MATLAB v5 file: " + at + " has " + std::to_string(zs.avail_in + left) +
                            " bytes after its zlib stream inside its " + std::to_string(nbytes) + "-byte element");
  if (head.size() < 8) fail(path, label(), "corrupt MATLAB v5 file: " + at + " decompresses to less than a tag");
  const std::uint32_t inner_type = u32(head.data()), inner_bytes = u32(head.data() + 4);
  if (inner_type == 14 && inner_bytes > 0) {
    if (decoded < std::uintmax_t(inner_bytes) + 8)
      fail(path, label(), "corrupt MATLAB v5 file: " + at + " decompresses to " + std::to_string(decoded) +
                              " bytes but its matrix tag declares " + std::to_string(inner_bytes) + " + 8");
    check_mat5_array_header(path, pos, head.data() + 8, head.size() - 8, inner_bytes, u32);
  }
}

void check_mat5_extent(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::error_code ec;
  const std::uintmax_t size = fs::file_size(path, ec);
  unsigned char head[128];
  if (ec || !in.read(reinterpret_cast<char*>(head), sizeof head)) fail(path, "", "truncated MATLAB v5 header");
  const bool swap = head[126] == 'M';  // "MI": written big-endian
  const std::function<std::uint32_t(const unsigned char*)> u32 = [swap](const unsigned char* b) {
    return swap ? (std::uint32_t(b[0]) << 24) | (std::uint32_t(b[1]) << 16) | (std::uint32_t(b[2]) << 8) | b[3]
                : (std::uint32_t(b[3]) << 24) | (std::uint32_t(b[2]) << 16) | (std::uint32_t(b[1]) << 8) | b[0];
  };
  constexpr std::size_t kHeader = 256;  // enough for flags, 32 dims and a name tag
  std::uintmax_t pos = 128;
  while (pos < size) {
    unsigned char tag[8];
    in.seekg(static_cast<std::streamoff>(pos));
    if (size - pos < 8 || !in.read(reinterpret_cast<char*>(tag), sizeof tag))
      fail(path, "", "truncated MATLAB v5 file: incomplete element tag at byte " + std::to_string(pos));
    const std::uint32_t type = u32(tag), nbytes = u32(tag + 4);
    const std::uintmax_t padded = type == 15 ? nbytes : (std::uintmax_t(nbytes) + 7) / 8 * 8;
    if (pos + 8 + padded > size && pos + 8 + nbytes > size)
      fail(path, "", "truncated MATLAB v5 file: the element at byte " + std::to_string(pos) + " declares " +
                         std::to_string(nbytes) + " bytes but the file has " + std::to_string(size) + " bytes");
    if (type == 14 && nbytes > 0) {  // miMATRIX
      std::vector<unsigned char> h(std::min<std::size_t>(kHeader, nbytes));
      in.read(reinterpret_cast<char*>(h.data()), static_cast<std::streamsize>(h.size()));
      check_mat5_array_header(path, pos, h.data(), static_cast<std::size_t>(in.gcount()), nbytes, u32);
    } else if (type == 15 && nbytes > 0) {  // miCOMPRESSED: a zlib stream holding one miMATRIX element
      check_mat5_compressed(path, in, pos, nbytes, u32);
    }
    pos += 8 + padded;
  }
}

// A v7.3 variable is an HDF5 dataset "/<name>"; libmatio reads it with H5Dread, which trusted a
// corrupt datatype enough to zero 4 GB for a 3.8 KiB file (fuzz_mat). Check it as h5_read does.
void check_mat73_dataset(const std::string& path, const std::string& what, const std::string& key, std::size_t n) {
  H5Id file = h5_open_read(path);
  const std::string name = "/" + key;
  if (!h5_is_dataset(file.get(), name)) fail(path, what, "is not an HDF5 dataset in this v7.3 file");
  H5Id dset(H5Dopen2(file.get(), name.c_str(), H5P_DEFAULT), H5Dclose);
  if (!dset.valid()) fail(path, what, "cannot open" + h5_detail());
  H5Id type(H5Dget_type(dset.get()), H5Tclose);
  H5Id space(H5Dget_space(dset.get()), H5Sclose);
  if (!type.valid() || !space.valid()) fail(path, what, "cannot read type/shape" + h5_detail());
  const H5T_class_t cls = H5Tget_class(type.get());
  if (cls != H5T_INTEGER && cls != H5T_FLOAT) fail(path, what, "not numeric (integer or float) data");
  const int rank = H5Sget_simple_extent_ndims(space.get());
  if (rank < 0 || rank > 32) fail(path, what, "cannot read shape" + h5_detail());
  std::vector<hsize_t> dims(static_cast<std::size_t>(rank));
  H5Sget_simple_extent_dims(space.get(), dims.data(), nullptr);
  const std::vector<std::size_t> shape(dims.begin(), dims.end());
  std::size_t count = 0;
  if (!element_count(shape, std::size_t(1) << 31, count) || count != n)
    fail(path, what, "HDF5 shape " + shape_str(shape) + " does not match the variable's " + std::to_string(n) + " elements");
  check_h5_storage(path, what, dset.get(), type.get(), shape, n);
}

// Everything qdo reads is MATLAB v5 or v7.3: a 116-byte text header starting "MATLAB", the
// version (0x0100 v5, 0x0200 v7.3) at byte 124 and the endian mark "IM" / "MI" at byte 126.
// Anything else is refused before libmatio sees it: libmatio falls back to the v4 format,
// whose reader allocates what the first bytes declare (a 208-byte file took 12 s and half a
// gigabyte in fuzz_mat). v5 files then get the structure check above.
void check_mat_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  unsigned char head[128] = {};
  in.read(reinterpret_cast<char*>(head), sizeof head);
  const bool text = in.gcount() == 128 && std::memcmp(head, "MATLAB", 6) == 0;
  const bool le = head[126] == 'I' && head[127] == 'M', be = head[126] == 'M' && head[127] == 'I';
  const unsigned version = le ? head[124] | (unsigned(head[125]) << 8) : (unsigned(head[124]) << 8) | head[125];
  if (!text || !(le || be) || (version != 0x0100 && version != 0x0200))
    fail(path, "", "not a MATLAB v5 or v7.3 .mat file (no \"MATLAB\" text header with version 5 or 7.3; v4 files are not supported)");
  if (version == 0x0100) check_mat5_extent(path);
}

// A matio variable's data (n elements, column-major) as doubles.
void mat_data_to_double(const std::string& path, const std::string& what, const matvar_t& v, std::size_t n,
                        std::vector<double>& out) {
  switch (v.class_type) {
    case MAT_C_DOUBLE: mat_convert<double>(v.data, n, out); break;
    case MAT_C_SINGLE: mat_convert<float>(v.data, n, out); break;
    case MAT_C_INT8: mat_convert<std::int8_t>(v.data, n, out); break;
    case MAT_C_UINT8: mat_convert<std::uint8_t>(v.data, n, out); break;
    case MAT_C_INT16: mat_convert<std::int16_t>(v.data, n, out); break;
    case MAT_C_UINT16: mat_convert<std::uint16_t>(v.data, n, out); break;
    case MAT_C_INT32: mat_convert<std::int32_t>(v.data, n, out); break;
    case MAT_C_UINT32: mat_convert<std::uint32_t>(v.data, n, out); break;
    case MAT_C_INT64: mat_convert<std::int64_t>(v.data, n, out); break;
    case MAT_C_UINT64: mat_convert<std::uint64_t>(v.data, n, out); break;
    default: fail(path, what, "unsupported class");
  }
}

// Reads a numeric variable from a MATLAB v5/v7.3 file; dims are MATLAB's [d0 d1 d2],
// data column-major (element (i,j,k) at i + d0*j + d0*d1*k).
// With band_axis non-null, also reads the first of kBandAxisNames the file holds as a
// numeric vector (1 x n or n x 1, at most 65536 elements) into it; its key stays empty when
// there is none.
RawArray read_mat_raw(const std::string& path, const std::string& key, RawArray* band_axis = nullptr) {
  static const int log_once = Mat_LogInitFunc("qdo", matio_log);
  (void)log_once;
  h5_quiet();  // matio reads v7.3 through HDF5
  g_matio_last.clear();
  check_mat_file(path);
  MatFile mat(Mat_Open(path.c_str(), MAT_ACC_RDONLY));
  if (!mat) fail(path, "", "not a readable MATLAB .mat file" + matio_detail());
  if (Mat_GetVersion(mat.get()) != MAT_FT_MAT5 && Mat_GetVersion(mat.get()) != MAT_FT_MAT73)
    fail(path, "", "not a MATLAB v5 or v7.3 .mat file");

  RawArray raw;
  raw.column_major = true;
  // Every variable as "name [dims] class"; the numeric 3-D ones are the cube candidates.
  std::vector<std::string> all, candidates;
  auto list = [](const std::vector<std::string>& v) {
    std::string s;
    for (const auto& x : v) s += (s.empty() ? "" : ", ") + x;
    return s.empty() ? std::string("none readable") : s;
  };
  auto scan = [&] {
    Mat_Rewind(mat.get());
    while (MatVar info{Mat_VarReadNextInfo(mat.get())}) {
      all.push_back(std::string(info->name ? info->name : "?") + " " + shape_str(mat_dims(*info)) + " " +
                    mat_class_name(info->class_type));
      if (info->name && info->rank == 3 && mat_numeric(*info)) candidates.push_back(info->name);
    }
  };
  if (key.empty()) {
    scan();
    if (candidates.empty()) fail(path, "", "no numeric 3-D variable (variables: " + list(all) + ")" + matio_detail());
    if (candidates.size() > 1)
      fail(path, "", "several numeric 3-D variables (" + list(candidates) + "); choose one with the cube key");
    raw.key = candidates.front();
  } else {
    raw.key = key;
  }
  const std::string what = "variable '" + raw.key + "'";
  {
    MatVar info(Mat_VarReadInfo(mat.get(), raw.key.c_str()));
    if (!info) {
      const std::string detail = matio_detail();
      scan();
      fail(path, what, "missing or unreadable (variables: " + list(all) + ")" + detail);
    }
    raw.dims = mat_dims(*info);
    if (!mat_numeric(*info))
      fail(path, what, std::string("not a real numeric array (class ") + mat_class_name(info->class_type) +
                           (info->isComplex ? ", complex" : "") + ")");
    std::size_t n = 0;
    if (!element_count(raw.dims, std::size_t(1) << 31, n))
      fail(path, what, "shape " + shape_str(raw.dims) + " exceeds the limit of 2^31 elements");
    // v5 stores a variable raw unless it is compressed (possibly in a narrower type than its
    // class, at least 1 byte per element); v7.3 (HDF5) may use any filter.
    const bool raw_v5 = Mat_GetVersion(mat.get()) == MAT_FT_MAT5 && info->compression == MAT_COMPRESSION_NONE;
    check_declared_bytes(path, what, raw.dims, n, 1, !raw_v5);
    if (Mat_GetVersion(mat.get()) == MAT_FT_MAT73) check_mat73_dataset(path, what, raw.key, n);
  }
  MatVar var(Mat_VarRead(mat.get(), raw.key.c_str()));
  if (!var || !var->data) fail(path, what, "cannot read data (truncated or corrupt file?)" + matio_detail());
  std::size_t n = 0;
  element_count(raw.dims, std::size_t(1) << 31, n);
  if (var->rank != static_cast<int>(raw.dims.size()) || !std::equal(raw.dims.begin(), raw.dims.end(), var->dims) ||
      var->data_size <= 0 || var->nbytes < n * static_cast<std::size_t>(var->data_size))
    fail(path, what, "data size does not match its shape " + shape_str(raw.dims) + " (truncated or corrupt file?)");
  mat_data_to_double(path, what, *var, n, raw.data);
  raw.kind = mat_num_kind(*var);
  if (band_axis) {
    for (const char* name : kBandAxisNames) {
      const std::string awhat = std::string("variable '") + name + "'";
      MatVar info(Mat_VarReadInfo(mat.get(), name));
      if (!info) continue;
      band_axis->key = name;
      band_axis->dims = mat_dims(*info);
      std::size_t na = 0;
      if (!mat_numeric(*info) || !element_count(band_axis->dims, 65536, na) || !is_vector_shape(band_axis->dims, na))
        fail(path, awhat, "a band axis must be a real numeric vector of at most 65536 wavelengths in nm (found " +
                              shape_str(band_axis->dims) + " " + mat_class_name(info->class_type) + ")");
      const bool raw_axis = Mat_GetVersion(mat.get()) == MAT_FT_MAT5 && info->compression == MAT_COMPRESSION_NONE;
      check_declared_bytes(path, awhat, band_axis->dims, na, 1, !raw_axis);
      if (Mat_GetVersion(mat.get()) == MAT_FT_MAT73) check_mat73_dataset(path, awhat, name, na);
      MatVar av(Mat_VarRead(mat.get(), name));
      if (!av || !av->data || av->data_size <= 0 || av->nbytes < na * static_cast<std::size_t>(av->data_size))
        fail(path, awhat, "cannot read data (truncated or corrupt file?)" + matio_detail());
      mat_data_to_double(path, awhat, *av, na, band_axis->data);
      break;
    }
  }
  return raw;
}

// A MATLAB file starts with a 116-byte text header "MATLAB 5.0 MAT-file..." (v5 and v7.3).
bool looks_like_mat(const std::string& path) {
  std::string ext = fs::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  if (ext == ".mat") return true;
  std::ifstream in(path, std::ios::binary);
  char head[6] = {};
  in.read(head, sizeof head);
  return in.gcount() == 6 && std::memcmp(head, "MATLAB", 6) == 0;
}

// ---------------------------------------------------------------------------------------
// PNG helpers
// ---------------------------------------------------------------------------------------

struct Rgb {
  double r, g, b;
};

// Approximate colour of a visible wavelength (piecewise linear, after D. Bruton), with the
// intensity fading towards the ends of 380..780 nm; outside that range a neutral gray.
Rgb wavelength_rgb(double nm) {
  if (!(nm >= 380 && nm <= 780)) return {0.7, 0.7, 0.7};
  Rgb c{0, 0, 0};
  if (nm < 440) c = {(440 - nm) / 60, 0, 1};
  else if (nm < 490) c = {0, (nm - 440) / 50, 1};
  else if (nm < 510) c = {0, 1, (510 - nm) / 20};
  else if (nm < 580) c = {(nm - 510) / 70, 1, 0};
  else if (nm < 645) c = {1, (645 - nm) / 65, 0};
  else c = {1, 0, 0};
  double f = 1;
  if (nm < 420) f = 0.3 + 0.7 * (nm - 380) / 40;
  else if (nm > 700) f = 0.3 + 0.7 * (780 - nm) / 80;
  return {c.r * f, c.g * f, c.b * f};
}

unsigned char to_byte(double v01) {
  const double v = std::clamp(v01, 0.0, 1.0);
  return static_cast<unsigned char>(std::lround(v * 255.0));
}

double srgb_encode(double v) { return v <= 0.0031308 ? 12.92 * v : 1.055 * std::pow(v, 1 / 2.4) - 0.055; }

void require_finite(const std::string& path, const std::string& what, const std::vector<double>& v) {
  const std::size_t bad = count_nonfinite(v);
  if (bad) fail(path, what, std::to_string(bad) + " non-finite values");
}

// An output about to be written: NaN or Inf is a NumericalError (nothing is written).
void require_finite_output(const std::string& path, const std::string& what, const std::vector<double>& v) {
  const std::size_t bad = count_nonfinite(v);
  if (bad)
    throw NumericalError("file '" + path + "': " + what + ": " + std::to_string(bad) + " of " + std::to_string(v.size()) +
                         " values are NaN or Inf; not written");
}

// One tile of a montage: plane p of stack cropped to (y0, x0, h, w), box-averaged by factor f.
// Returns a (ceil(h/f) x ceil(w/f)) row-major image.
std::vector<double> tile_of(const RealStack& s, std::size_t p, std::size_t y0, std::size_t x0, std::size_t h,
                            std::size_t w, std::size_t f, std::size_t th, std::size_t tw) {
  std::vector<double> t(th * tw, 0.0);
  for (std::size_t ty = 0; ty < th; ++ty)
    for (std::size_t tx = 0; tx < tw; ++tx) {
      double sum = 0;
      std::size_t cnt = 0;
      for (std::size_t y = ty * f; y < std::min(h, ty * f + f); ++y)
        for (std::size_t x = tx * f; x < std::min(w, tx * f + f); ++x, ++cnt) sum += s(p, y0 + y, x0 + x);
      t[ty * tw + tx] = cnt ? sum / static_cast<double>(cnt) : 0.0;
    }
  return t;
}

}  // namespace

// =========================================================================================
// HDF5 public API
// =========================================================================================

void h5_write(const std::string& path, const std::vector<H5Dataset>& datasets,
              const std::map<std::string, std::string>& root_str_attrs) {
  for (const H5Dataset& d : datasets) {
    if (const std::size_t bad = count_nonfinite(d.data))
      throw NumericalError("file '" + path + "': dataset '" + d.name + "': " + std::to_string(bad) + " of " +
                           std::to_string(d.data.size()) + " values are NaN or Inf; not written");
    for (const auto& kv : d.num_attrs)
      if (!std::isfinite(kv.second))
        throw NumericalError("file '" + path + "': dataset '" + d.name + "': attribute '" + kv.first + "' = " +
                             to_str(kv.second) + " is not finite; not written");
  }
  h5_write_unchecked(path, datasets, root_str_attrs);
}

void h5_write_unchecked(const std::string& path, const std::vector<H5Dataset>& datasets,
                        const std::map<std::string, std::string>& root_str_attrs) {
  h5_quiet();
  AtomicFile out(path);
  {
    H5Id file(H5Fcreate(out.tmp().c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT), H5Fclose);
    if (!file.valid()) fail(path, "", "cannot create HDF5 file" + h5_detail());
    {
      H5Id root(H5Gopen2(file.get(), "/", H5P_DEFAULT), H5Gclose);
      if (!root.valid()) fail(path, "", "cannot open root group" + h5_detail());
      for (const auto& kv : root_str_attrs) h5_write_str_attr(root.get(), path, kv.first, kv.second);
    }
    for (const H5Dataset& d : datasets) h5_write_dataset(file.get(), path, d);
    if (!file.close()) fail(path, "", "closing (flushing) the HDF5 file failed" + h5_detail());
  }
  out.commit();
}

H5Dataset h5_read(const std::string& path, const std::string& name, std::size_t max_elements) {
  return h5_read_impl(path, name, max_elements, nullptr);
}

bool h5_has(const std::string& path, const std::string& name) {
  H5Id file = h5_open_read(path);
  return h5_is_dataset(file.get(), name);
}

// =========================================================================================
// Contract helpers
// =========================================================================================

void write_design(const std::string& path, const Design& d, const std::map<std::string, std::string>& provenance) {
  if (!(d.pitch_m > 0) || !std::isfinite(d.pitch_m)) reject("pitch_m", d.pitch_m, "a finite pitch > 0 in metres");
  if (d.height_m.rows != d.height_m.cols || d.height_m.rows == 0)
    reject("height_m", std::to_string(d.height_m.rows) + " x " + std::to_string(d.height_m.cols),
           "a non-empty square N x N map");
  H5Dataset h{"/height_m", {d.height_m.rows, d.height_m.cols}, d.height_m.data, {{"pitch_m", d.pitch_m}},
              {{"units", "m"}}};
  std::vector<H5Dataset> sets{h};
  if (!d.levels_m.empty()) sets.push_back({"/levels_m", {d.levels_m.size()}, d.levels_m, {}, {{"units", "m"}}});
  h5_write(path, sets, provenance);
}

Design read_design(const std::string& path) {
  const H5Dataset h = h5_read(path, "/height_m");
  const std::string what = "dataset '/height_m'";
  if (h.shape.size() != 2 || h.shape[0] != h.shape[1] || h.shape[0] == 0)
    fail(path, what, "shape " + shape_str(h.shape) + " is not a square N x N map");
  require_finite(path, what, h.data);
  const auto it = h.num_attrs.find("pitch_m");
  if (it == h.num_attrs.end()) fail(path, what, "attribute 'pitch_m' is missing");
  if (!(it->second > 0) || !std::isfinite(it->second))
    fail(path, what, "attribute 'pitch_m' = " + to_str(it->second) + " is invalid (must be finite and > 0)");
  Design d;
  d.height_m = Map2D(h.shape[0], h.shape[1]);
  d.height_m.data = h.data;
  d.pitch_m = it->second;
  if (h5_has(path, "/levels_m")) {
    const H5Dataset l = h5_read(path, "/levels_m");
    if (l.shape.size() != 1) fail(path, "dataset '/levels_m'", "shape " + shape_str(l.shape) + " is not 1-D");
    require_finite(path, "dataset '/levels_m'", l.data);
    d.levels_m = l.data;
  }
  return d;
}

void write_psf(const std::string& path, const RealStack& psf, const std::vector<double>& wavelengths_nm,
               double pitch_m, const std::map<std::string, double>& extra_num_attrs) {
  if (wavelengths_nm.size() != psf.planes)
    reject("wavelengths_nm", wavelengths_nm.size(), "one wavelength per PSF plane (" + std::to_string(psf.planes) + ")");
  if (!(pitch_m > 0) || !std::isfinite(pitch_m)) reject("pitch_m", pitch_m, "a finite pitch > 0 in metres");
  H5Dataset p{"/psf", {psf.planes, psf.rows, psf.cols}, psf.data, extra_num_attrs, {}};
  p.num_attrs["pitch_m"] = pitch_m;
  h5_write(path, {p, H5Dataset{"/wavelengths_nm", {wavelengths_nm.size()}, wavelengths_nm, {}, {{"units", "nm"}}}});
}

void write_cube(const std::string& path, const RealStack& cube, const std::vector<double>& wavelengths_nm) {
  if (wavelengths_nm.size() != cube.planes)
    reject("wavelengths_nm", wavelengths_nm.size(), "one wavelength per cube band (" + std::to_string(cube.planes) + ")");
  h5_write(path, {H5Dataset{"/cube", {cube.planes, cube.rows, cube.cols}, cube.data, {}, {}},
                  H5Dataset{"/wavelengths_nm", {wavelengths_nm.size()}, wavelengths_nm, {}, {{"units", "nm"}}}});
}

void write_rgb(const std::string& path, const RealStack& rgb, const std::map<std::string, double>& attrs) {
  if (rgb.planes != 3) reject("rgb planes", rgb.planes, "exactly 3 (R, G, B)");
  h5_write(path, {H5Dataset{"/rgb", {rgb.planes, rgb.rows, rgb.cols}, rgb.data, attrs, {}}});
}

// Output: (bands, H, W) row-major, divided by the scale. See io.hpp for the layout rules.
RealStack read_cube(const std::string& path, const CubeReadOptions& opt) {
  if (opt.layout != "auto" && opt.layout != "bhw" && opt.layout != "hwb")
    reject("layout", opt.layout, "\"auto\", \"bhw\" or \"hwb\"");
  if (!(opt.scale >= 0) || !std::isfinite(opt.scale)) reject("scale", opt.scale, "0 (auto) or a finite value > 0");
  require_file(path);
  const bool is_mat = looks_like_mat(path);
  if (!opt.wavelengths_nm.empty() && opt.expected_bands != 0 && opt.expected_bands != opt.wavelengths_nm.size())
    reject("expected_bands", opt.expected_bands,
           "0 or the number of wavelengths_nm (" + std::to_string(opt.wavelengths_nm.size()) + ")");
  RawArray raw, axis;
  if (is_mat) {
    raw = read_mat_raw(path, opt.key, &axis);
  } else {
    H5Dataset d = h5_read_impl(path, opt.key.empty() ? "/cube" : opt.key, std::size_t(1) << 31, &raw.kind);
    raw.key = d.name;
    raw.dims = d.shape;
    raw.data = std::move(d.data);
    // The band axis: beside the cube in its group, else at the root.
    const std::string group = raw.key.substr(0, raw.key.find_last_of('/') + 1);
    for (const std::string& prefix : {group, std::string("/")}) {
      for (const char* name : kBandAxisNames) {
        if (!axis.key.empty() || !h5_has(path, prefix + name)) continue;
        H5Dataset a = h5_read_impl(path, prefix + name, 65536, nullptr);
        if (!is_vector_shape(a.shape, a.data.size()))
          fail(path, "dataset '" + a.name + "'",
               "a band axis must be a numeric vector of wavelengths in nm (found shape " + shape_str(a.shape) + ")");
        axis.key = a.name;
        axis.dims = a.shape;
        axis.data = std::move(a.data);
      }
    }
  }
  const std::string what = std::string(is_mat ? "variable '" : "dataset '") + raw.key + "'";
  if (raw.dims.size() != 3)
    fail(path, what, "shape " + shape_str(raw.dims) + " is not a 3-D cube (H x W x bands or bands x H x W)");
  const std::vector<std::size_t>& d = raw.dims;
  if (d[0] == 0 || d[1] == 0 || d[2] == 0) fail(path, what, "shape " + shape_str(d) + " is empty");

  // Band axis: 0 ("bhw") or 2 ("hwb"). Compared with a configured grid, a file with its own
  // band axis has that many bands (conform_band_axis compares the grids below).
  std::size_t band_axis = 0;
  const bool use_axis = !axis.key.empty() && !opt.wavelengths_nm.empty();
  const std::size_t nb = use_axis ? axis.data.size() : (opt.expected_bands ? opt.expected_bands : opt.wavelengths_nm.size());
  if (opt.layout == "auto") {
    if (nb > 0) {
      const std::size_t first = is_mat ? 2 : 0, second = is_mat ? 0 : 2;
      if (d[first] == nb) band_axis = first;
      else if (d[second] == nb) band_axis = second;
      else fail(path, what, "shape " + shape_str(d) + " has no band axis of length " + std::to_string(nb) + " (bands expected)");
    } else {
      band_axis = is_mat ? 2 : 0;
    }
  } else {
    band_axis = opt.layout == "bhw" ? 0 : 2;
    if (nb > 0 && d[band_axis] != nb)
      fail(path, what, "shape " + shape_str(d) + " with layout " + opt.layout + " has " + std::to_string(d[band_axis]) +
                           " bands, " + std::to_string(nb) + " bands expected");
  }
  const std::size_t bad = count_nonfinite(raw.data);
  if (bad) fail(path, what, std::to_string(bad) + " non-finite values");

  double scale = opt.scale;
  if (scale == 0) {
    const std::string base = raw.key.substr(raw.key.find_last_of('/') == std::string::npos ? 0 : raw.key.find_last_of('/') + 1);
    const double maxv = raw.data.empty() ? 0.0 : *std::max_element(raw.data.begin(), raw.data.end());
    if (base == "rad" && maxv <= 4095) scale = 4095;
    else scale = raw.kind.integer ? raw.kind.max : 1.0;
  }

  // (i, j, k) -> source index, in the file's memory order.
  const std::size_t d0 = d[0], d1 = d[1], d2 = d[2];
  auto src = [&](std::size_t i, std::size_t j, std::size_t k) {
    return raw.column_major ? i + d0 * (j + d1 * k) : (i * d1 + j) * d2 + k;
  };
  RealStack out = band_axis == 0 ? RealStack(d0, d1, d2) : RealStack(d2, d0, d1);
  for (std::size_t i = 0; i < d0; ++i)
    for (std::size_t j = 0; j < d1; ++j)
      for (std::size_t k = 0; k < d2; ++k) {
        const double v = raw.data[src(i, j, k)] / scale;
        if (band_axis == 0) out(i, j, k) = v;
        else out(k, i, j) = v;
      }
  if (axis.key.empty() || opt.wavelengths_nm.empty()) return out;
  const std::string awhat = std::string(is_mat ? "variable '" : "dataset '") + axis.key + "'";
  return conform_band_axis(out, axis.data, opt.wavelengths_nm, opt.resample_bands, "file '" + path + "': " + awhat);
}

namespace {

// "31 bands, 400 ... 700 nm (step 10)" or the list when it is short or irregular.
std::string grid_str(const std::vector<double>& nm) {
  std::ostringstream o;
  o << nm.size() << (nm.size() == 1 ? " band" : " bands");
  if (nm.empty()) return o.str();
  o << ", " << nm.front();
  if (nm.size() > 1) {
    const double step = (nm.back() - nm.front()) / double(nm.size() - 1);
    bool regular = true;
    for (std::size_t k = 1; k < nm.size(); ++k)
      if (std::fabs(nm[k] - nm[k - 1] - step) > 1e-6 * std::fabs(step) + 1e-9) regular = false;
    if (regular) {
      o << " ... " << nm.back() << " nm (step " << step << ")";
    } else if (nm.size() <= 8) {
      for (std::size_t k = 1; k < nm.size(); ++k) o << ", " << nm[k];
      o << " nm";
    } else {
      o << ", " << nm[1] << ", ... " << nm.back() << " nm (irregular)";
    }
  } else {
    o << " nm";
  }
  return o.str();
}

}  // namespace

RealStack conform_band_axis(const RealStack& cube, const std::vector<double>& file_nm,
                            const std::vector<double>& grid_nm, bool resample, const std::string& origin) {
  auto refuse = [&](const std::string& problem) { throw InputError(origin + ": " + problem); };
  if (file_nm.size() != cube.planes)
    refuse("the band axis has " + std::to_string(file_nm.size()) + " wavelengths but the cube has " +
           std::to_string(cube.planes) + " bands");
  for (std::size_t k = 0; k < file_nm.size(); ++k)
    if (!std::isfinite(file_nm[k]) || file_nm[k] < kBandAxisMinNm || file_nm[k] > kBandAxisMaxNm)
      refuse("band axis value " + std::to_string(k) + " = " + std::to_string(file_nm[k]) + " is not a wavelength in nm (allowed: " +
             std::to_string(int(kBandAxisMinNm)) + " to " + std::to_string(int(kBandAxisMaxNm)) + " nm; µm or metres are not converted)");
  const bool ascending = file_nm.size() < 2 || file_nm[1] > file_nm[0];
  for (std::size_t k = 1; k < file_nm.size(); ++k)
    if (ascending ? !(file_nm[k] > file_nm[k - 1]) : !(file_nm[k] < file_nm[k - 1]))
      refuse("the band axis (" + grid_str(file_nm) + ") is not strictly monotonic at index " + std::to_string(k));
  if (grid_nm.empty()) return cube;
  bool same = file_nm.size() == grid_nm.size();
  for (std::size_t k = 0; same && k < grid_nm.size(); ++k) same = std::fabs(file_nm[k] - grid_nm[k]) <= kBandAxisToleranceNm;
  if (same) return cube;
  const std::string both = "the file's bands are " + grid_str(file_nm) + (ascending ? "" : " (descending)") +
                           ", the configuration's " + grid_str(grid_nm);
  if (!resample)
    refuse(both + "; they differ by more than " + std::to_string(kBandAxisToleranceNm).substr(0, 3) +
           " nm. Configure the same bands, or resample the cube onto the configured ones (--resample-bands)");
  // Linear interpolation along wavelength, per pixel, onto the configured grid, which must
  // lie inside the file's range (no extrapolation).
  std::vector<std::size_t> order(file_nm.size());
  for (std::size_t k = 0; k < order.size(); ++k) order[k] = ascending ? k : order.size() - 1 - k;
  std::vector<double> x(order.size());
  for (std::size_t k = 0; k < order.size(); ++k) x[k] = file_nm[order[k]];
  const double lo = x.front() - kBandAxisToleranceNm, hi = x.back() + kBandAxisToleranceNm;
  for (double g : grid_nm)
    if (g < lo || g > hi)
      refuse(both + "; " + std::to_string(g) + " nm lies outside the file's range, and bands are not extrapolated");
  RealStack out(grid_nm.size(), cube.rows, cube.cols);
  const std::size_t px = cube.rows * cube.cols;
  for (std::size_t b = 0; b < grid_nm.size(); ++b) {
    const double g = std::min(std::max(grid_nm[b], x.front()), x.back());
    std::size_t j = std::size_t(std::upper_bound(x.begin(), x.end(), g) - x.begin());
    j = std::min(std::max<std::size_t>(j, 1), x.size() - 1);
    const std::size_t k0 = x.size() == 1 ? 0 : j - 1, k1 = x.size() == 1 ? 0 : j;
    const double t = x.size() == 1 ? 0.0 : (g - x[k0]) / (x[k1] - x[k0]);
    const double* p0 = cube.plane(order[k0]);
    const double* p1 = cube.plane(order[k1]);
    double* q = out.plane(b);
    for (std::size_t i = 0; i < px; ++i) q[i] = (1 - t) * p0[i] + t * p1[i];
  }
  std::cerr << "qdo: note: " << origin << ": resampled from " << grid_str(file_nm) << (ascending ? "" : " (descending)")
            << " onto the configured " << grid_str(grid_nm) << " by linear interpolation\n";
  return out;
}

RadianceReport conform_radiance(RealStack& cube, const std::string& origin) {
  RadianceReport r;
  double mn = 0, mx = 0;
  for (std::size_t i = 0; i < cube.data.size(); ++i) {
    const double v = cube.data[i];
    if (!std::isfinite(v)) throw InputError(origin + ": value " + std::to_string(i) + " is not finite");
    if (i == 0 || v < mn) mn = v;
    if (i == 0 || v > mx) mx = v;
    if (v < 0) ++r.negative;
  }
  r.min = mn;
  r.max = mx;
  if (mn < -kRadianceNegativeTolerance) {
    std::ostringstream o;
    o << origin << ": " << r.negative << " negative radiance values, down to " << mn
      << " (full scale 1); values below " << -kRadianceNegativeTolerance
      << " are refused (wrong data type, offset or scale?). Allowed: 0 to 1 after the format's scale";
    throw InputError(o.str());
  }
  if (r.negative) {
    for (double& v : cube.data) v = std::max(v, 0.0);
    std::cerr << "qdo: note: " << origin << ": " << r.negative << " slightly negative values (down to " << mn
              << ", noise of a dark-frame subtraction) clipped to 0\n";
  }
  if (mx > 1.0 + kRadianceOverTolerance) {
    r.divided_by = mx;
    for (double& v : cube.data) v /= mx;
    std::cerr << "qdo: note: " << origin << ": values up to " << mx
              << " times full scale (HDR or unscaled data) divided by that maximum, so the brightest value is 1\n";
  } else if (mx > 1.0) {
    for (double& v : cube.data) v = std::min(v, 1.0);
  }
  return r;
}

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

// =========================================================================================
// PNG
// =========================================================================================

// pixels: height rows of width * channels bytes, interleaved (RGBRGB... or gray).
void write_png(const std::string& path, std::size_t width, std::size_t height, int channels,
               const std::vector<unsigned char>& pixels) {
  if (channels != 1 && channels != 3) reject("channels", channels, "1 (gray) or 3 (RGB)");
  const std::size_t max_dim = 0x7fffffffu;
  if (width == 0 || height == 0 || width > max_dim || height > max_dim)
    reject("png size", std::to_string(width) + " x " + std::to_string(height), "1 .. 2^31-1 pixels per side");
  const std::size_t ch = static_cast<std::size_t>(channels);
  if (pixels.size() != width * height * ch)
    reject("pixels", pixels.size(), "width * height * channels = " + std::to_string(width * height * ch) + " bytes");
  AtomicFile out(path);
  png_image img;
  std::memset(&img, 0, sizeof img);
  img.version = PNG_IMAGE_VERSION;
  img.width = static_cast<png_uint_32>(width);
  img.height = static_cast<png_uint_32>(height);
  img.format = channels == 1 ? PNG_FORMAT_GRAY : PNG_FORMAT_RGB;
  const int ok = png_image_write_to_file(&img, out.tmp().c_str(), 0, pixels.data(),
                                         static_cast<png_int_32>(width * ch), nullptr);
  const std::string msg = img.message;
  png_image_free(&img);
  if (!ok) fail(path, "", "PNG write failed: " + msg);
  out.commit();
}

// stack: planes x rows x cols; one tile per plane.
void write_montage_png(const std::string& path, const RealStack& stack, const std::vector<double>& wavelengths_nm,
                       double gamma, std::size_t crop) {
  const std::size_t P = stack.planes;
  if (P == 0 || stack.rows == 0 || stack.cols == 0 || stack.data.size() != P * stack.rows * stack.cols)
    reject("stack", std::to_string(P) + " x " + std::to_string(stack.rows) + " x " + std::to_string(stack.cols),
           "a non-empty stack whose data matches its shape");
  if (!wavelengths_nm.empty() && wavelengths_nm.size() != P)
    reject("wavelengths_nm", wavelengths_nm.size(), "empty or one per plane (" + std::to_string(P) + ")");
  if (!(gamma > 0) || !std::isfinite(gamma)) reject("gamma", gamma, "a finite value > 0");
  require_finite_output(path, "montage data", stack.data);
  const std::size_t h = crop ? std::min(crop, stack.rows) : stack.rows;
  const std::size_t w = crop ? std::min(crop, stack.cols) : stack.cols;
  const std::size_t y0 = (stack.rows - h) / 2, x0 = (stack.cols - w) / 2;
  const std::size_t grid_cols = static_cast<std::size_t>(std::ceil(std::sqrt(static_cast<double>(P))));
  const std::size_t grid_rows = (P + grid_cols - 1) / grid_cols;
  const std::size_t max_tile = std::max<std::size_t>(16, std::min<std::size_t>(256, 4096 / grid_cols));
  const std::size_t f = (std::max(h, w) + max_tile - 1) / max_tile;  // box-average factor
  const std::size_t th = (h + f - 1) / f, tw = (w + f - 1) / f, gap = 2;
  const std::size_t W = grid_cols * tw + (grid_cols - 1) * gap, H = grid_rows * th + (grid_rows - 1) * gap;
  std::vector<unsigned char> px(W * H * 3, 0);
  for (std::size_t p = 0; p < P; ++p) {
    const std::vector<double> t = tile_of(stack, p, y0, x0, h, w, f, th, tw);
    const double mx = *std::max_element(t.begin(), t.end());
    const Rgb tint = wavelengths_nm.empty() ? Rgb{1, 1, 1} : wavelength_rgb(wavelengths_nm[p]);
    const std::size_t oy = (p / grid_cols) * (th + gap), ox = (p % grid_cols) * (tw + gap);
    for (std::size_t y = 0; y < th; ++y)
      for (std::size_t x = 0; x < tw; ++x) {
        const double v = mx > 0 ? std::pow(std::max(t[y * tw + x], 0.0) / mx, gamma) : 0.0;
        unsigned char* q = &px[((oy + y) * W + ox + x) * 3];
        q[0] = to_byte(v * tint.r);
        q[1] = to_byte(v * tint.g);
        q[2] = to_byte(v * tint.b);
      }
  }
  write_png(path, W, H, 3, px);
}

// rgb3: 3 x H x W (planes R, G, B), linear values.
void write_rgb_png(const std::string& path, const RealStack& rgb3) {
  if (rgb3.planes != 3 || rgb3.rows == 0 || rgb3.cols == 0 || rgb3.data.size() != 3 * rgb3.rows * rgb3.cols)
    reject("rgb stack", std::to_string(rgb3.planes) + " x " + std::to_string(rgb3.rows) + " x " + std::to_string(rgb3.cols),
           "a non-empty 3 x H x W stack");
  require_finite_output(path, "rgb data", rgb3.data);
  std::vector<double> sorted = rgb3.data;
  const std::size_t k = std::min(sorted.size() - 1, static_cast<std::size_t>(0.999 * static_cast<double>(sorted.size())));
  std::nth_element(sorted.begin(), sorted.begin() + static_cast<std::ptrdiff_t>(k), sorted.end());
  double ref = sorted[k];
  if (!(ref > 0)) ref = *std::max_element(rgb3.data.begin(), rgb3.data.end());
  if (!(ref > 0)) ref = 1;
  const std::size_t n = rgb3.plane_size();
  std::vector<unsigned char> px(n * 3);
  for (std::size_t i = 0; i < n; ++i)
    for (std::size_t c = 0; c < 3; ++c) px[i * 3 + c] = to_byte(srgb_encode(std::clamp(rgb3.data[c * n + i] / ref, 0.0, 1.0)));
  write_png(path, rgb3.cols, rgb3.rows, 3, px);
}

// m: rows x cols, row-major.
void write_map_png(const std::string& path, const Map2D& m) {
  if (m.rows == 0 || m.cols == 0 || m.data.size() != m.rows * m.cols)
    reject("map", std::to_string(m.rows) + " x " + std::to_string(m.cols), "a non-empty map whose data matches its shape");
  require_finite_output(path, "map data", m.data);
  static const Rgb viridis[] = {{68, 1, 84},    {71, 45, 123},  {59, 82, 139},  {44, 114, 142}, {33, 145, 140},
                                {40, 174, 128}, {94, 201, 98},  {173, 220, 48}, {253, 231, 37}};
  const std::size_t na = sizeof(viridis) / sizeof(viridis[0]);
  const auto [lo_it, hi_it] = std::minmax_element(m.data.begin(), m.data.end());
  const double lo = *lo_it, span = *hi_it - *lo_it;
  std::vector<unsigned char> px(m.data.size() * 3);
  for (std::size_t i = 0; i < m.data.size(); ++i) {
    const double t = span > 0 ? (m.data[i] - lo) / span : 0.5;
    const double pos = t * static_cast<double>(na - 1);
    const std::size_t a = std::min(na - 2, static_cast<std::size_t>(pos));
    const double u = pos - static_cast<double>(a);
    const Rgb& c0 = viridis[a];
    const Rgb& c1 = viridis[a + 1];
    px[i * 3 + 0] = to_byte((c0.r + u * (c1.r - c0.r)) / 255);
    px[i * 3 + 1] = to_byte((c0.g + u * (c1.g - c0.g)) / 255);
    px[i * 3 + 2] = to_byte((c0.b + u * (c1.b - c0.b)) / 255);
  }
  write_png(path, m.cols, m.rows, 3, px);
}

namespace detail {
// For src/datasets.cpp, which lists .mat variables through libmatio too (declared there).
void check_mat_file(const std::string& path) { qdo::check_mat_file(path); }
}  // namespace detail

// =========================================================================================
// Output staging
// =========================================================================================

namespace {
OutputStage* g_stage = nullptr;  // the active stage (CLI: one per command)
}  // namespace

OutputStage::OutputStage(bool defer_files) : defer_files_(defer_files) {
  if (g_stage) throw Error("OutputStage: a stage is already active (one per command)");
  g_stage = this;
}

OutputStage::~OutputStage() {
  g_stage = nullptr;
  if (committed_) return;
  std::error_code ec;
  for (const auto& f : files_) fs::remove(f.first, ec);
  // Folders this command created, deepest first, removed only while empty: never anything
  // else's (a non-empty folder is kept, e.g. a run folder holding a resumable checkpoint).
  for (auto it = dirs_.rbegin(); it != dirs_.rend(); ++it) fs::remove(*it, ec);
}

void OutputStage::commit() {
  if (committed_) return;
  // What can be known to fail is checked before the first rename, so that a set is renamed
  // whole or not at all: a final name taken by a folder, a temporary file that vanished.
  for (const auto& f : files_) {
    std::error_code ec;
    if (fs::is_directory(f.second, ec)) fail(f.second, "", "is a folder; the command's outputs were not written");
    if (!fs::is_regular_file(f.first, ec))
      fail(f.second, "", "its temporary file '" + f.first + "' disappeared; the command's outputs were not written");
  }
  for (const auto& f : files_) {
    std::error_code ec;
    fs::rename(f.first, f.second, ec);
    if (ec) fail(f.second, "", "cannot rename the temporary file '" + f.first + "' into place: " + ec.message());
  }
  files_.clear();
  committed_ = true;
}

void commit_output(const std::string& tmp, const std::string& path) {
  if (g_stage && g_stage->defer_files_) {
    for (auto& f : g_stage->files_)
      if (f.second == path) {  // written again: the newer temporary file replaces the older
        if (f.first != tmp) {
          std::error_code ec;
          fs::remove(f.first, ec);
        }
        f.first = tmp;
        return;
      }
    g_stage->files_.emplace_back(tmp, path);
    return;
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0)
    fail(path, "", std::string("cannot rename temp file into place: ") + std::strerror(errno));
}

std::string readable_output(const std::string& path) {
  if (g_stage)
    for (const auto& f : g_stage->files_)
      if (f.second == path) return f.first;
  return path;
}

void make_output_dir(const std::string& dir, const std::string& argument) {
  if (dir.empty()) reject(argument, "\"\"", "a folder name");
  std::error_code ec;
  if (fs::is_directory(dir, ec)) return;
  // The ancestors that do not exist yet, outermost first: the stage removes them on failure.
  std::vector<fs::path> missing;
  for (fs::path p = fs::path(dir).lexically_normal(); !p.empty() && !fs::exists(p, ec); p = p.parent_path()) {
    missing.push_back(p);
    if (p == p.parent_path()) break;
  }
  fs::create_directories(dir, ec);
  if (ec || !fs::is_directory(dir))
    reject(argument, dir, "a folder that can be created (" + (ec ? ec.message() : std::string("exists as a file")) + ")");
  if (g_stage)
    for (auto it = missing.rbegin(); it != missing.rend(); ++it) g_stage->dirs_.push_back(it->string());
}

void write_text_atomic(const std::string& path, const std::string& text) {
  AtomicFile out(path);
  {
    std::ofstream f(out.tmp(), std::ios::binary | std::ios::trunc);
    if (!f) fail(path, "", std::string("cannot create file: ") + std::strerror(errno));
    f.write(text.data(), static_cast<std::streamsize>(text.size()));
    f.close();
    if (!f) fail(path, "", "write failed");
  }
  out.commit();
}

}  // namespace qdo
