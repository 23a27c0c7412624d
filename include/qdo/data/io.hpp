// Files in and out. The HDF5 layout is a contract (docs/formats.md):
//   designs       /height_m        (N x N, float64, attribute pitch_m)  [+ optional /levels_m]
//   PSF stacks    /psf_sensor      (bands x S x S on the sensor grid, attribute pitch_m) + /wavelengths_nm
//                 (bands); `qdo psf --native` adds /psf_native (bands x N x N on the DOE grid)
//   cubes         /cube            (bands x H x W, float64 in [0,1]) + /wavelengths_nm
//   sensor images /rgb             (3 x H x W, float64)
// Every writer writes to "<path>.tmp-<pid>" and renames, so a failure never leaves a
// half-written file. Every reader names the file, the dataset and the problem on failure.
#pragma once
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "qdo/data/io_raw.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

// ---------- HDF5 ----------
// A named array for writing: shape in C order, row-major data.
struct H5Dataset {
  std::string name;                    // absolute path, e.g. "/psf"
  std::vector<std::size_t> shape;
  std::vector<double> data;            // written as float64, or float32 when float32 is set
  std::map<std::string, double> num_attrs;       // numeric attributes
  std::map<std::string, std::string> str_attrs;  // string attributes (e.g. "units")
  // Store as IEEE float32 (half the bytes; ~7 significant digits): for large outputs whose
  // precision is float anyway (PSF stacks of a float32 run). Readers convert back to double.
  bool float32 = false;
  // When set, a dataset of rank >= 2 and at least 1 MiB is stored chunked (one plane of the last
  // two axes per chunk, at most 4 MiB) with HDF5's shuffle + deflate (level 1) filters, the chunks
  // compressed on every core; any HDF5 reader reads it as usual. Pays for data with structure
  // (a 4-level 1024² height map: 8.4 MB -> 1.2 MB); float PSF stacks shrink only ~20 % (their
  // low mantissa bits are noise) for ~0.2 s at the paper preset, so they are compressed only on
  // request (`--compress`; BENCHMARKS "CPU speed").
  bool compress = false;
  // When set, the values are read from *view instead of `data` (which stays empty): a large
  // array the caller keeps alive until h5_write returns, written without a copy.
  const std::vector<double>* view = nullptr;
  const std::vector<double>& values() const { return view ? *view : data; }
  // When set, the values are f32_count floats at f32_view (a float32 device stack mapped on the
  // host, say), written as float32 without any conversion or copy; `data` and `view` stay empty
  // and `float32` must be set. The caller keeps the memory alive until h5_write returns.
  const float* f32_view = nullptr;
  std::size_t f32_count = 0;
  std::size_t size() const { return f32_view ? f32_count : values().size(); }
};

// True when v holds at most max_distinct distinct values (a quantized height map): such data is
// worth H5Dataset::compress (stops counting at max_distinct + 1, so a continuous map costs little).
bool few_distinct_values(const std::vector<double>& v, std::size_t max_distinct = 256);

// Writes all datasets into one new file atomically (temp file + rename). Every value and
// numeric attribute must be finite: NaN or Inf is a NumericalError naming the file and the
// dataset, raised before the file is created; so is a float32 dataset holding a value beyond
// float32's range.
void h5_write(const std::string& path, const std::vector<H5Dataset>& datasets,
              const std::map<std::string, std::string>& root_str_attrs = {});
// The same without the finiteness check: for tests and fuzz seeds that build hostile files.
void h5_write_unchecked(const std::string& path, const std::vector<H5Dataset>& datasets,
                        const std::map<std::string, std::string>& root_str_attrs = {});

// Reads one dataset (any numeric type, converted to double). Throws InputError naming the
// file and dataset if missing, non-numeric, or larger than max_elements.
H5Dataset h5_read(const std::string& path, const std::string& name,
                  std::size_t max_elements = std::size_t(1) << 31);
// Several datasets through one open file: all from the same file even when another process
// renames a new one over `path` meanwhile (a checkpoint read while its run saves the next).
std::vector<H5Dataset> h5_read_many(const std::string& path, const std::vector<std::string>& names,
                                    std::size_t max_elements = std::size_t(1) << 31);
bool h5_has(const std::string& path, const std::string& name);
// The file's root attributes (the provenance qdo writes: "config", "source", "notes", ...): string
// attributes as stored, numeric ones as text. InputError naming the file if it cannot be read.
std::map<std::string, std::string> h5_read_root_attrs(const std::string& path);

// ---------- Contract helpers ----------
struct Design {
  Map2D height_m;                      // N x N glass relief above the base plate, metres
  double pitch_m = 0;
  std::vector<double> levels_m;        // the level table when quantized, else empty
};
void write_design(const std::string& path, const Design& d,
                  const std::map<std::string, std::string>& provenance = {});
Design read_design(const std::string& path);   // checks square, finite, pitch_m > 0

// A sensor-grid PSF stack (planes x S x S, row-major) as /psf_sensor with its pitch, and
// /wavelengths_nm (planes): the layout `qdo psf` writes and read_psf_stack_file reads, without
// provenance. Through write_psf_file (psf_file.hpp: the one psf.h5 writer, with provenance and
// further datasets).
void write_psf(const std::string& path, const RealStack& psf, const std::vector<double>& wavelengths_nm,
               double pitch_m, const std::map<std::string, double>& extra_num_attrs = {});
// A sensor-grid PSF stack file (`qdo psf`, `qdo simulate`, a run folder's psf.h5): /psf_sensor
// (planes x S x S, attribute pitch_m) and /wavelengths_nm (planes). Files from before the name
// was unified hold the stack as /psf (a run folder's psf.h5); it is read when /psf_sensor is
// absent. Checked: rank 3 with square planes, finite values, a finite pitch_m > 0, one finite
// wavelength per plane. An InputError naming the file and the dataset otherwise. The caller checks
// it against a configuration (psf_source.hpp: psf_source_from_file).
struct PsfStackFile {
  RealStack psf_sensor;                // planes x S x S
  std::vector<double> wavelengths_nm;  // planes
  double pitch_m = 0;                  // sensor pixel pitch of the stack, metres
  std::string dataset;                 // the dataset read: "/psf_sensor" or "/psf"
};
PsfStackFile read_psf_stack_file(const std::string& path);
void write_cube(const std::string& path, const RealStack& cube, const std::vector<double>& wavelengths_nm);
// rgb: 3 x H x W as /rgb, with numeric attributes (e.g. clipped_fraction).
void write_rgb(const std::string& path, const RealStack& rgb, const std::map<std::string, double>& attrs = {});

// A hyperspectral cube from HDF5 (/cube, or a named dataset), MATLAB .mat v5 or v7.3
// (libmatio). `key` picks the variable ("" = the only numeric 3-D variable, or /cube).
// `layout` says where the band axis is: "auto" (the axis whose length equals
// expected_bands, preferring the last for .mat), "bhw" or "hwb" (both in reading order:
// for .mat files MATLAB's dims). `scale` divides the values ("auto": 65535 for uint16,
// 4095 for ICVL-like data whose max <= 4095 and key "rad", 1 for floats).
// expected_bands = 0 skips the band check; otherwise a mismatch is an InputError naming
// the file, the key, the shape found and the bands expected.
//
// Band axis: a file may store its band centres in nm beside the cube (HDF5: `wavelengths_nm`,
// `wavelengths` or `bands` in the cube's group or at the root; .mat: a variable of one of
// those names). When it does and `wavelengths_nm` (the configured grid) is given, the file's
// axis decides the band count and must match the grid (conform_band_axis); files without
// an axis (CAVE's) are taken to be on the configured grid. expected_bands, when both are
// given, must equal wavelengths_nm.size().
struct CubeReadOptions {
  std::string key;
  std::string layout = "auto";
  double scale = 0;                    // 0 = auto
  std::size_t expected_bands = 0;
  std::vector<double> wavelengths_nm;  // configured band centres, nm; empty: the axis is not compared
  bool resample_bands = false;         // interpolate a cube on another grid instead of refusing it
};
RealStack read_cube(const std::string& path, const CubeReadOptions& opt = {});

// Names under which a cube file may store its band centres in nm, tried in this order
// (qdo's own files write /wavelengths_nm; ICVL's files carry `bands`).
inline constexpr const char* kBandAxisNames[] = {"wavelengths_nm", "wavelengths", "bands"};
// Tolerance and range of a stored band axis (nm).
constexpr double kBandAxisToleranceNm = 0.5;
constexpr double kBandAxisMinNm = 100, kBandAxisMaxNm = 20000;

// cube: bands x H x W (C order) with file_nm[b] the centre of band b (strictly ascending or
// descending; finite, 100 ... 20000 nm). Returns the cube unchanged when grid_nm is empty or
// when the two grids agree within kBandAxisToleranceNm at every band. Otherwise: an
// InputError naming both grids (`origin` first), or with resample, the cube linearly
// interpolated along wavelength onto grid_nm (output grid.size() x H x W), which must lie in
// the file's range (no extrapolation), with a one-line note on stderr.
RealStack conform_band_axis(const RealStack& cube, const std::vector<double>& file_nm,
                            const std::vector<double>& grid_nm, bool resample, const std::string& origin);

// The radiance rule every scene passes after its format's scale (REFERENCE: radiance relative
// to full scale, in [0, 1]):
//  - a non-finite value, or a value below -kRadianceNegativeTolerance, is an InputError
//    naming `origin`, the count and the minimum;
//  - values in [-kRadianceNegativeTolerance, 0) (noise of a dark-frame subtraction) are set to
//    0, with a note;
//  - a maximum above 1 + kRadianceOverTolerance (HDR or unscaled data) divides the whole cube
//    by that maximum, with a note; a maximum in (1, 1 + tolerance] is clipped to 1.
// cube: any shape, modified in place.
constexpr double kRadianceNegativeTolerance = 0.01;
constexpr double kRadianceOverTolerance = 1e-6;
struct RadianceReport {
  std::size_t negative = 0;  // values that were below 0 (set to 0)
  double min = 0, max = 0;   // before the rule
  double divided_by = 0;     // > 0: the cube was divided by this maximum
};
RadianceReport conform_radiance(RealStack& cube, const std::string& origin);

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
// RFC 4180 quoting: a cell that starts with '"' runs to its closing quote ("" is a quote inside;
// commas and line breaks inside belong to the cell). Unquoted cells are trimmed.
CsvTable parse_csv(const std::string& text, const std::string& origin);
CsvTable read_csv(const std::string& path);

// Writing. csv_field quotes a cell when it must be (a comma, quote or line break inside, blanks
// at either end, or a leading '#', which the reader would take for a comment), doubling quotes;
// parse_csv gives the value back. csv_number formats with %.<digits>g.
std::string csv_field(const std::string& value);
std::string csv_number(double value, int significant_digits = 6);
// A CSV text built row by row: every row has the header's column count (Error otherwise: a
// programming slip, not input) and every cell goes through csv_field. Every CSV qdo writes
// (metrics.csv, table1/2.csv, sweep.csv, tolerance.csv) is made with it.
class CsvText {
 public:
  explicit CsvText(std::vector<std::string> header);
  CsvText& row(const std::vector<std::string>& cells);
  const std::string& str() const { return text_; }

 private:
  std::size_t columns_ = 0;
  std::string text_;
};

// ---------- PNG figures ----------
// 8-bit grayscale (channels = 1) or RGB (channels = 3) image, row-major, interleaved.
void write_png(const std::string& path, std::size_t width, std::size_t height, int channels,
               const std::vector<unsigned char>& pixels);
// A raw frame as a 16-bit grayscale PNG (rows x cols code values in DN, row-major), read and
// written unchanged (a 16-bit file without gAMA, or with gamma 1, is linear). Reading refuses an
// 8-bit or colour file, naming it.
Map2D read_png16_gray(const std::string& path);
// Values must be integers in [0, 65535] (an InputError naming the file otherwise).
void write_png16_gray(const std::string& path, const Map2D& dn);
// A capture as a 16-bit PNG: grayscale (a raw mosaic: 1 x H x W) or RGB (3 x H x W, planes R, G,
// B), code values in DN unchanged. An 8-bit file or one with alpha is refused, naming the file.
RealStack read_png16(const std::string& path);
// dn3: 3 x H x W integer code values in [0, 65535] (an InputError naming the file otherwise).
void write_png16_rgb(const std::string& path, const RealStack& dn3);
// A capture as a 16-bit TIFF (libtiff): 1 (grayscale, a raw mosaic) or 3 (RGB) unsigned 16-bit
// samples per pixel, interleaved or in separate planes, strips or tiles, any compression libtiff
// reads; code values unchanged. Another bit depth, signed or float samples, alpha, a palette or a
// file that is no TIFF is refused, naming the file. write_tiff16: 1 or 3 planes of integer code
// values in [0, 65535], uncompressed strips (written, then renamed).
RealStack read_tiff16(const std::string& path);
void write_tiff16(const std::string& path, const RealStack& dn);
bool is_tiff_path(const std::string& path);  // extension .tif or .tiff (any case)
// What a capture file says about itself beyond its codes: for a camera raw file, its metadata.
struct CaptureMeta {
  bool camera_raw = false;
  CameraRawInfo raw;  // when camera_raw
};
// A 16-bit capture by its extension: .png (read_png16), .tif / .tiff (read_tiff16), or a camera
// raw file (.dng, .nef, .cr2, ...: read_camera_raw, the Bayer mosaic as stored, 1 x H x W); any
// other extension is refused, naming the file. planes x H x W code values in DN.
RealStack read_capture16(const std::string& path, CaptureMeta* meta = nullptr);
// A camera raw file's metadata against the configuration (cfa as config's JSON names it: "none",
// "rggb", ...; black level and white level in DN): an InputError naming the file, both values and
// the setting to change when the mosaic layout or the black level differ, or the file's white level
// lies above the configuration's. Nothing for other files.
void check_camera_raw(const CaptureMeta& meta, const std::string& config_cfa, double black_level_dn, double white_level_dn,
                      const std::string& path);
// The frames of a folder (calibrate's frames and darks, reconstruct's darks): its .png, .tif,
// .tiff and camera raw files (is_camera_raw_path) in any case of the extension, sorted; a folder
// that is none, or holds no frame, is refused naming `argument`.
std::vector<std::string> capture_files(const std::string& dir, const std::string& argument);
// An RGB image from a 3 x H x W stack: scaled so the 99.9th percentile maps to 1, sRGB gamma.
void write_rgb_png(const std::string& path, const RealStack& rgb3);

// Atomic text write (temp + rename).
void write_text_atomic(const std::string& path, const std::string& text);

// ---------- Output staging: a failed command leaves no output set ----------
// Every qdo writer writes "<path>.tmp-<pid>" and then calls commit_output. While an
// OutputStage with defer_files is alive, commit_output only records the file: all are renamed
// into place together by commit(), and a stage destroyed without commit (an exception, a
// non-zero exit) removes them, so a failed command leaves none of its outputs and never half
// of a set (an older file of the same name stays as it was). Without defer_files (long,
// resumable commands: design, sweep, demo) files are renamed at once. Either way, the folders
// make_output_dir created for the command are removed on failure while they are empty.
// One stage at a time; the CLI opens one per command.
class OutputStage {
 public:
  explicit OutputStage(bool defer_files);
  ~OutputStage();
  OutputStage(const OutputStage&) = delete;
  OutputStage& operator=(const OutputStage&) = delete;
  void commit();  // renames every staged file into place; the created folders stay

 private:
  friend void abandon_output_stage();
  void discard();  // what the destructor does when not committed (and abandon_output_stage)
  friend void commit_output(const std::string& tmp, const std::string& path);
  friend std::string readable_output(const std::string& path);
  friend void make_output_dir(const std::string& dir, const std::string& argument);
  bool defer_files_;
  bool committed_ = false;
  std::vector<std::pair<std::string, std::string>> files_;  // (temporary name, final name)
  std::vector<std::string> dirs_;                           // created, outermost first
  std::vector<std::string> markers_;                        // output markers claim_output_dir wrote
  friend void claim_output_dir(const std::string&, const std::string&, const std::string&, bool);
};
// What a command interrupted by SIGINT, SIGTERM or SIGHUP leaves: the active stage discarded as
// on a failure (its staged files, its "<name>.tmp-<pid>" files in the folders it wrote to, its
// marker in a folder holding nothing else, the folders it created while empty), from the CLI's
// signal thread; nothing happens without an active stage or after commit. A resumable run's
// folder (checkpoints, logs) is kept: it is not empty.
void abandon_output_stage();
// SIGINT, SIGTERM and SIGHUP blocked in every thread and taken by one thread of its own, which
// abandons the output stage (abandon_output_stage) and then dies of the same signal (exit status
// 128 + signal for the shell). Call it before any other thread exists (the qdo tool's main), so
// that every thread inherits the mask.
void abandon_outputs_on_termination_signals();
// Blocks for good once abandon_output_stage has run (the signal then ends the process): called
// where an output write starts (AtomicFile) or ends (commit_output, the checkpoint's renames).
void wait_if_abandoned();
// Moves a finished temporary file onto path, or records it in the active deferring stage.
void commit_output(const std::string& tmp, const std::string& path);
// The name under which an output written in this command can be read back now: its
// temporary name while staged, else path.
std::string readable_output(const std::string& path);
// create_directories(dir), recorded in the active stage; an InputError naming `argument`
// (e.g. "--out") when it cannot be created.
void make_output_dir(const std::string& dir, const std::string& argument = "--out");

// The rule every command's output folder follows. A folder that does not exist or is empty is
// made the command's: created, and marked with the file kOutputMarker naming the command. One
// whose marker names the same command is the command's own (its rerun, resume and replace
// rules apply). Anything else that holds an entry (a folder qdo did not make, one another
// command made, an unreadable marker) is refused with an InputError naming `argument`, the
// folder, up to five of its entries and the way out, unless into_existing (--into-existing):
// then the folder is marked and written into. Call before any work. On a failed command the
// marker goes again when the folder holds nothing else (OutputStage).
inline constexpr const char* kOutputMarker = ".qdo-out";
void claim_output_dir(const std::string& dir, const std::string& argument, const std::string& command, bool into_existing);

}  // namespace qdo
