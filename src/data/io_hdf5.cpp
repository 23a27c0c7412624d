// HDF5 (contract files): reading with its hostile-input checks and writing through AtomicFile.
// The contract helpers built on it (design, PSF, cube and RGB files) are io_contract.cpp.
#include <hdf5.h>

#include <zlib.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstring>
#include <limits>
#include <memory>
#include <thread>
#include <unordered_set>
#include <vector>

#include "data/io_internal.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"

namespace qdo {
using namespace io_detail;
namespace {

std::string h5_abs(const std::string& name) { return (!name.empty() && name[0] == '/') ? name : "/" + name; }

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

// Compressed storage of large datasets (H5Dataset::compress): HDF5's own shuffle + deflate
// filters, so any HDF5 reader (h5py, MATLAB, h5dump) reads the file as it is; the chunks are
// filtered here, on every core, and written with H5Dwrite_chunk (HDF5 alone would run the
// filters on one thread).
constexpr std::size_t kCompressMinBytes = std::size_t(1) << 20;  // smaller datasets stay contiguous
constexpr std::size_t kChunkBytes = std::size_t(4) << 20;        // target chunk size
constexpr int kDeflateLevel = 1;                                  // fast; shuffle does most of the work

// Chunk shape: one plane of the last two axes (1 x ... x 1 x rows x cols), or a band of rows of it
// when a plane is larger than kChunkBytes.
std::vector<hsize_t> chunk_dims(const std::vector<std::size_t>& shape, std::size_t elem) {
  std::vector<hsize_t> c(shape.size(), 1);
  const std::size_t rows = shape[shape.size() - 2], cols = shape.back();
  c.back() = cols;
  c[c.size() - 2] = std::max<std::size_t>(1, std::min(rows, kChunkBytes / std::max<std::size_t>(1, cols * elem)));
  return c;
}

// HDF5's shuffle filter: byte j of element i goes to position j * count + i.
void shuffle_bytes(const unsigned char* in, unsigned char* out, std::size_t count, std::size_t elem) {
  for (std::size_t i = 0; i < count; ++i)
    for (std::size_t j = 0; j < elem; ++j) out[j * count + i] = in[i * elem + j];
}

// Converts, shuffles and deflates every chunk of d (row-major, chunk shape `chunk`), the chunks
// spread over the machine's cores, then writes them in order with H5Dwrite_chunk. Edge chunks
// are padded with zeros to the full chunk shape, as HDF5 stores them.
void write_chunks_compressed(hid_t dset, const std::string& path, const std::string& what, const H5Dataset& d,
                             const std::vector<hsize_t>& chunk) {
  const std::size_t rank = d.shape.size(), elem = d.float32 ? 4 : 8;
  std::vector<std::size_t> grid(rank);
  std::size_t chunks = 1, chunk_elems = 1;
  for (std::size_t k = 0; k < rank; ++k) {
    grid[k] = (d.shape[k] + chunk[k] - 1) / chunk[k];
    chunks *= grid[k];
    chunk_elems *= chunk[k];
  }
  const std::size_t rows = d.shape[rank - 2], cols = d.shape[rank - 1], plane = rows * cols;
  const std::size_t crow = chunk[rank - 2];
  std::vector<std::vector<unsigned char>> packed(chunks);
  std::vector<std::vector<hsize_t>> offsets(chunks, std::vector<hsize_t>(rank));
  std::atomic<std::size_t> next{0};
  std::atomic<bool> failed{false};
  const auto work = [&]() {
    std::vector<unsigned char> raw(chunk_elems * elem), shuf(chunk_elems * elem);
    for (std::size_t c = next++; c < chunks; c = next++) {
      // Chunk c's grid coordinates (row-major over the grid), its first element and its rows.
      std::size_t rem = c, plane_index = 0;
      for (std::size_t k = rank; k-- > 0;) {
        offsets[c][k] = hsize_t((rem % grid[k]) * chunk[k]);
        rem /= grid[k];
      }
      for (std::size_t k = 0; k + 2 < rank; ++k) plane_index = plane_index * d.shape[k] + offsets[c][k];
      const std::size_t y0 = offsets[c][rank - 2];
      std::fill(raw.begin(), raw.end(), 0);
      for (std::size_t y = 0; y < crow && y0 + y < rows; ++y) {
        const std::size_t at = plane_index * plane + (y0 + y) * cols;
        unsigned char* dst = raw.data() + y * cols * elem;
        if (d.f32_view) {
          std::memcpy(dst, d.f32_view + at, cols * 4);
          continue;
        }
        const double* src = d.values().data() + at;
        if (d.float32)
          for (std::size_t x = 0; x < cols; ++x) {
            const float f = static_cast<float>(src[x]);
            std::memcpy(dst + x * 4, &f, 4);
          }
        else
          std::memcpy(dst, src, cols * 8);
      }
      shuffle_bytes(raw.data(), shuf.data(), chunk_elems, elem);
      uLongf len = compressBound(static_cast<uLong>(shuf.size()));
      packed[c].resize(len);
      if (compress2(packed[c].data(), &len, shuf.data(), static_cast<uLong>(shuf.size()), kDeflateLevel) != Z_OK) {
        failed = true;
        return;
      }
      packed[c].resize(len);
    }
  };
  const unsigned threads = std::max(1u, std::min<unsigned>(std::thread::hardware_concurrency(), unsigned(chunks)));
  std::vector<std::thread> pool;
  for (unsigned t = 1; t < threads; ++t) pool.emplace_back(work);
  work();
  for (auto& t : pool) t.join();
  if (failed) fail(path, what, "compressing a chunk failed (zlib)");
  for (std::size_t c = 0; c < chunks; ++c)
    if (H5Dwrite_chunk(dset, H5P_DEFAULT, 0, offsets[c].data(), packed[c].size(), packed[c].data()) < 0)
      fail(path, what, "writing a compressed chunk failed" + h5_detail());
}

// One dataset, shape in C order, float64 on disk; validates shape against data size first.
void h5_write_dataset(hid_t file, const std::string& path, const H5Dataset& d) {
  const std::string what = "dataset '" + d.name + "'";
  if (d.name.size() < 2 || d.name[0] != '/') fail(path, what, "name must be an absolute path like \"/psf\"");
  std::size_t n = 0;
  if (!element_count(d.shape, std::numeric_limits<std::size_t>::max(), n) || n != d.size())
    fail(path, what, "shape " + shape_str(d.shape) + " does not match the data size " + std::to_string(d.size()));
  if (d.f32_view && (!d.float32 || !d.data.empty() || d.view))
    fail(path, what, "f32_view needs float32 set and neither data nor view");
  const std::vector<hsize_t> dims(d.shape.begin(), d.shape.end());
  H5Id space(d.shape.empty() ? H5Screate(H5S_SCALAR)
                             : H5Screate_simple(static_cast<int>(dims.size()), dims.data(), nullptr),
             H5Sclose);
  H5Id lcpl(H5Pcreate(H5P_LINK_CREATE), H5Pclose);
  if (!space.valid() || !lcpl.valid() || H5Pset_create_intermediate_group(lcpl.get(), 1) < 0)
    fail(path, what, "cannot create dataspace" + h5_detail());
  const std::size_t elem = d.float32 ? 4 : 8;
  const bool compress = d.compress && d.shape.size() >= 2 && n * elem >= kCompressMinBytes;
  H5Id dcpl(H5Pcreate(H5P_DATASET_CREATE), H5Pclose);
  std::vector<hsize_t> chunk;
  if (compress) {
    chunk = chunk_dims(d.shape, elem);
    if (!dcpl.valid() || H5Pset_chunk(dcpl.get(), static_cast<int>(chunk.size()), chunk.data()) < 0 ||
        H5Pset_shuffle(dcpl.get()) < 0 || H5Pset_deflate(dcpl.get(), kDeflateLevel) < 0)
      fail(path, what, "cannot set up chunked, compressed storage" + h5_detail());
  }
  H5Id dset(H5Dcreate2(file, d.name.c_str(), d.float32 ? H5T_IEEE_F32LE : H5T_IEEE_F64LE, space.get(), lcpl.get(),
                       compress ? dcpl.get() : H5P_DEFAULT, H5P_DEFAULT),
            H5Dclose);
  if (!dset.valid()) fail(path, what, "cannot create" + h5_detail());
  if (compress) write_chunks_compressed(dset.get(), path, what, d, chunk);
  else if (n > 0 && d.f32_view) {
    if (H5Dwrite(dset.get(), H5T_NATIVE_FLOAT, H5S_ALL, H5S_ALL, H5P_DEFAULT, d.f32_view) < 0)
      fail(path, what, "write failed" + h5_detail());
  } else if (n > 0 && d.float32) {
    // Converted here (h5_write checked the range): HDF5's own double -> float conversion path is
    // several times slower than this loop. In slabs of whole leading-axis entries through one
    // buffer of at most ~4 MiB: a full-size float copy (32 MB for a paper-preset PSF stack) costs
    // more in fresh pages than the conversion itself.
    const std::vector<double>& v = d.values();
    const std::size_t inner = d.shape.empty() ? 1 : n / std::max<std::size_t>(1, d.shape[0]);
    const std::size_t lead = d.shape.empty() ? 1 : d.shape[0];
    const std::size_t per = std::max<std::size_t>(1, (std::size_t(1) << 20) / std::max<std::size_t>(1, inner));
    std::vector<float> f(std::min(lead, per) * inner);
    H5Id fspace(H5Dget_space(dset.get()), H5Sclose);
    if (!fspace.valid()) fail(path, what, "cannot get its dataspace" + h5_detail());
    for (std::size_t a = 0; a < lead; a += per) {
      const std::size_t cnt = std::min(per, lead - a);
      std::copy(v.begin() + std::ptrdiff_t(a * inner), v.begin() + std::ptrdiff_t((a + cnt) * inner), f.begin());
      if (d.shape.empty()) {
        if (H5Dwrite(dset.get(), H5T_NATIVE_FLOAT, H5S_ALL, H5S_ALL, H5P_DEFAULT, f.data()) < 0)
          fail(path, what, "write failed" + h5_detail());
        continue;
      }
      std::vector<hsize_t> start(dims.size(), 0), count(dims.begin(), dims.end());
      start[0] = hsize_t(a);
      count[0] = hsize_t(cnt);
      const hsize_t mcount = hsize_t(cnt * inner);
      H5Id mspace(H5Screate_simple(1, &mcount, nullptr), H5Sclose);
      if (!mspace.valid() || H5Sselect_hyperslab(fspace.get(), H5S_SELECT_SET, start.data(), nullptr, count.data(), nullptr) < 0 ||
          H5Dwrite(dset.get(), H5T_NATIVE_FLOAT, mspace.get(), fspace.get(), H5P_DEFAULT, f.data()) < 0)
        fail(path, what, "write failed" + h5_detail());
    }
  } else if (n > 0 && H5Dwrite(dset.get(), H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, d.values().data()) < 0)
    fail(path, what, "write failed" + h5_detail());
  for (const auto& kv : d.num_attrs) h5_write_num_attr(dset.get(), path, kv.first, kv.second);
  for (const auto& kv : d.str_attrs) h5_write_str_attr(dset.get(), path, kv.first, kv.second);
}

}  // namespace

namespace io_detail {

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

H5Numeric h5_open_numeric(hid_t file, const std::string& name, const std::string& path, const std::string& what,
                          const std::string& missing) {
  if (!h5_is_dataset(file, name)) fail(path, what, missing);
  H5Id dset(H5Dopen2(file, name.c_str(), H5P_DEFAULT), H5Dclose);
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
  return H5Numeric{std::move(dset), std::move(type), std::move(space), std::vector<std::size_t>(dims.begin(), dims.end())};
}

// Reads one numeric dataset (converted to float64, C order) plus its attributes.
namespace {
// One dataset of an open file (h5_read_impl, h5_read_many).
H5Dataset h5_read_open(const H5Id& file, const std::string& path, const std::string& name, std::size_t max_elements, NumKind* kind) {
  H5Dataset ds;
  ds.name = h5_abs(name);
  const std::string what = "dataset '" + ds.name + "'";
  H5Numeric h = h5_open_numeric(file.get(), ds.name, path, what, "missing (no such dataset)");
  H5Id& dset = h.dset;
  H5Id& type = h.type;
  ds.shape = h.shape;
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
}  // namespace

H5Dataset h5_read_impl(const std::string& path, const std::string& name, std::size_t max_elements, NumKind* kind) {
  const H5Id file = h5_open_read(path);
  return h5_read_open(file, path, name, max_elements, kind);
}

std::vector<H5Dataset> h5_read_many_impl(const std::string& path, const std::vector<std::string>& names, std::size_t max_elements) {
  const H5Id file = h5_open_read(path);
  std::vector<H5Dataset> out;
  for (const auto& n : names) out.push_back(h5_read_open(file, path, n, max_elements, nullptr));
  return out;
}

}  // namespace io_detail

// =========================================================================================
// HDF5 public API
// =========================================================================================

bool few_distinct_values(const std::vector<double>& v, std::size_t max_distinct) {
  std::unordered_set<double> seen;
  for (double x : v)
    if (seen.insert(x).second && seen.size() > max_distinct) return false;
  return true;
}

void h5_write(const std::string& path, const std::vector<H5Dataset>& datasets,
              const std::map<std::string, std::string>& root_str_attrs) {
  for (const H5Dataset& d : datasets) {
    if (d.f32_view) {
      // Floats are within float32's range by construction; only NaN and Inf are refused.
      std::size_t bad = 0;
      for (std::size_t i = 0; i < d.f32_count; ++i) bad += !std::isfinite(d.f32_view[i]);
      if (bad)
        throw NumericalError("file '" + path + "': dataset '" + d.name + "': " + std::to_string(bad) + " of " +
                             std::to_string(d.f32_count) + " values are NaN or Inf; not written");
    }
    if (const std::size_t bad = count_nonfinite(d.values()))
      throw NumericalError("file '" + path + "': dataset '" + d.name + "': " + std::to_string(bad) + " of " +
                           std::to_string(d.values().size()) + " values are NaN or Inf; not written");
    if (d.float32)
      for (double v : d.values())
        if (std::fabs(v) > double(std::numeric_limits<float>::max()))
          throw NumericalError("file '" + path + "': dataset '" + d.name + "': value " + to_str(v) +
                               " is beyond float32's range; not written");
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

std::vector<H5Dataset> h5_read_many(const std::string& path, const std::vector<std::string>& names, std::size_t max_elements) {
  return h5_read_many_impl(path, names, max_elements);
}

bool h5_has(const std::string& path, const std::string& name) {
  H5Id file = h5_open_read(path);
  return h5_is_dataset(file.get(), name);
}

std::map<std::string, std::string> h5_read_root_attrs(const std::string& path) {
  H5Id file = h5_open_read(path);
  H5Dataset root;
  root.name = "/";
  h5_read_attrs(file.get(), path, root);
  std::map<std::string, std::string> out = root.str_attrs;
  for (const auto& [k, v] : root.num_attrs) out.emplace(k, to_str(v));
  return out;
}

}  // namespace qdo
