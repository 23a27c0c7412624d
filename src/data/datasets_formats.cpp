// Training scenes, the readers: scene format detection and probing (MAT variable listing,
// HDF5 dataset shapes), folders of PNG bands, and load_scene with each format's scale (see
// include/qdo/data/datasets.hpp).
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
#include <utility>

#include "data/datasets_internal.hpp"
#include "data/io_internal.hpp"
#include "qdo/data/datasets.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"

namespace qdo {
using namespace io_detail;
using namespace datasets_detail;
namespace {

namespace fs = std::filesystem;

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return s;
}

// The rule read_cube uses to pick libmatio over HDF5.
bool is_mat_file(const std::string& path) { return looks_like_mat(path); }

const std::vector<std::string>& known_formats() {
  static const std::vector<std::string> f = {"auto", "icvl", "cave", "cave-png", "harvard", "kaist", "h5"};
  return f;
}

// ---------------------------------------------------------------------------------------
// MATLAB and HDF5 headers
// ---------------------------------------------------------------------------------------

struct MatVarInfo {
  std::string name;
  std::vector<std::size_t> dims;  // MATLAB's dims
  bool numeric = false;           // real numeric class
};

// Every variable's name, dims and class, from the variable headers only (no data read).
std::vector<MatVarInfo> mat_variables(const std::string& path) {
  h5_quiet();  // v7.3 files are read through HDF5
  check_mat_file(path);
  MatFile mat(Mat_Open(path.c_str(), MAT_ACC_RDONLY));
  if (!mat) fail(path, "not a readable MATLAB .mat file");
  std::vector<MatVarInfo> vars;
  Mat_Rewind(mat.get());
  while (MatVar info{Mat_VarReadNextInfo(mat.get())}) {
    MatVarInfo v;
    v.name = info->name ? info->name : "";
    v.dims = mat_dims(*info);
    v.numeric = mat_numeric(*info);
    vars.push_back(std::move(v));
  }
  return vars;
}

bool mat_has(const std::vector<MatVarInfo>& vars, const std::string& name) {
  return std::any_of(vars.begin(), vars.end(), [&](const MatVarInfo& v) { return v.name == name; });
}

// Whether `elements` of at least `bytes_each` bytes could be stored in the file at `path`
// (compressed at most ~1032:1, as read_cube checks before allocating). Probes only trust
// header shapes that pass; others go through the reader, which names the problem.
bool plausible_size(const std::string& path, std::uintmax_t elements, std::uintmax_t bytes_each) {
  std::error_code ec;
  const std::uintmax_t file = fs::file_size(path, ec);
  return !ec && elements <= (file * kMaxExpansion + kSlackBytes) / std::max<std::uintmax_t>(bytes_each, 1);
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
  h5_quiet();
  H5Id file(H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT), H5Fclose);
  if (!file.valid() || H5Lexists(file.get(), name.c_str(), H5P_DEFAULT) <= 0) return false;
  H5Id dset(H5Dopen2(file.get(), name.c_str(), H5P_DEFAULT), H5Dclose);
  if (!dset.valid()) return false;
  H5Id space(H5Dget_space(dset.get()), H5Sclose);
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

// A grayscale PNG: the header on construction (libpng's simplified API, which only reads it
// here), the stored pixels with finish() (read_png_codes).
class PngRead {
 public:
  explicit PngRead(const std::string& path) : path_(path) {
    if (!png_image_begin_read_from_file(&img_.img, path.c_str()))
      fail(path, std::string("not a readable PNG file (") + img_.img.message + ")");
    // Colour (RGB, RGBA, colour palette) and alpha files are accepted when every pixel is grey
    // (R = G = B) and opaque (checked in finish()).
    // Decoding allocates what the header declares: check it against the file first. Each row
    // holds a filter byte and at least 1 bit per pixel, deflated at most ~1032:1.
    const std::uintmax_t w = img_.img.width, h = img_.img.height;
    const std::string dims = std::to_string(h) + " x " + std::to_string(w);
    if (w == 0 || h == 0 || w * h > (std::uintmax_t{1} << 28))
      fail(path, "header declares " + dims + " pixels (rows x columns); at most 2^28 (16384 x 16384) per band are accepted");
    std::error_code ec;
    const std::uintmax_t file = fs::file_size(path, ec);
    if (ec || h * (1 + (w + 7) / 8) > file * kMaxExpansion + kSlackBytes)
      fail(path, "header declares " + dims + " pixels but the file has only " + std::to_string(file) +
                     " bytes: truncated or corrupt");
  }

  std::size_t width() const { return img_.img.width; }
  std::size_t height() const { return img_.img.height; }
  bool sixteen_bit() const { return (img_.img.format & PNG_FORMAT_FLAG_LINEAR) != 0; }

  // The pixels, row-major, the stored codes divided by 65535 (16-bit) or 255 (8-bit): no gamma
  // transform, whatever gAMA, sRGB or iCCP chunk the file carries (read_png_codes). Colour and
  // alpha files are accepted when every pixel is grey (R = G = B) and opaque.
  std::vector<double> finish() {
    const PngCodes p = read_png_codes(path_);
    if (p.width != width() || p.height != height()) fail(path_, "the file changed while it was read");
    const double full = p.bit_depth == 16 ? 65535.0 : 255.0;
    const std::size_t n = p.width * p.height;
    std::vector<double> out(n);
    if (p.channels == 1) {
      for (std::size_t i = 0; i < n; ++i) out[i] = p.samples[i] / full;
      return out;
    }
    grey_opaque(p, full, out);
    return out;
  }

 private:
  // Gray+alpha or RGB(A) samples to one grey channel: R = G = B and alpha at full scale
  // everywhere, else an InputError naming the first pixel that is coloured or transparent.
  void grey_opaque(const PngCodes& p, double full, std::vector<double>& out) const {
    const std::size_t w = width(), ch = p.channels;
    const bool colour = ch >= 3, alpha = ch == 2 || ch == 4;
    for (std::size_t i = 0; i < out.size(); ++i) {
      const std::uint16_t* px = &p.samples[i * ch];
      const std::uint16_t r = px[0], g = colour ? px[1] : r, b = colour ? px[2] : r, a = alpha ? px[ch - 1] : std::uint16_t(full);
      auto at = [&] { return "pixel (row " + std::to_string(i / w) + ", column " + std::to_string(i % w) + ")"; };
      if (r != g || g != b)
        fail(path_, "colour PNG with a coloured " + at() + " (R, G, B = " + std::to_string(r) + ", " + std::to_string(g) +
                        ", " + std::to_string(b) + "); a band image must be grayscale, or RGB(A) with R = G = B");
      if (a != full)
        fail(path_, "PNG with a transparent " + at() + " (alpha " + std::to_string(a) + " of " + to_str(full) +
                        "); a band image must be opaque");
      out[i] = r / full;
    }
  }

  std::string path_;
  PngImage img_;
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

namespace datasets_detail {

[[noreturn]] void fail_dir(const std::string& dir, const std::string& problem) {
  throw InputError("folder '" + dir + "': " + problem);
}

std::string lower_ext(const fs::path& p) { return lower(p.extension().string()); }

std::string shape_str(const SceneShape& s) { return io_detail::shape_str(std::vector<std::size_t>{s.bands, s.rows, s.cols}); }

void check_format(const std::string& format) {
  const auto& f = known_formats();
  if (std::find(f.begin(), f.end(), format) == f.end())
    reject("format", format, "one of auto, icvl, cave, cave-png, harvard, kaist, h5");
}

std::string resolve_format(const std::string& path, const std::string& format) {
  check_format(format);
  std::error_code ec;
  const bool dir = fs::is_directory(path, ec);
  if (format == "auto") return detect_scene_format(path);
  if (format == "cave" && dir) return "cave-png";
  return format;
}

}  // namespace datasets_detail

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
  h5_quiet();
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

}  // namespace qdo
