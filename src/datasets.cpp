// Training scenes: dataset readers, scene index and split, patches, augmentation, the patch
// sampler and the synthetic scene generator (see include/qdo/datasets.hpp).
#include "qdo/datasets.hpp"

#include <hdf5.h>
#include <matio.h>
#include <png.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <numeric>
#include <utility>

#include "qdo/embedded.hpp"
#include "qdo/error.hpp"
#include "qdo/io.hpp"
#include "qdo/scenes.hpp"

namespace qdo {
namespace detail {
// src/io.cpp: checks that a file is MATLAB v5 or v7.3 and, for v5, its element structure,
// before libmatio reads its headers (libmatio allocates what a corrupt header declares);
// InputError naming the file.
void check_mat_file(const std::string& path);
}  // namespace detail
namespace {

namespace fs = std::filesystem;

// "file '<file>': <problem>"
[[noreturn]] void fail(const std::string& file, const std::string& problem) {
  throw InputError("file '" + file + "': " + problem);
}
[[noreturn]] void fail_dir(const std::string& dir, const std::string& problem) {
  throw InputError("folder '" + dir + "': " + problem);
}

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return s;
}
std::string lower_ext(const fs::path& p) { return lower(p.extension().string()); }

std::string shape_str(const std::vector<std::size_t>& d) {
  std::string s = "[";
  for (std::size_t i = 0; i < d.size(); ++i) s += (i ? " x " : "") + std::to_string(d[i]);
  return s + "]";
}
std::string shape_str(const SceneShape& s) { return shape_str(std::vector<std::size_t>{s.bands, s.rows, s.cols}); }

bool has_matlab_header(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  char head[6] = {};
  in.read(head, sizeof head);
  return in.gcount() == 6 && std::memcmp(head, "MATLAB", 6) == 0;
}
// The rule read_cube uses to pick libmatio over HDF5.
bool is_mat_file(const std::string& path) { return lower_ext(path) == ".mat" || has_matlab_header(path); }

const std::vector<std::string>& known_formats() {
  static const std::vector<std::string> f = {"auto", "icvl", "cave", "cave-png", "harvard", "kaist", "h5"};
  return f;
}
void check_format(const std::string& format) {
  const auto& f = known_formats();
  if (std::find(f.begin(), f.end(), format) == f.end())
    reject("format", format, "one of auto, icvl, cave, cave-png, harvard, kaist, h5");
}

// ---------------------------------------------------------------------------------------
// Random numbers: std::mt19937_64 (its output sequence is fixed by the standard) with our
// own integer -> range mappings, since the std distributions differ between libraries.
// ---------------------------------------------------------------------------------------

std::uint64_t splitmix64(std::uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}
std::uint64_t mix_seed(std::uint64_t seed, std::uint64_t stream) { return splitmix64(splitmix64(seed) ^ (stream * 0xD1B54A32D192ED03ull)); }

// Uniform in [0, 1).
double uniform01(std::mt19937_64& rng) { return static_cast<double>(rng() >> 11) * (1.0 / 9007199254740992.0); }
double uniform(std::mt19937_64& rng, double a, double b) { return a + (b - a) * uniform01(rng); }
// Uniform in 0 .. n-1 (n > 0), unbiased by rejection.
std::size_t uniform_below(std::mt19937_64& rng, std::size_t n) {
  const std::uint64_t un = n;
  const std::uint64_t limit = std::numeric_limits<std::uint64_t>::max() - std::numeric_limits<std::uint64_t>::max() % un;
  std::uint64_t r = rng();
  while (r >= limit) r = rng();
  return static_cast<std::size_t>(r % un);
}
template <typename T>
void shuffle(std::vector<T>& v, std::mt19937_64& rng) {
  for (std::size_t i = v.size(); i > 1; --i) std::swap(v[i - 1], v[uniform_below(rng, i)]);
}

// ---------------------------------------------------------------------------------------
// MATLAB and HDF5 headers
// ---------------------------------------------------------------------------------------

struct MatCloser {
  void operator()(mat_t* m) const { Mat_Close(m); }
};
struct MatVarFreer {
  void operator()(matvar_t* v) const { Mat_VarFree(v); }
};
using MatFile = std::unique_ptr<mat_t, MatCloser>;
using MatVar = std::unique_ptr<matvar_t, MatVarFreer>;

struct MatVarInfo {
  std::string name;
  std::vector<std::size_t> dims;  // MATLAB's dims
  bool numeric = false;           // real numeric class
};

bool mat_numeric_class(matio_classes c) {
  switch (c) {
    case MAT_C_DOUBLE: case MAT_C_SINGLE: case MAT_C_INT8: case MAT_C_UINT8: case MAT_C_INT16:
    case MAT_C_UINT16: case MAT_C_INT32: case MAT_C_UINT32: case MAT_C_INT64: case MAT_C_UINT64:
      return true;
    default:
      return false;
  }
}

// Every variable's name, dims and class, from the variable headers only (no data read).
std::vector<MatVarInfo> mat_variables(const std::string& path) {
  H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);  // v7.3 files are read through HDF5
  detail::check_mat_file(path);
  MatFile mat(Mat_Open(path.c_str(), MAT_ACC_RDONLY));
  if (!mat) fail(path, "not a readable MATLAB .mat file");
  std::vector<MatVarInfo> vars;
  Mat_Rewind(mat.get());
  while (MatVar info{Mat_VarReadNextInfo(mat.get())}) {
    MatVarInfo v;
    v.name = info->name ? info->name : "";
    for (int k = 0; k < info->rank; ++k) v.dims.push_back(info->dims[k]);
    v.numeric = mat_numeric_class(info->class_type) && !info->isComplex;
    vars.push_back(std::move(v));
  }
  return vars;
}

bool mat_has(const std::vector<MatVarInfo>& vars, const std::string& name) {
  return std::any_of(vars.begin(), vars.end(), [&](const MatVarInfo& v) { return v.name == name; });
}

class H5Handle {
 public:
  using Closer = herr_t (*)(hid_t);
  H5Handle(hid_t id, Closer closer) : id_(id), closer_(closer) {}
  H5Handle(const H5Handle&) = delete;
  H5Handle& operator=(const H5Handle&) = delete;
  ~H5Handle() {
    if (id_ >= 0) closer_(id_);
  }
  hid_t get() const { return id_; }
  bool valid() const { return id_ >= 0; }

 private:
  hid_t id_;
  Closer closer_;
};

// Whether `elements` of at least `bytes_each` bytes could be stored in the file at `path`
// (compressed at most ~1032:1, as read_cube checks before allocating). Probes only trust
// header shapes that pass; others go through the reader, which names the problem.
bool plausible_size(const std::string& path, std::uintmax_t elements, std::uintmax_t bytes_each) {
  std::error_code ec;
  const std::uintmax_t file = fs::file_size(path, ec);
  return !ec && elements <= (file * 1100 + (std::uintmax_t{1} << 16)) / std::max<std::uintmax_t>(bytes_each, 1);
}
std::uintmax_t product(const std::vector<std::size_t>& d) {
  std::uintmax_t n = 1;
  for (std::size_t v : d) {
    if (v != 0 && n > std::numeric_limits<std::uintmax_t>::max() / v) return std::numeric_limits<std::uintmax_t>::max();
    n *= v;
  }
  return n;
}

// Dims (C order) of an HDF5 dataset; false when the file, the dataset or its shape cannot be
// read (the caller then falls back to reading the scene, which reports the problem).
bool h5_dims(const std::string& path, const std::string& name, std::vector<std::size_t>& dims) {
  H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
  H5Handle file(H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT), H5Fclose);
  if (!file.valid() || H5Lexists(file.get(), name.c_str(), H5P_DEFAULT) <= 0) return false;
  H5Handle dset(H5Dopen2(file.get(), name.c_str(), H5P_DEFAULT), H5Dclose);
  if (!dset.valid()) return false;
  H5Handle space(H5Dget_space(dset.get()), H5Sclose);
  if (!space.valid()) return false;
  const int rank = H5Sget_simple_extent_ndims(space.get());
  if (rank < 0) return false;
  std::vector<hsize_t> d(static_cast<std::size_t>(rank));
  if (rank > 0 && H5Sget_simple_extent_dims(space.get(), d.data(), nullptr) < 0) return false;
  dims.assign(d.begin(), d.end());
  return true;
}

// bands x rows x cols from 3-D dims as read_cube orients them ("auto" layout): the band axis
// is the last (MATLAB) or first (HDF5) one of length `bands`, else the other end.
bool orient(const std::vector<std::size_t>& d, bool mat, std::size_t bands, SceneShape& s) {
  if (d.size() != 3 || d[0] == 0 || d[1] == 0 || d[2] == 0) return false;
  const std::size_t first = mat ? 2 : 0, second = mat ? 0 : 2;
  std::size_t axis = first;
  if (bands > 0) {
    if (d[first] == bands) axis = first;
    else if (d[second] == bands) axis = second;
    else return false;
  }
  s = axis == 0 ? SceneShape{d[0], d[1], d[2]} : SceneShape{d[2], d[0], d[1]};
  return true;
}

// ---------------------------------------------------------------------------------------
// PNG
// ---------------------------------------------------------------------------------------

// A png_image, freed by png_image_free on destruction (also after a failed read).
struct PngImage {
  png_image img;
  PngImage() {
    std::memset(&img, 0, sizeof img);
    img.version = PNG_IMAGE_VERSION;
  }
  PngImage(const PngImage&) = delete;
  PngImage& operator=(const PngImage&) = delete;
  ~PngImage() { png_image_free(&img); }
};

// A grayscale PNG read through libpng's simplified API: the header on construction, the
// pixels with finish().
class PngRead {
 public:
  explicit PngRead(const std::string& path) : path_(path) {
    if (!png_image_begin_read_from_file(&img_.img, path.c_str()))
      fail(path, std::string("not a readable PNG file (") + img_.img.message + ")");
    // Colour (RGB, RGBA, colour palette) and alpha files are decoded to four channels and
    // accepted when every pixel is grey (R = G = B) and opaque (checked in finish()).
    four_channels_ = (img_.img.format & (PNG_FORMAT_FLAG_COLOR | PNG_FORMAT_FLAG_ALPHA)) != 0;
    // Decoding allocates what the header declares: check it against the file first. Each row
    // holds a filter byte and at least 1 bit per pixel, deflated at most ~1032:1.
    const std::uintmax_t w = img_.img.width, h = img_.img.height;
    const std::string dims = std::to_string(h) + " x " + std::to_string(w);
    if (w == 0 || h == 0 || w * h > (std::uintmax_t{1} << 28))
      fail(path, "header declares " + dims + " pixels (rows x columns); at most 2^28 (16384 x 16384) per band are accepted");
    std::error_code ec;
    const std::uintmax_t file = fs::file_size(path, ec);
    if (ec || h * (1 + (w + 7) / 8) > file * 1100 + (std::uintmax_t{1} << 16))
      fail(path, "header declares " + dims + " pixels but the file has only " + std::to_string(file) +
                     " bytes: truncated or corrupt");
  }

  std::size_t width() const { return img_.img.width; }
  std::size_t height() const { return img_.img.height; }
  bool sixteen_bit() const { return (img_.img.format & PNG_FORMAT_FLAG_LINEAR) != 0; }

  // The pixels, row-major, divided by 65535 (16-bit) or 255 (8-bit).
  std::vector<double> finish() {
    const std::size_t n = width() * height();
    std::vector<double> out(n);
    if (four_channels_) {
      if (sixteen_bit()) {
        std::vector<png_uint_16> buf(4 * n);
        decode(PNG_FORMAT_LINEAR_RGB_ALPHA, buf.data());
        grey_opaque(buf, 65535, out);
      } else {
        std::vector<png_byte> buf(4 * n);
        decode(PNG_FORMAT_RGBA, buf.data());
        grey_opaque(buf, 255, out);
      }
      return out;
    }
    if (sixteen_bit()) {
      img_.img.format = PNG_FORMAT_LINEAR_Y;
      std::vector<png_uint_16> buf(n);
      if (!png_image_finish_read(&img_.img, nullptr, buf.data(), 0, nullptr))
        fail(path_, std::string("cannot decode the PNG data, truncated or corrupt file (") + img_.img.message + ")");
      for (std::size_t i = 0; i < n; ++i) out[i] = buf[i] / 65535.0;
    } else {
      img_.img.format = PNG_FORMAT_GRAY;
      std::vector<png_byte> buf(n);
      if (!png_image_finish_read(&img_.img, nullptr, buf.data(), 0, nullptr))
        fail(path_, std::string("cannot decode the PNG data, truncated or corrupt file (") + img_.img.message + ")");
      for (std::size_t i = 0; i < n; ++i) out[i] = buf[i] / 255.0;
    }
    return out;
  }

 private:
  void decode(png_uint_32 format, void* buf) {
    img_.img.format = format;
    if (!png_image_finish_read(&img_.img, nullptr, buf, 0, nullptr))
      fail(path_, std::string("cannot decode the PNG data, truncated or corrupt file (") + img_.img.message + ")");
  }
  // RGBA pixels to one grey channel: R = G = B and alpha at full scale everywhere, else an
  // InputError naming the first pixel that is coloured or transparent. (libpng premultiplies
  // 16-bit colour by alpha, so only opaque pixels keep their value.)
  template <typename T>
  void grey_opaque(const std::vector<T>& buf, double full, std::vector<double>& out) const {
    const std::size_t w = width();
    for (std::size_t i = 0; i < out.size(); ++i) {
      const T r = buf[4 * i], g = buf[4 * i + 1], b = buf[4 * i + 2], a = buf[4 * i + 3];
      auto at = [&] { return "pixel (row " + std::to_string(i / w) + ", column " + std::to_string(i % w) + ")"; };
      if (r != g || g != b)
        fail(path_, "colour PNG with a coloured " + at() + " (R, G, B = " + std::to_string(r) + ", " + std::to_string(g) +
                        ", " + std::to_string(b) + "); a band image must be grayscale, or RGB(A) with R = G = B");
      if (a != static_cast<T>(full))
        fail(path_, "PNG with a transparent " + at() + " (alpha " + std::to_string(a) + " of " + to_str(full) +
                        "); a band image must be opaque");
      out[i] = r / full;
    }
  }

  std::string path_;
  PngImage img_;
  bool four_channels_ = false;
};

std::vector<std::string> checked_band_files(const std::string& dir, std::size_t expected_bands) {
  const std::vector<std::string> files = png_band_files(dir);
  if (files.empty()) fail_dir(dir, "no PNG files (a CAVE scene is a folder of one grayscale PNG per band)");
  if (expected_bands > 0 && files.size() != expected_bands)
    fail_dir(dir, std::to_string(files.size()) + " PNG band files, " + std::to_string(expected_bands) +
                      " expected (one grayscale PNG per band)");
  return files;
}

SceneShape png_folder_shape(const std::string& dir, std::size_t expected_bands) {
  const std::vector<std::string> files = checked_band_files(dir, expected_bands);
  SceneShape s{files.size(), 0, 0};
  for (const std::string& f : files) {
    const PngRead png(f);
    if (f == files.front()) {
      s.rows = png.height();
      s.cols = png.width();
    } else if (png.height() != s.rows || png.width() != s.cols) {
      fail(f, std::to_string(png.height()) + " x " + std::to_string(png.width()) + " pixels, but '" + files.front() +
                  "' has " + std::to_string(s.rows) + " x " + std::to_string(s.cols));
    }
  }
  return s;
}

std::string resolve_format(const std::string& path, const std::string& format) {
  check_format(format);
  std::error_code ec;
  const bool dir = fs::is_directory(path, ec);
  if (format == "auto") return detect_scene_format(path);
  if (format == "cave" && dir) return "cave-png";
  return format;
}

double max_of(const RealStack& c) { return c.data.empty() ? 0.0 : *std::max_element(c.data.begin(), c.data.end()); }
void divide(RealStack& c, double s) {
  for (double& v : c.data) v /= s;
}

// The MATLAB key a format reads ("" = the only numeric 3-D variable).
std::string format_key(const std::string& format) {
  if (format == "icvl") return "rad";
  if (format == "harvard") return "ref";
  if (format == "kaist") return "HSI";
  return "";
}

}  // namespace

// =========================================================================================
// Readers
// =========================================================================================

bool operator==(const SceneShape& a, const SceneShape& b) {
  return a.bands == b.bands && a.rows == b.rows && a.cols == b.cols;
}

std::string detect_scene_format(const std::string& path) {
  std::error_code ec;
  if (fs::is_directory(path, ec)) return "cave-png";
  if (!fs::is_regular_file(path, ec)) fail(path, "no such file or folder");
  if (is_mat_file(path)) {
    const std::vector<MatVarInfo> vars = mat_variables(path);
    if (mat_has(vars, "rad")) return "icvl";
    if (mat_has(vars, "ref")) return "harvard";
    if (mat_has(vars, "HSI")) return "kaist";
    return "cave";
  }
  H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
  if (H5Fis_hdf5(path.c_str()) > 0) {
    std::vector<std::size_t> d;
    if (h5_dims(path, "/cube", d)) return "h5";
    if (h5_dims(path, "/rad", d)) return "icvl";
    return "h5";  // read_cube then names the missing /cube
  }
  fail(path, "not a recognised scene (a MATLAB .mat file, an HDF5 file with /cube, or a folder of PNG bands)");
}

std::vector<std::string> png_band_files(const std::string& dir) {
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) fail_dir(dir, "no such folder");
  std::vector<std::pair<unsigned long long, std::string>> numbered;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    if (!it->is_regular_file(ec) || lower_ext(it->path()) != ".png") continue;
    const std::string stem = it->path().stem().string();
    const std::size_t last = stem.find_last_of("0123456789");
    if (last == std::string::npos)
      fail(it->path().string(), "no band number in the file name (expected e.g. scene_ms_01.png .. scene_ms_31.png)");
    std::size_t first = last;
    while (first > 0 && std::isdigit(static_cast<unsigned char>(stem[first - 1]))) --first;
    const std::string digits = stem.substr(first, std::min<std::size_t>(last - first + 1, 18));
    numbered.emplace_back(std::stoull(digits), it->path().string());
  }
  if (ec) fail_dir(dir, "cannot list the folder: " + ec.message());
  std::sort(numbered.begin(), numbered.end());
  std::vector<std::string> files;
  for (std::size_t i = 0; i < numbered.size(); ++i) {
    if (i > 0 && numbered[i].first == numbered[i - 1].first)
      fail_dir(dir, "band number " + std::to_string(numbered[i].first) + " appears twice ('" + numbered[i - 1].second +
                        "' and '" + numbered[i].second + "')");
    files.push_back(numbered[i].second);
  }
  return files;
}

// Output: bands x H x W, band k from the k-th file in band-number order.
RealStack read_png_band_folder(const std::string& dir, std::size_t expected_bands) {
  const std::vector<std::string> files = checked_band_files(dir, expected_bands);
  RealStack cube;
  for (std::size_t k = 0; k < files.size(); ++k) {
    PngRead png(files[k]);
    if (k == 0) {
      if (files.size() > (std::size_t{1} << 31) / (png.height() * png.width()))
        fail_dir(dir, std::to_string(files.size()) + " bands of " + std::to_string(png.height()) + " x " +
                          std::to_string(png.width()) + " pixels exceed the limit of 2^31 values per cube");
      cube = RealStack(files.size(), png.height(), png.width());
    } else if (png.height() != cube.rows || png.width() != cube.cols) {
      fail(files[k], std::to_string(png.height()) + " x " + std::to_string(png.width()) + " pixels, but '" + files[0] +
                         "' has " + std::to_string(cube.rows) + " x " + std::to_string(cube.cols));
    }
    const std::vector<double> plane = png.finish();
    std::copy(plane.begin(), plane.end(), cube.plane(k));
  }
  return cube;
}

RealStack load_scene(const std::string& path, const std::string& format, std::size_t expected_bands,
                     const std::vector<double>& wavelengths_nm, bool resample_bands) {
  const std::string fmt = resolve_format(path, format);
  if (fmt == "cave-png") {
    RealStack png = read_png_band_folder(path, expected_bands);
    conform_radiance(png, "folder '" + path + "'");
    return png;
  }
  CubeReadOptions opt;
  opt.expected_bands = expected_bands;
  opt.wavelengths_nm = wavelengths_nm;
  opt.resample_bands = resample_bands;
  opt.key = format_key(fmt);
  RealStack cube;
  if (fmt == "icvl") {
    opt.scale = 4095;
    cube = read_cube(path, opt);
  } else if (fmt == "harvard") {
    opt.scale = 1;
    cube = read_cube(path, opt);
    const double mx = max_of(cube);
    if (mx > 0) divide(cube, mx);
  } else if (fmt == "kaist") {
    cube = read_cube(path, opt);  // auto scale: integer / type max, float as is
    const double mx = max_of(cube);
    if (mx > 1) divide(cube, mx);
  } else if (fmt == "cave") {
    cube = read_cube(path, opt);  // auto scale: integer / type max (uint16: 65535), float as is
    if (max_of(cube) > 1) divide(cube, 65535.0);
  } else {  // "h5"
    cube = read_cube(path, opt);
  }
  conform_radiance(cube, "file '" + path + "'");
  return cube;
}

void check_training_scene(const RealStack& cube, const std::string& path) {
  if (cube.data.empty()) fail(path, "an empty scene (0 values) cannot be training data");
  const auto [lo, hi] = std::minmax_element(cube.data.begin(), cube.data.end());
  if (*lo == *hi)
    fail(path, std::string(*lo == 0 ? "an all-zero" : "a constant") + " scene (every one of its " +
                   std::to_string(cube.data.size()) + " values is " + to_str(*lo) +
                   "): training scenes must vary (remove it from the training data)");
}

SceneShape probe_scene(const std::string& path, const std::string& format, std::size_t expected_bands,
                       const std::vector<double>& wavelengths_nm) {
  auto is_axis_name = [](const std::string& n) {
    for (const char* a : kBandAxisNames)
      if (n == a) return true;
    return false;
  };
  const std::string fmt = resolve_format(path, format);
  if (fmt == "cave-png") return png_folder_shape(path, expected_bands);
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) fail(path, "no such file");
  SceneShape s;
  if (is_mat_file(path)) {
    const std::vector<MatVarInfo> vars = mat_variables(path);
    std::string key = format_key(fmt);
    bool has_axis = false;  // a band axis to check: read the scene below
    for (const auto& v : vars) has_axis = has_axis || (!wavelengths_nm.empty() && is_axis_name(v.name));
    if (key.empty()) {
      std::size_t found = 0;
      for (const auto& v : vars)
        if (v.numeric && v.dims.size() == 3) {
          key = v.name;
          ++found;
        }
      if (found != 1) key.clear();
    }
    for (const auto& v : vars)
      if (!has_axis && !key.empty() && v.name == key && v.numeric && plausible_size(path, product(v.dims), 1) &&
          orient(v.dims, true, expected_bands, s))
        return s;
  } else {
    std::vector<std::size_t> d;
    const std::string key = fmt == "h5" ? "/cube" : "/" + format_key(fmt);
    bool has_axis = false;
    for (const char* a : kBandAxisNames)
      if (!wavelengths_nm.empty() && (h5_dims(path, std::string("/") + a, d) ||
                                      h5_dims(path, key.substr(0, key.find_last_of('/') + 1) + a, d)))
        has_axis = true;
    if (!has_axis && h5_dims(path, key, d) && plausible_size(path, product(d), 1) && orient(d, false, expected_bands, s))
      return s;
  }
  // Anything unusual, or a band axis to check: read the scene, which either gives the shape or
  // names the problem.
  const RealStack cube = load_scene(path, fmt, expected_bands, wavelengths_nm);
  return {cube.planes, cube.rows, cube.cols};
}

// =========================================================================================
// Scene index and split
// =========================================================================================

SceneIndex::SceneIndex(const std::vector<std::string>& paths, const std::string& format, std::size_t expected_bands,
                       const std::vector<double>& wavelengths_nm)
    : bands_(expected_bands), wavelengths_nm_(wavelengths_nm) {
  check_format(format);
  if (paths.empty()) reject("paths", "[]", "at least one scene file or folder");
  const bool want_png = format == "auto" || format == "cave" || format == "cave-png";
  const bool want_files = format != "cave-png";
  std::vector<std::string> found;
  auto folder_has_png = [](const fs::path& d) {
    std::error_code e;
    for (fs::directory_iterator it(d, e), end; !e && it != end; it.increment(e))
      if (it->is_regular_file(e) && lower_ext(it->path()) == ".png") return true;
    return false;
  };
  auto scene_file = [](const fs::path& f) {
    const std::string e = lower_ext(f);
    return e == ".mat" || e == ".h5" || e == ".hdf5";
  };
  for (const std::string& p : paths) {
    std::error_code ec;
    if (fs::is_regular_file(p, ec)) {
      found.push_back(p);
      continue;
    }
    if (!fs::is_directory(p, ec)) fail(p, "no such file or folder");
    if (want_png && folder_has_png(p)) found.push_back(p);
    for (fs::recursive_directory_iterator it(p, fs::directory_options::skip_permission_denied, ec), end;
         !ec && it != end; it.increment(ec)) {
      if (want_files && it->is_regular_file(ec) && scene_file(it->path())) found.push_back(it->path().string());
      else if (want_png && it->is_directory(ec) && folder_has_png(it->path())) found.push_back(it->path().string());
    }
    if (ec) fail_dir(p, "cannot list the folder: " + ec.message());
  }
  std::sort(found.begin(), found.end());
  found.erase(std::unique(found.begin(), found.end()), found.end());
  if (found.empty()) {
    std::string list;
    for (const auto& p : paths) list += (list.empty() ? "" : ", ") + p;
    throw InputError("no scenes (*.mat, *.h5, *.hdf5 or folders of PNG bands) found under " + list);
  }
  for (const std::string& f : found) {
    SceneEntry e;
    e.path = f;
    e.format = resolve_format(f, format);
    e.shape = probe_scene(f, e.format, expected_bands, wavelengths_nm);
    entries_.push_back(std::move(e));
  }
}

SceneIndex SceneIndex::synthetic(const SystemConfig& cfg, std::size_t count, std::size_t size_px, std::uint64_t seed) {
  if (count == 0) reject("count", count, "at least 1 synthetic scene");
  if (size_px == 0 || size_px > 16384) reject("size_px", size_px, "1 .. 16384 pixels");
  const std::size_t bands = cfg.wavelengths_nm().size();
  if (bands == 0) reject("bands", bands, "at least 1 band");
  SceneIndex idx;
  idx.bands_ = bands;
  idx.synthetic_cfg_ = std::make_shared<const SystemConfig>(cfg);
  for (std::size_t k = 0; k < count; ++k) {
    SceneEntry e;
    e.path = "synthetic:" + std::to_string(k);
    e.format = "synthetic";
    e.shape = {bands, size_px, size_px};
    e.synthetic_seed = mix_seed(seed, k);
    idx.entries_.push_back(std::move(e));
  }
  return idx;
}

RealStack SceneIndex::load(std::size_t i) const {
  if (i >= entries_.size()) reject("scene", i, "an index below " + std::to_string(entries_.size()));
  const SceneEntry& e = entries_[i];
  RealStack cube = e.format == "synthetic" ? synthetic_scene(*synthetic_cfg_, e.shape.rows, e.synthetic_seed)
                                           : load_scene(e.path, e.format, bands_, wavelengths_nm_);
  const SceneShape got{cube.planes, cube.rows, cube.cols};
  if (!(got == e.shape))
    fail(e.path, "read as " + shape_str(got) + " but indexed as " + shape_str(e.shape) + " (changed since indexed?)");
  return cube;
}

SceneSplit SceneIndex::split(std::uint64_t seed, double train_frac, double val_frac) const {
  if (!(train_frac >= 0 && train_frac <= 1)) reject("train_frac", train_frac, "0 .. 1");
  if (!(val_frac >= 0 && val_frac <= 1)) reject("val_frac", val_frac, "0 .. 1");
  if (train_frac + val_frac > 1 + 1e-12) reject("train_frac + val_frac", train_frac + val_frac, "at most 1");
  const std::size_t n = entries_.size();
  const auto count = [n](double f) { return static_cast<std::size_t>(std::llround(f * static_cast<double>(n))); };
  const std::size_t n_train = std::min(n, count(train_frac));
  const std::size_t n_val = std::min(n - n_train, count(val_frac));
  std::vector<std::size_t> order(n);
  std::iota(order.begin(), order.end(), std::size_t{0});
  std::mt19937_64 rng(mix_seed(seed, 0x5911u));
  shuffle(order, rng);
  SceneSplit s;
  s.train.assign(order.begin(), order.begin() + static_cast<std::ptrdiff_t>(n_train));
  s.val.assign(order.begin() + static_cast<std::ptrdiff_t>(n_train),
               order.begin() + static_cast<std::ptrdiff_t>(n_train + n_val));
  s.test.assign(order.begin() + static_cast<std::ptrdiff_t>(n_train + n_val), order.end());
  std::sort(s.train.begin(), s.train.end());
  std::sort(s.val.begin(), s.val.end());
  std::sort(s.test.begin(), s.test.end());
  return s;
}

// =========================================================================================
// Patches and augmentation
// =========================================================================================

bool operator==(const PatchOrigin& a, const PatchOrigin& b) { return a.y == b.y && a.x == b.x; }

std::vector<std::size_t> patch_starts(std::size_t length, std::size_t size, std::size_t stride) {
  if (size == 0) reject("patch size", size, "at least 1 pixel");
  if (stride == 0) reject("stride", stride, "at least 1 pixel");
  if (size > length)
    reject("patch size", size, "at most the scene size along each axis (" + std::to_string(length) + " pixels)");
  std::vector<std::size_t> s;
  for (std::size_t p = 0; p + size <= length; p += stride) s.push_back(p);
  if (s.back() + size < length) s.push_back(length - size);
  return s;
}

std::vector<PatchOrigin> patch_origins(std::size_t rows, std::size_t cols, std::size_t size, std::size_t stride) {
  const std::vector<std::size_t> ys = patch_starts(rows, size, stride), xs = patch_starts(cols, size, stride);
  std::vector<PatchOrigin> o;
  for (std::size_t y : ys)
    for (std::size_t x : xs) o.push_back({y, x});
  return o;
}

std::vector<PatchOrigin> grid_origins(std::size_t rows, std::size_t cols, std::size_t size, std::size_t per_axis) {
  if (per_axis == 0) reject("per_axis", per_axis, "at least 1 crop per axis");
  if (size == 0) reject("patch size", size, "at least 1 pixel");
  if (size > rows || size > cols)
    reject("patch size", size,
           "at most the scene size " + std::to_string(rows) + " x " + std::to_string(cols) + " (rows x cols)");
  auto starts = [&](std::size_t length) {
    std::vector<std::size_t> s;
    for (std::size_t k = 0; k < per_axis; ++k)
      s.push_back(per_axis == 1 ? (length - size) / 2
                                : static_cast<std::size_t>(std::llround(static_cast<double>(k * (length - size)) /
                                                                        static_cast<double>(per_axis - 1))));
    return s;
  };
  std::vector<PatchOrigin> o;
  for (std::size_t y : starts(rows))
    for (std::size_t x : starts(cols)) o.push_back({y, x});
  return o;
}

RealStack crop_patch(const RealStack& cube, const PatchOrigin& o, std::size_t size) {
  if (size == 0 || o.y + size > cube.rows || o.x + size > cube.cols)
    reject("patch", "(" + std::to_string(o.y) + ", " + std::to_string(o.x) + ") size " + std::to_string(size),
           "a non-empty crop inside the " + std::to_string(cube.rows) + " x " + std::to_string(cube.cols) + " scene");
  RealStack p(cube.planes, size, size);
  for (std::size_t b = 0; b < cube.planes; ++b)
    for (std::size_t y = 0; y < size; ++y) {
      const double* src = &cube(b, o.y + y, o.x);
      std::copy(src, src + size, &p(b, y, 0));
    }
  return p;
}

std::vector<RealStack> extract_patches(const RealStack& cube, std::size_t size, std::size_t stride) {
  std::vector<RealStack> out;
  for (const PatchOrigin& o : patch_origins(cube.rows, cube.cols, size, stride)) out.push_back(crop_patch(cube, o, size));
  return out;
}

std::vector<RealStack> paper_crops(const RealStack& cube, std::size_t size) {
  std::vector<RealStack> out;
  for (const PatchOrigin& o : grid_origins(cube.rows, cube.cols, size, 3)) out.push_back(crop_patch(cube, o, size));
  return out;
}

RealStack augment(const RealStack& cube, int code) {
  if (code < 0 || code > 7) reject("augmentation code", code, "0 .. 7 (4 x flip + quarter turns)");
  const std::size_t rot = static_cast<std::size_t>(code % 4);
  const bool flip = code >= 4;
  const std::size_t H = cube.rows, W = cube.cols;
  const bool swap = rot % 2 == 1;
  RealStack out(cube.planes, swap ? W : H, swap ? H : W);
  // Source pixel of each output pixel: undo the rotations (each counter-clockwise quarter
  // turn maps in(y, x) to out(W-1-x, y), i.e. out(i, j) = in(j, h-1-i) with h = out rows),
  // then the mirror.
  std::vector<std::size_t> src(out.rows * out.cols);
  for (std::size_t i0 = 0; i0 < out.rows; ++i0)
    for (std::size_t j0 = 0; j0 < out.cols; ++j0) {
      std::size_t i = i0, j = j0, h = out.rows, w = out.cols;
      for (std::size_t r = 0; r < rot; ++r) {
        const std::size_t ni = j, nj = h - 1 - i;
        i = ni;
        j = nj;
        std::swap(h, w);
      }
      if (flip) j = w - 1 - j;
      src[i0 * out.cols + j0] = i * W + j;
    }
  for (std::size_t b = 0; b < cube.planes; ++b) {
    const double* in = cube.plane(b);
    double* o = out.plane(b);
    for (std::size_t k = 0; k < src.size(); ++k) o[k] = in[src[k]];
  }
  return out;
}

int augment_inverse(int code) {
  if (code < 0 || code > 7) reject("augmentation code", code, "0 .. 7 (4 x flip + quarter turns)");
  return code >= 4 ? code : (4 - code) % 4;  // mirrors are their own inverse
}

// =========================================================================================
// Patch sampler
// =========================================================================================

CubeCache::CubeCache(std::size_t capacity) : capacity_(capacity) {
  if (capacity == 0) reject("cache_scenes", capacity, "at least 1 cube");
}

std::shared_ptr<const RealStack> CubeCache::get(const SceneIndex& index, std::size_t i) {
  const auto it = where_.find(i);
  if (it != where_.end()) {
    lru_.splice(lru_.begin(), lru_, it->second);
    return it->second->second;
  }
  auto cube = std::make_shared<const RealStack>(index.load(i));
  ++loads_;
  while (lru_.size() >= capacity_) {
    where_.erase(lru_.back().first);
    lru_.pop_back();
  }
  lru_.emplace_front(i, cube);
  where_[i] = lru_.begin();
  return cube;
}

PatchSampler::PatchSampler(SceneIndex index, std::vector<std::size_t> scenes, const PatchSamplerOptions& opt,
                           std::uint64_t seed)
    : index_(std::move(index)), scenes_(std::move(scenes)), opt_(opt), seed_(seed), cache_(opt.cache_scenes) {
  if (scenes_.empty()) reject("scenes", "[]", "at least one scene of the index");
  if (opt_.batch_size == 0) reject("batch_size", opt_.batch_size, "at least 1");
  if (opt_.patch_size == 0) reject("patch_size", opt_.patch_size, "at least 1 pixel");
  for (std::size_t s : scenes_) {
    if (s >= index_.size()) reject("scene", s, "an index below " + std::to_string(index_.size()));
    const SceneEntry& e = index_[s];
    if (e.shape.rows < opt_.patch_size || e.shape.cols < opt_.patch_size)
      fail(e.path, "scene of " + std::to_string(e.shape.rows) + " x " + std::to_string(e.shape.cols) +
                       " pixels is smaller than the " + std::to_string(opt_.patch_size) + " x " +
                       std::to_string(opt_.patch_size) + " patch");
  }
}

std::vector<PatchOrigin> PatchSampler::origins_for(std::size_t scene, std::mt19937_64& rng) const {
  const SceneShape& s = index_[scene].shape;
  const std::size_t P = opt_.patch_size;
  if (opt_.random_per_scene > 0) {
    std::vector<PatchOrigin> o;
    for (std::size_t k = 0; k < opt_.random_per_scene; ++k) {
      const std::size_t y = uniform_below(rng, s.rows - P + 1);
      o.push_back({y, uniform_below(rng, s.cols - P + 1)});
    }
    return o;
  }
  return opt_.stride == 0 ? grid_origins(s.rows, s.cols, P, 3) : patch_origins(s.rows, s.cols, P, opt_.stride);
}

std::size_t PatchSampler::patches_per_epoch() const {
  if (opt_.random_per_scene > 0) return opt_.random_per_scene * scenes_.size();
  std::size_t n = 0;
  std::mt19937_64 unused(0);
  for (std::size_t s : scenes_) n += origins_for(s, unused).size();
  return n;
}

void PatchSampler::plan_epoch() {
  ++epoch_;
  std::mt19937_64 rng(mix_seed(seed_, epoch_));
  std::vector<std::size_t> order = scenes_;
  shuffle(order, rng);
  plan_.clear();
  for (std::size_t g = 0; g < order.size(); g += opt_.cache_scenes) {
    std::vector<PatchRef> group;
    for (std::size_t k = g; k < std::min(order.size(), g + opt_.cache_scenes); ++k)
      for (const PatchOrigin& o : origins_for(order[k], rng)) group.push_back({order[k], o, 0});
    shuffle(group, rng);
    for (PatchRef& r : group) r.code = opt_.augment ? static_cast<int>(uniform_below(rng, 8)) : 0;
    plan_.insert(plan_.end(), group.begin(), group.end());
  }
  next_ = 0;
}

std::vector<RealStack> PatchSampler::next_batch() {
  std::vector<RealStack> batch;
  last_refs_.clear();
  while (batch.size() < opt_.batch_size) {
    if (next_ >= plan_.size()) plan_epoch();
    const PatchRef& r = plan_[next_++];
    const std::shared_ptr<const RealStack> cube = cache_.get(index_, r.scene);
    RealStack p = crop_patch(*cube, r.origin, opt_.patch_size);
    batch.push_back(r.code == 0 ? std::move(p) : augment(p, r.code));
    last_refs_.push_back(r);
  }
  return batch;
}

// =========================================================================================
// Synthetic scenes
// =========================================================================================

namespace {

// A spectral table as tabulated: rows = spectra, values on `wl_nm`.
struct SpectralTable {
  std::string file;
  std::vector<double> wl_nm;
  std::vector<std::string> names;
  std::vector<std::vector<double>> rows;
};

SpectralTable load_table(const std::string& file, bool clip01) {
  const CsvTable t = parse_csv(embedded_file(file), "embedded table " + file);
  if (t.header.size() < 2 || t.header[0] != "name")
    throw Error("embedded table " + file + ": expected a 'name' column followed by wavelength columns");
  SpectralTable s;
  s.file = file;
  for (std::size_t c = 1; c < t.header.size(); ++c) {
    char* end = nullptr;
    const double w = std::strtod(t.header[c].c_str(), &end);
    if (end == t.header[c].c_str() || (!s.wl_nm.empty() && !(w > s.wl_nm.back())))
      throw Error("embedded table " + file + ": column '" + t.header[c] + "' is not an ascending wavelength in nm");
    s.wl_nm.push_back(w);
  }
  const std::size_t n = t.raw[0].size();
  for (std::size_t r = 0; r < n; ++r) {
    std::vector<double> v;
    for (std::size_t c = 1; c < t.header.size(); ++c) {
      const double x = t.columns[c][r];
      if (!std::isfinite(x)) throw Error("embedded table " + file + ": row " + t.raw[0][r] + " has a non-number");
      v.push_back(clip01 ? std::clamp(x, 0.0, 1.0) : std::max(x, 0.0));
    }
    s.names.push_back(t.raw[0][r]);
    s.rows.push_back(std::move(v));
  }
  if (s.rows.empty()) throw Error("embedded table " + file + ": no rows");
  return s;
}

struct SyntheticTables {
  std::vector<SpectralTable> reflectance;
  SpectralTable illuminant;
};
const SyntheticTables& synthetic_tables() {
  static const SyntheticTables t = [] {
    SyntheticTables s;
    for (const std::string& f : synthetic_reflectance_files()) s.reflectance.push_back(load_table(f, true));
    s.illuminant = load_table(synthetic_illuminant_file(), false);
    return s;
  }();
  return t;
}

// Smooth value noise in [0, 1]: hashed lattice values, smoothstep-interpolated, 3 octaves.
double lattice(std::uint64_t seed, std::int64_t ix, std::int64_t iy) {
  const std::uint64_t h = splitmix64(seed ^ splitmix64(static_cast<std::uint64_t>(ix) * 0x9E3779B97F4A7C15ull +
                                                       static_cast<std::uint64_t>(iy) * 0xC2B2AE3D27D4EB4Full));
  return static_cast<double>(h >> 11) * (1.0 / 9007199254740992.0);
}
double value_noise(std::uint64_t seed, double x, double y) {
  const double fx0 = std::floor(x), fy0 = std::floor(y);
  const auto ix = static_cast<std::int64_t>(fx0), iy = static_cast<std::int64_t>(fy0);
  const double fx = x - fx0, fy = y - fy0;
  const double sx = fx * fx * (3 - 2 * fx), sy = fy * fy * (3 - 2 * fy);
  const double a = lattice(seed, ix, iy), b = lattice(seed, ix + 1, iy);
  const double c = lattice(seed, ix, iy + 1), d = lattice(seed, ix + 1, iy + 1);
  return (a + (b - a) * sx) * (1 - sy) + (c + (d - c) * sx) * sy;
}
double fractal_noise(std::uint64_t seed, double x, double y, double cell) {
  double sum = 0, norm = 0, amp = 1, f = 1 / cell;
  for (std::uint64_t o = 0; o < 3; ++o) {
    sum += amp * value_noise(seed + o, x * f, y * f);
    norm += amp;
    amp *= 0.5;
    f *= 2;
  }
  return sum / norm;
}

// One occluding shape, centre (cx, cy) and size r in pixels.
struct Shape {
  int type = 0;                   // 0 ellipse, 1 rotated rectangle, 2 star-shaped polygon
  double cx = 0, cy = 0, r = 1, aspect = 1, angle = 0;
  std::vector<double> px, py;     // polygon vertices (type 2)

  double bound() const { return r * std::sqrt(1 + aspect * aspect); }
  bool inside(double x, double y) const {
    const double dx = x - cx, dy = y - cy;
    if (type == 2) {  // crossing number
      bool in = false;
      for (std::size_t i = 0, j = px.size() - 1; i < px.size(); j = i++)
        if ((py[i] > y) != (py[j] > y) && x < (px[j] - px[i]) * (y - py[i]) / (py[j] - py[i]) + px[i]) in = !in;
      return in;
    }
    const double c = std::cos(angle), s = std::sin(angle);
    const double u = (dx * c + dy * s) / r, v = (-dx * s + dy * c) / (r * aspect);
    return type == 0 ? u * u + v * v <= 1 : (std::abs(u) <= 1 && std::abs(v) <= 1);
  }
};

// Per-material appearance: texture and shading parameters.
struct Look {
  double tex_amp = 0, tex_cell = 16, shade = 0, shade_angle = 0, cx = 0, cy = 0, r = 1;
  std::uint64_t tex_seed = 0;
};

}  // namespace

const std::vector<std::string>& synthetic_reflectance_files() {
  static const std::vector<std::string> f = {"munsell_matt_uef1269_400-700nm_10nm.csv",
                                             "rawtoaces_190patches_400-700nm_10nm.csv",
                                             "cie2017_cfi_ces99_400-700nm_10nm.csv"};
  return f;
}
const std::string& synthetic_illuminant_file() {
  static const std::string f = "cie_illuminants_400-700nm_10nm.csv";
  return f;
}

SyntheticScene synthetic_scene_detail(const SystemConfig& cfg, std::size_t size_px, std::uint64_t seed) {
  if (size_px == 0 || size_px > 16384) reject("size_px", size_px, "1 .. 16384 pixels");
  const std::vector<double> wl = cfg.wavelengths_nm();
  if (wl.empty()) reject("bands", wl.size(), "at least 1 band");
  const SyntheticTables& tables = synthetic_tables();
  std::mt19937_64 rng(mix_seed(seed, 0x5CE7Eu));
  const std::size_t S = size_px;
  const double Sd = static_cast<double>(S);

  SyntheticScene out;
  // Illuminant, scaled to max 1 on the band grid.
  {
    const SpectralTable& t = tables.illuminant;
    const std::size_t r = uniform_below(rng, t.rows.size());
    out.illuminant = t.file + ":" + t.names[r];
    out.illuminant_spd = interpolate_spectrum(t.wl_nm, t.rows[r], wl, "illuminant " + out.illuminant);
    const double mx = *std::max_element(out.illuminant_spd.begin(), out.illuminant_spd.end());
    if (!(mx > 0)) throw Error("illuminant " + out.illuminant + " is zero on the band grid");
    for (double& v : out.illuminant_spd) v /= mx;
  }
  auto draw_material = [&] {
    const SpectralTable& t = tables.reflectance[uniform_below(rng, tables.reflectance.size())];
    const std::size_t r = uniform_below(rng, t.rows.size());
    out.material.push_back(t.file + ":" + t.names[r]);
    out.reflectance.push_back(interpolate_spectrum(t.wl_nm, t.rows[r], wl, "reflectance " + out.material.back()));
  };
  auto draw_look = [&](double cx, double cy, double r) {
    Look l;
    l.tex_amp = uniform01(rng) < 0.3 ? 0.0 : uniform(rng, 0.05, 0.6);
    l.tex_cell = std::max(2.0, Sd * std::exp(uniform(rng, std::log(1.0 / 64), std::log(1.0 / 4))));
    l.tex_seed = rng();
    l.shade = uniform(rng, 0.0, 0.4);
    l.shade_angle = uniform(rng, 0.0, 2 * M_PI);
    l.cx = cx;
    l.cy = cy;
    l.r = std::max(r, 1.0);
    return l;
  };

  // Background (label 0), then K shapes in painter's order.
  std::vector<Look> looks;
  draw_material();
  looks.push_back(draw_look(Sd / 2, Sd / 2, Sd));
  out.label.assign(S * S, 0);
  const std::size_t K = 12 + uniform_below(rng, 29);  // 12 .. 40 shapes
  for (std::size_t k = 1; k <= K; ++k) {
    Shape sh;
    sh.type = static_cast<int>(uniform_below(rng, 3));
    sh.cx = uniform(rng, -0.1, 1.1) * Sd;
    sh.cy = uniform(rng, -0.1, 1.1) * Sd;
    sh.r = std::max(1.5, Sd * std::exp(uniform(rng, std::log(0.03), std::log(0.3))));  // log-uniform size
    sh.aspect = uniform(rng, 0.3, 1.0);
    sh.angle = uniform(rng, 0.0, M_PI);
    if (sh.type == 2) {
      const std::size_t nv = 3 + uniform_below(rng, 6);
      std::vector<double> ang(nv);
      for (double& a : ang) a = uniform(rng, 0.0, 2 * M_PI);
      std::sort(ang.begin(), ang.end());
      for (double a : ang) {
        const double rr = sh.r * uniform(rng, 0.5, 1.0);
        sh.px.push_back(sh.cx + rr * std::cos(a));
        sh.py.push_back(sh.cy + rr * std::sin(a));
      }
    }
    draw_material();
    looks.push_back(draw_look(sh.cx, sh.cy, sh.r));
    const double b = sh.bound();
    const auto lo = [&](double c) { return static_cast<std::size_t>(std::clamp(std::floor(c - b), 0.0, Sd)); };
    const auto hi = [&](double c) { return static_cast<std::size_t>(std::clamp(std::ceil(c + b) + 1, 0.0, Sd)); };
    for (std::size_t y = lo(sh.cy); y < hi(sh.cy); ++y)
      for (std::size_t x = lo(sh.cx); x < hi(sh.cx); ++x)
        if (sh.inside(static_cast<double>(x) + 0.5, static_cast<double>(y) + 0.5))
          out.label[y * S + x] = static_cast<std::uint32_t>(k);
  }

  // Albedo: exposure x global shading x per-shape shading x per-shape texture, in (0, 1].
  const double exposure = uniform(rng, 0.75, 1.0);
  const double g_shade = uniform(rng, 0.0, 0.4), g_angle = uniform(rng, 0.0, 2 * M_PI);
  const double gc = std::cos(g_angle), gs = std::sin(g_angle);
  out.albedo = Map2D(S, S);
  for (std::size_t y = 0; y < S; ++y)
    for (std::size_t x = 0; x < S; ++x) {
      const double fx = static_cast<double>(x) + 0.5, fy = static_cast<double>(y) + 0.5;
      const double ramp = std::clamp(((fx / Sd - 0.5) * gc + (fy / Sd - 0.5) * gs) * M_SQRT2, -1.0, 1.0);
      const Look& l = looks[out.label[y * S + x]];
      const double proj = std::clamp(((fx - l.cx) * std::cos(l.shade_angle) + (fy - l.cy) * std::sin(l.shade_angle)) / l.r,
                                     -1.0, 1.0);
      const double tex = l.tex_amp > 0 ? 1 - l.tex_amp * fractal_noise(l.tex_seed, fx, fy, l.tex_cell) : 1.0;
      out.albedo(y, x) = exposure * (1 - g_shade * (0.5 + 0.5 * ramp)) * (1 - l.shade * (0.5 + 0.5 * proj)) * tex;
    }

  // cube(b, y, x) = albedo(y, x) * reflectance[label][b] * illuminant[b].
  out.cube = RealStack(wl.size(), S, S);
  for (std::size_t b = 0; b < wl.size(); ++b) {
    double* plane = out.cube.plane(b);
    for (std::size_t i = 0; i < S * S; ++i)
      plane[i] = out.albedo.data[i] * out.reflectance[out.label[i]][b] * out.illuminant_spd[b];
  }
  return out;
}

RealStack synthetic_scene(const SystemConfig& cfg, std::size_t size_px, std::uint64_t seed) {
  return synthetic_scene_detail(cfg, size_px, seed).cube;
}

}  // namespace qdo
