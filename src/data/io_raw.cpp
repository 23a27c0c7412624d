// Camera raw files through LibRaw (open_file + unpack only: the stored mosaic, never its
// processing), and the minimal DNG writer (libtiff). io_raw.hpp holds the contract.
#include <libraw/libraw.h>
#include <tiffio.h>

#include <algorithm>
#include <array>
#include <cctype>
#include <cmath>
#include <cstdarg>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>
#include <system_error>
#include <vector>

#include "data/io_internal.hpp"
#include "data/io_tiff_internal.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io_raw.hpp"

namespace qdo {
using namespace io_detail;

namespace {

constexpr std::uint64_t kMaxRawPixels = std::uint64_t{1} << 28;
const std::string kNeedBayer =
    "qdo needs a raw Bayer mosaic (a DNG or a camera's raw file) or a 16-bit TIFF/PNG export of it without demosaicking";

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  return s;
}

// LibRaw returns errno values (> 0) for system errors and its own codes (< 0) otherwise.
std::string libraw_message(int code) {
  if (code > 0) return std::generic_category().message(code);
  return libraw_strerror(code);
}

// LibRaw's decoders report damaged data through this callback and go on decoding; the first
// report is kept so that read_camera_raw refuses the frame instead of returning damaged codes.
struct DataErrors {
  int count = 0;
  int offset = 0;  // byte offset of the first report; < 0: the file ended early
};
void on_data_error(void* data, const char* /*file*/, const int offset) {
  auto* e = static_cast<DataErrors*>(data);
  if (e->count++ == 0) e->offset = offset;
}

// The 2 x 2 cell at the visible origin as lowercase colour letters (LibRaw's cdesc names the
// colour indices COLOR returns: "RGBG" for RGB cameras, index 3 the second green), or "" when
// the filter layout (8 rows x 2 columns in LibRaw's `filters`) does not repeat every 2 rows.
std::string bayer_cell(LibRaw& r) {
  const char* cdesc = r.imgdata.idata.cdesc;
  auto letter = [&](int row, int col) {
    const int c = r.COLOR(row, col);
    return c >= 0 && c < 4 && cdesc[c] ? char(std::tolower(static_cast<unsigned char>(cdesc[c]))) : '?';
  };
  for (int row = 2; row < 8; ++row)
    for (int col = 0; col < 2; ++col)
      if (letter(row, col) != letter(row % 2, col)) return "";
  return {letter(0, 0), letter(0, 1), letter(1, 0), letter(1, 1)};
}

bool is_bayer(const std::string& cell) {
  return cell == "rggb" || cell == "bggr" || cell == "grbg" || cell == "gbrg";
}

// LibRaw, with a look at what it parsed from the DNG IFD it decodes.
class RawDecoder : public LibRaw {
 public:
  // The ActiveArea corner (row, column) that IFD gives (0, 0 without one). LibRaw 0.20 moves an
  // odd corner to even coordinates and shifts `filters` to match, but leaves the BlackLevel
  // block (cblack[6...]) as the file anchors it: at this corner.
  std::array<long, 2> dng_active_origin() const {
    const auto& frames = libraw_internal_data.unpacker_data.dng_frames;
    const unsigned shot = imgdata.params.shot_select;
    if (!imgdata.idata.dng_version || shot >= sizeof frames / sizeof frames[0]) return {0, 0};
    const unsigned ifd = (frames[shot] >> 8) & 0xff;  // bits 8-15: the IFD of the frame
    if (ifd >= libraw_internal_data.identify_data.tiff_nifds || ifd >= LIBRAW_IFD_MAXCOUNT) return {0, 0};
    return {tiff_ifd[ifd].t_tm, tiff_ifd[ifd].t_lm};
  }
};

// Black level per CFA position (row-major 2 x 2 at the visible origin, which is stored pixel
// (top, left)) from what open_file leaves in imgdata.color: black + cblack[COLOR(row, col)] + the
// repeating block cblack[6...] of cblack[4] rows x cblack[5] columns (where a DNG BlackLevel
// with BlackLevelRepeatDim lands, black then 0). LibRaw folds these together (adjust_bl) only
// when it processes, which qdo never asks for. A DNG's block starts at its ActiveArea corner;
// while LibRaw leaves the block as parsed it is read from there. A block that does not repeat
// every 2 rows and columns is averaged over each position's pixels.
std::array<double, 4> channel_black(RawDecoder& r, std::size_t top, std::size_t left) {
  const auto& c = r.imgdata.color;
  const std::size_t br = c.cblack[4], bc = c.cblack[5];
  const bool block = br > 0 && bc > 0 && br * bc <= LIBRAW_CBLACK_SIZE - 6;
  std::size_t phase_r = 0, phase_c = 0;  // the block's row and column at the visible origin
  if (block && r.imgdata.idata.dng_version &&
      std::equal(c.cblack + 6, c.cblack + 6 + br * bc, c.dng_levels.dng_cblack + 6)) {
    const std::array<long, 2> origin = r.dng_active_origin();
    const long dr = long(top) - origin[0], dc = long(left) - origin[1];
    phase_r = std::size_t((dr % long(br) + long(br)) % long(br));
    phase_c = std::size_t((dc % long(bc) + long(bc)) % long(bc));
  }
  const std::size_t period_r = block ? 2 * br : 2, period_c = block ? 2 * bc : 2;
  std::array<double, 4> out{};
  for (std::size_t p = 0; p < 4; ++p) {
    double sum = 0;
    std::size_t n = 0;
    for (std::size_t row = p / 2; row < period_r; row += 2)
      for (std::size_t col = p % 2; col < period_c; col += 2) {
        double b = double(c.black) + double(c.cblack[r.COLOR(int(row), int(col)) & 3]);
        if (block) b += double(c.cblack[6 + ((row + phase_r) % br) * bc + (col + phase_c) % bc]);
        sum += b;
        ++n;
      }
    out[p] = sum / double(n);
  }
  return out;
}


bool is_code_value(double v) { return v >= 0 && v <= 65535 && v == std::floor(v); }

}  // namespace

bool is_camera_raw_path(const std::string& path) {
  static const char* const kExtensions[] = {".dng", ".nef", ".cr2", ".cr3", ".arw", ".raf",
                                            ".orf", ".rw2", ".pef", ".srw", ".raw"};
  const std::string e = lower(std::filesystem::path(path).extension().string());
  return std::any_of(std::begin(kExtensions), std::end(kExtensions), [&](const char* x) { return e == x; });
}

RealStack read_camera_raw(const std::string& path, CameraRawInfo* info) {
  require_file(path);
  // LibRaw holds several hundred KiB of state: on the heap; its destructor recycles.
  auto raw = std::make_unique<RawDecoder>();
  DataErrors data_errors;
  raw->set_dataerror_handler(on_data_error, &data_errors);
  int rc = raw->open_file(path.c_str());
  if (rc != LIBRAW_SUCCESS) fail(path, "", "not a camera raw file LibRaw reads (" + libraw_message(rc) + "); " + kNeedBayer);

  const auto& id = raw->imgdata.idata;
  const std::string camera = std::string(id.make) + " " + id.model;
  if (id.is_foveon) fail(path, "", "a Foveon sensor's raw file (" + camera + ": three stacked colour layers, no mosaic); " + kNeedBayer);
  if (id.filters == 0) {
    if (id.colors == 1) fail(path, "", "a monochrome sensor's raw image (" + camera + ": no colour filter array); " + kNeedBayer);
    fail(path, "", "holds no colour filter mosaic but " + std::to_string(id.colors) +
                       " colour samples per pixel (a linear DNG, or a demosaiced or reduced-size sRAW/mRAW image); " + kNeedBayer);
  }
  if (id.filters == 9) fail(path, "", "a Fujifilm X-Trans mosaic (6 x 6 pattern, " + camera + "), not a Bayer mosaic; " + kNeedBayer);
  if (id.filters < 1000)
    fail(path, "", "a colour filter layout other than a Bayer mosaic (LibRaw filters " + std::to_string(id.filters) + ", " + camera +
                       "); " + kNeedBayer);
  if (raw->get_internal_data_pointer()->internal_output_params.fuji_width)
    fail(path, "", "a Fujifilm SuperCCD layout (pixels on a 45-degree grid, " + camera + "), not a Bayer mosaic; " + kNeedBayer);
  const std::string cell = bayer_cell(*raw);
  if (!is_bayer(cell))
    fail(path, "", "a " + std::to_string(id.colors) + "-colour mosaic (" + std::string(id.cdesc) + ", 2 x 2 cell '" + cell +
                       "'), not an RGB Bayer mosaic; " + kNeedBayer);
  {
    const auto& s = raw->imgdata.sizes;
    const std::uint64_t stored = std::uint64_t(s.raw_height) * s.raw_width;
    if (stored == 0 || stored > kMaxRawPixels || s.height == 0 || s.width == 0)
      fail(path, "", "declares " + std::to_string(s.raw_height) + " x " + std::to_string(s.raw_width) +
                         " stored pixels (at least 1 x 1, at most 2^28)");
  }

  rc = raw->unpack();
  if (rc != LIBRAW_SUCCESS) fail(path, "", "LibRaw cannot unpack its raw data (" + libraw_message(rc) + ")");
  if (data_errors.count > 0)
    fail(path, "", data_errors.offset < 0 ? "the file ends before its raw data does (truncated?)"
                                          : "LibRaw reports corrupt raw data near byte " + std::to_string(data_errors.offset));
  const ushort* mosaic = raw->imgdata.rawdata.raw_image;
  if (!mosaic)
    fail(path, "", "holds no one-sample-per-pixel mosaic after unpacking (a reduced-size sRAW/mRAW or a linear DNG); " + kNeedBayer);

  // The visible area, clipped to what is stored (as LibRaw's own copy does).
  const auto& s = raw->imgdata.sizes;
  const std::size_t top = s.top_margin, left = s.left_margin;
  const std::size_t pitch = s.raw_pitch / sizeof(ushort);  // uint16 per stored row
  if (top >= s.raw_height || left >= s.raw_width || pitch < s.raw_width)
    fail(path, "", "an inconsistent layout (visible area at row " + std::to_string(top) + ", column " + std::to_string(left) +
                       " of " + std::to_string(s.raw_height) + " x " + std::to_string(s.raw_width) + " stored pixels)");
  const std::size_t rows = std::min<std::size_t>(s.height, s.raw_height - top);
  const std::size_t cols = std::min<std::size_t>(s.width, s.raw_width - left);
  RealStack out(1, rows, cols);
  for (std::size_t y = 0; y < rows; ++y) {
    const ushort* line = mosaic + (top + y) * pitch + left;
    double* dst = out.plane(0) + y * cols;
    for (std::size_t x = 0; x < cols; ++x) dst[x] = line[x];
  }

  if (info) {
    const auto& c = raw->imgdata.color;
    CameraRawInfo in;
    in.make = id.make;
    in.model = id.model;
    in.cfa = cell;
    in.channel_black_dn = channel_black(*raw, top, left);
    in.black_level_dn = (in.channel_black_dn[0] + in.channel_black_dn[1] + in.channel_black_dn[2] + in.channel_black_dn[3]) / 4;
    in.white_level_dn = c.maximum;
    for (long m : c.linear_max)
      if (m > 0 && (in.linear_max_dn == 0 || double(m) < in.linear_max_dn)) in.linear_max_dn = double(m);
    in.rows = rows;
    in.cols = cols;
    in.top = top;
    in.left = left;
    const unsigned bps = raw->get_internal_data_pointer()->unpacker_data.tiff_bps;
    in.bits = bps >= 1 && bps <= 16 ? int(bps) : 0;
    *info = std::move(in);
  }
  return out;
}

void write_dng_mosaic(const std::string& path, const Map2D& dn, const std::string& cfa, double black_level_dn,
                      double white_level_dn, const std::string& make, const std::string& model) {
  const std::string where = " (file '" + path + "')";
  const std::string pattern = lower(cfa);
  if (!is_bayer(pattern)) reject("CFA pattern", cfa, "one of rggb, bggr, grbg, gbrg" + where);
  if (dn.rows == 0 || dn.cols == 0 || dn.data.size() != dn.rows * dn.cols ||
      std::uint64_t(dn.rows) * dn.cols > kMaxRawPixels)
    reject("DNG mosaic size", std::to_string(dn.rows) + " x " + std::to_string(dn.cols),
           "at least 1 x 1, at most 2^28 pixels, data matching the shape" + where);
  for (double v : dn.data)
    if (!is_code_value(v)) reject("DNG code value", v, "integer code values in [0, 65535]" + where);
  if (!is_code_value(black_level_dn)) reject("DNG black level", black_level_dn, "an integer in [0, 65535]" + where);
  if (!is_code_value(white_level_dn) || white_level_dn <= black_level_dn)
    reject("DNG white level", white_level_dn, "an integer in [0, 65535] above the black level" + where);
  if (make.empty() || model.empty()) reject("DNG make and model", "\"" + make + "\", \"" + model + "\"", "non-empty names" + where);

  // CFAPattern codes: 0 red, 1 green, 2 blue, row-major over the 2 x 2 cell.
  std::array<std::uint8_t, 4> cfa_codes{};
  for (std::size_t i = 0; i < 4; ++i) cfa_codes[i] = pattern[i] == 'r' ? 0 : pattern[i] == 'g' ? 1 : 2;
  const std::string unique_model = make + " " + model;
  const std::uint8_t dng_version[4] = {1, 4, 0, 0}, dng_backward[4] = {1, 1, 0, 0};
  const std::uint16_t cfa_dim[2] = {2, 2};
  const float black[1] = {float(black_level_dn)};
  const std::uint32_t white[1] = {std::uint32_t(white_level_dn)};
  const float color_matrix[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};  // XYZ -> camera, row-major 3 x 3
  const float neutral[3] = {1, 1, 1};

  AtomicFile out(path);
  TIFFSetErrorHandler(tiff_handler);
  tiff_message.clear();
  {
    TiffPtr t(TIFFOpen(out.tmp().c_str(), "w"));
    if (!t) fail(path, "", "DNG write failed (" + tiff_message + ")");
    TIFF* f = t.get();
    const std::uint32_t w = std::uint32_t(dn.cols), h = std::uint32_t(dn.rows);
    TIFFSetField(f, TIFFTAG_SUBFILETYPE, std::uint32_t{0});
    TIFFSetField(f, TIFFTAG_IMAGEWIDTH, w);
    TIFFSetField(f, TIFFTAG_IMAGELENGTH, h);
    TIFFSetField(f, TIFFTAG_BITSPERSAMPLE, 16);
    TIFFSetField(f, TIFFTAG_SAMPLESPERPIXEL, 1);
    TIFFSetField(f, TIFFTAG_SAMPLEFORMAT, SAMPLEFORMAT_UINT);
    TIFFSetField(f, TIFFTAG_PLANARCONFIG, PLANARCONFIG_CONTIG);
    TIFFSetField(f, TIFFTAG_PHOTOMETRIC, PHOTOMETRIC_CFA);
    TIFFSetField(f, TIFFTAG_COMPRESSION, COMPRESSION_NONE);
    TIFFSetField(f, TIFFTAG_ORIENTATION, ORIENTATION_TOPLEFT);
    TIFFSetField(f, TIFFTAG_ROWSPERSTRIP, TIFFDefaultStripSize(f, 0));
    TIFFSetField(f, TIFFTAG_MAKE, make.c_str());
    TIFFSetField(f, TIFFTAG_MODEL, model.c_str());
    // Array tags: fixed-count ones take the array alone, variable-count ones a uint16 count first
    // (libtiff 4's field table); rationals are passed as float.
    TIFFSetField(f, TIFFTAG_DNGVERSION, dng_version);
    TIFFSetField(f, TIFFTAG_DNGBACKWARDVERSION, dng_backward);
    TIFFSetField(f, TIFFTAG_UNIQUECAMERAMODEL, unique_model.c_str());
    TIFFSetField(f, TIFFTAG_CFAREPEATPATTERNDIM, cfa_dim);
    TIFFSetField(f, TIFFTAG_CFAPATTERN, std::uint16_t{4}, cfa_codes.data());
    TIFFSetField(f, TIFFTAG_BLACKLEVEL, std::uint16_t{1}, black);
    TIFFSetField(f, TIFFTAG_WHITELEVEL, std::uint16_t{1}, white);
    TIFFSetField(f, TIFFTAG_COLORMATRIX1, std::uint16_t{9}, color_matrix);
    TIFFSetField(f, TIFFTAG_ASSHOTNEUTRAL, std::uint16_t{3}, neutral);
    TIFFSetField(f, TIFFTAG_CALIBRATIONILLUMINANT1, std::uint16_t{21});  // D65
    std::vector<std::uint16_t> line(w);
    for (std::uint32_t y = 0; y < h; ++y) {
      for (std::uint32_t x = 0; x < w; ++x) line[x] = std::uint16_t(dn.data[std::size_t(y) * w + x]);
      if (TIFFWriteScanline(f, line.data(), y, 0) < 0) fail(path, "", "DNG write failed (" + tiff_message + ")");
    }
    if (!TIFFFlush(f)) fail(path, "", "DNG write failed (" + tiff_message + ")");
  }
  out.commit();
}

}  // namespace qdo
