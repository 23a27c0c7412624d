// MATLAB .mat files (libmatio): the v5/v7.3 checks made before libmatio sees a file (element
// structure, zlib inflation, v7.3 datasets) and the reading of a numeric variable.
#include <hdf5.h>
#include <matio.h>
#include <zlib.h>

#include <algorithm>
#include <cctype>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <string>
#include <vector>

#include "data/io_internal.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"

namespace qdo {
using namespace io_detail;
namespace {

namespace fs = std::filesystem;

// matio reports problems through a log callback; keep the last message for our errors.
thread_local std::string g_matio_last;
void matio_log(int, char* message) { g_matio_last = message ? message : ""; }

std::string matio_detail() {
  std::string s = g_matio_last.empty() ? "" : " (matio: " + g_matio_last + ")";
  g_matio_last.clear();
  return s;
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
  const H5Numeric h = h5_open_numeric(file.get(), name, path, what, "is not an HDF5 dataset in this v7.3 file");
  const std::vector<std::size_t>& shape = h.shape;
  std::size_t count = 0;
  if (!element_count(shape, std::size_t(1) << 31, count) || count != n)
    fail(path, what, "HDF5 shape " + shape_str(shape) + " does not match the variable's " + std::to_string(n) + " elements");
  check_h5_storage(path, what, h.dset.get(), h.type.get(), shape, n);
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

}  // namespace

namespace io_detail {

bool mat_numeric(const matvar_t& v) {
  return v.class_type >= MAT_C_DOUBLE && v.class_type <= MAT_C_UINT64 && !v.isComplex;
}

std::vector<std::size_t> mat_dims(const matvar_t& v) {
  return std::vector<std::size_t>(v.dims, v.dims + std::max(v.rank, 0));
}

// A 1 x n, n x 1 or n-element shape holding n elements.
bool is_vector_shape(const std::vector<std::size_t>& dims, std::size_t n) {
  if (dims.empty() || dims.size() > 2 || n == 0) return false;
  return dims.size() == 1 || dims[0] == 1 || dims[1] == 1;
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


// Reads a numeric variable from a MATLAB v5/v7.3 file; dims are MATLAB's [d0 d1 d2],
// data column-major (element (i,j,k) at i + d0*j + d0*d1*k).
// With band_axis non-null, also reads the first of kBandAxisNames the file holds as a
// numeric vector (1 x n or n x 1, at most 65536 elements) into it; its key stays empty when
// there is none.
RawArray read_mat_raw(const std::string& path, const std::string& key, RawArray* band_axis) {
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

}  // namespace io_detail
}  // namespace qdo
