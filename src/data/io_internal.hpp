// Private to src/: what the io_*.cpp and datasets_*.cpp files share. The one RAII wrapper
// for HDF5 ids (H5Id) and for libmatio files and variables (MatFile, MatVar), the "file '...'"
// failure and shape helpers, the hostile-input size checks, atomic output files, and the HDF5
// and MATLAB readers that read_cube and the dataset probes build on. Not installed; the
// public API is include/qdo/data/io.hpp.
#pragma once

#include <hdf5.h>
#include <matio.h>
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"

namespace qdo::io_detail {

// ---------------------------------------------------------------------------------------
// Shared helpers (src/data/io_common.cpp)
// ---------------------------------------------------------------------------------------

[[noreturn]] void fail(const std::string& file, const std::string& what, const std::string& problem);
std::string shape_str(const std::vector<std::size_t>& shape);
bool element_count(const std::vector<std::size_t>& shape, std::size_t max_elements, std::size_t& n);
// A reader allocates what a file declares, so a tiny corrupt file must not be able to declare
// gigabytes. Uncompressed data must fit in the file; compressed data (deflate, the strongest
// filter HDF5 and MATLAB files use) expand at most ~1032:1. Checked before any allocation.
inline constexpr std::uintmax_t kMaxExpansion = 1100;
inline constexpr std::uintmax_t kSlackBytes = std::uintmax_t{1} << 16;
void check_declared_bytes(const std::string& path, const std::string& what, const std::vector<std::size_t>& shape,
                          std::size_t elements, std::size_t bytes_per_element, bool compressed);
std::size_t count_nonfinite(const std::vector<double>& v);
void require_file(const std::string& path);

// A PNG file's stored samples, no gamma or colour transform applied (src/data/io_png_codes.cpp):
// height x width x channels, row-major, interleaved. A palette is expanded to its RGB entries,
// 1/2/4-bit gray to 8-bit codes, a tRNS chunk to an alpha channel.
struct PngCodes {
  std::size_t width = 0, height = 0, channels = 0;  // channels: 1 gray, 2 gray+alpha, 3 RGB, 4 RGBA
  int bit_depth = 0;                                  // 8 or 16
  bool has_alpha = false, from_palette = false;
  std::vector<std::uint16_t> samples;
};
PngCodes read_png_codes(const std::string& path);

// Writes go to "<path>.tmp-<pid>"; commit() renames onto path; the destructor removes the
// temp file unless committed, so an exception anywhere leaves nothing behind.
class AtomicFile {
 public:
  explicit AtomicFile(std::string path)
      : path_(std::move(path)), tmp_(path_ + ".tmp-" + std::to_string(static_cast<long>(::getpid()))) {
    if (path_.empty()) reject("path", "\"\"", "an output file name is required");
    wait_if_abandoned();
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

// ---------------------------------------------------------------------------------------
// HDF5 (src/data/io_hdf5.cpp)
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

void h5_quiet();
std::string h5_detail();
H5Id h5_open_read(const std::string& path);
bool h5_is_dataset(hid_t file, const std::string& name);

// Numeric type of a dataset, for the automatic cube scale.
struct NumKind {
  bool integer = false;
  double max = 1;  // largest representable value for integers
};

void check_h5_storage(const std::string& path, const std::string& what, hid_t dset, hid_t type,
                      const std::vector<std::size_t>& shape, std::size_t n);
H5Dataset h5_read_impl(const std::string& path, const std::string& name, std::size_t max_elements,
                       NumKind* kind);
std::vector<H5Dataset> h5_read_many_impl(const std::string& path, const std::vector<std::string>& names, std::size_t max_elements);
// An open numeric (integer or float) dataset `name` of an open file, with its type, dataspace
// and shape; every failure is fail(path, what, ...): missing (`missing` says how), unreadable,
// not numeric, or a rank above 32.
struct H5Numeric {
  H5Id dset, type, space;
  std::vector<std::size_t> shape;
};
H5Numeric h5_open_numeric(hid_t file, const std::string& name, const std::string& path, const std::string& what,
                          const std::string& missing);

// ---------------------------------------------------------------------------------------
// MATLAB .mat (src/data/io_mat.cpp)
// ---------------------------------------------------------------------------------------

struct MatCloser {
  void operator()(mat_t* m) const { Mat_Close(m); }
};
struct MatVarFreer {
  void operator()(matvar_t* v) const { Mat_VarFree(v); }
};
using MatFile = std::unique_ptr<mat_t, MatCloser>;
using MatVar = std::unique_ptr<matvar_t, MatVarFreer>;

bool mat_numeric(const matvar_t& v);
std::vector<std::size_t> mat_dims(const matvar_t& v);

// A raw array as read from a file: dims in reading order, data in that file's memory order.
struct RawArray {
  std::string key;
  std::vector<std::size_t> dims;
  std::vector<double> data;
  bool column_major = false;  // MATLAB order (first index fastest) vs C order
  NumKind kind;
};

bool is_vector_shape(const std::vector<std::size_t>& dims, std::size_t n);
void check_mat_file(const std::string& path);
RawArray read_mat_raw(const std::string& path, const std::string& key, RawArray* band_axis = nullptr);
bool looks_like_mat(const std::string& path);

}  // namespace qdo::io_detail
