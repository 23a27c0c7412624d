// Files in and out. The HDF5 layout is a contract (README "File formats"):
//   designs       /height_m        (N x N, float64, attribute pitch_m)  [+ optional /levels_m]
//   PSF stacks    /psf             (bands x N x N, float64) + /wavelengths_nm (bands)
//   cubes         /cube            (bands x H x W, float64 in [0,1]) + /wavelengths_nm
//   sensor images /rgb             (3 x H x W, float64)
// Every writer writes to "<path>.tmp-<pid>" and renames, so a failure never leaves a
// half-written file. Every reader names the file, the dataset and the problem on failure.
#pragma once
#include <map>
#include <string>
#include <vector>

#include "qdo/types.hpp"

namespace qdo {

// ---------- HDF5 ----------
// A named array for writing: shape in C order, row-major data.
struct H5Dataset {
  std::string name;                    // absolute path, e.g. "/psf"
  std::vector<std::size_t> shape;
  std::vector<double> data;            // written as float64
  std::map<std::string, double> num_attrs;       // numeric attributes
  std::map<std::string, std::string> str_attrs;  // string attributes (e.g. "units")
};

// Writes all datasets into one new file atomically (temp file + rename).
void h5_write(const std::string& path, const std::vector<H5Dataset>& datasets,
              const std::map<std::string, std::string>& root_str_attrs = {});

// Reads one dataset (any numeric type, converted to double). Throws InputError naming the
// file and dataset if missing, non-numeric, or larger than max_elements.
H5Dataset h5_read(const std::string& path, const std::string& name,
                  std::size_t max_elements = std::size_t(1) << 31);
bool h5_has(const std::string& path, const std::string& name);

// ---------- Contract helpers ----------
struct Design {
  Map2D height_m;                      // N x N glass relief above the base plate, metres
  double pitch_m = 0;
  std::vector<double> levels_m;        // the level table when quantized, else empty
};
void write_design(const std::string& path, const Design& d,
                  const std::map<std::string, std::string>& provenance = {});
Design read_design(const std::string& path);   // checks square, finite, pitch_m > 0

void write_psf(const std::string& path, const RealStack& psf, const std::vector<double>& wavelengths_nm,
               double pitch_m, const std::map<std::string, double>& extra_num_attrs = {});
void write_cube(const std::string& path, const RealStack& cube, const std::vector<double>& wavelengths_nm);
void write_rgb(const std::string& path, const RealStack& rgb);

// A hyperspectral cube from HDF5 (/cube, or a named dataset), MATLAB .mat v5 or v7.3
// (libmatio). `key` picks the variable ("" = the only numeric 3-D variable, or /cube).
// `layout` says where the band axis is: "auto" (the axis whose length equals
// expected_bands, preferring the last for .mat), "bhw" or "hwb" (both in reading order:
// for .mat files MATLAB's dims). `scale` divides the values ("auto": 65535 for uint16,
// 4095 for ICVL-like data whose max <= 4095 and key "rad", 1 for floats).
// expected_bands = 0 skips the band check; otherwise a mismatch is an InputError naming
// the file, the key, the shape found and the bands expected.
struct CubeReadOptions {
  std::string key;
  std::string layout = "auto";
  double scale = 0;                    // 0 = auto
  std::size_t expected_bands = 0;
};
RealStack read_cube(const std::string& path, const CubeReadOptions& opt = {});

// ---------- CSV spectral tables ----------
// '#' lines are comments; the first non-comment line is the header; numeric rows follow.
struct CsvTable {
  std::vector<std::string> header;
  std::vector<std::vector<double>> columns;  // columns[c][row]; NaN where a cell is not a number
  std::vector<std::vector<std::string>> raw; // raw[c][row], the cell text (e.g. a name column)
  std::vector<std::string> comments;
  std::string origin;                        // the file (or description) it was parsed from
  const std::vector<double>& column(const std::string& name) const;  // throws InputError naming it and origin
};
CsvTable parse_csv(const std::string& text, const std::string& origin);
CsvTable read_csv(const std::string& path);

// ---------- PNG figures ----------
// 8-bit grayscale (channels = 1) or RGB (channels = 3) image, row-major, interleaved.
void write_png(const std::string& path, std::size_t width, std::size_t height, int channels,
               const std::vector<unsigned char>& pixels);
// A montage of every plane of `stack`, tiles in a near-square grid with 2 px gaps, each plane
// scaled to its own max, gamma `gamma` (0.5 shows faint PSF wings), tinted by its wavelength
// (CIE-like hue) when wavelengths_nm is non-empty, else gray. Optional crop to the centre
// `crop` x `crop` of each plane (0 = whole).
void write_montage_png(const std::string& path, const RealStack& stack,
                       const std::vector<double>& wavelengths_nm, double gamma = 0.5, std::size_t crop = 0);
// An RGB image from a 3 x H x W stack: scaled so the 99.9th percentile maps to 1, sRGB gamma.
void write_rgb_png(const std::string& path, const RealStack& rgb3);
// A single map (e.g. a height map) with a perceptual colormap (viridis-like), min..max.
void write_map_png(const std::string& path, const Map2D& m);

// Atomic text write (temp + rename).
void write_text_atomic(const std::string& path, const std::string& text);

}  // namespace qdo
