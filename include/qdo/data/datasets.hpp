// Training scenes: readers for the public hyperspectral sets (REFERENCE §3), a scene index
// with a scene-level train/val/test split, patches and dihedral augmentation, a seeded patch
// sampler with an LRU cache of decoded cubes, and a synthetic scene generator built from
// measured reflectance and illuminant tables embedded in the binary (so training needs no
// download).
//
// Every cube is a RealStack bands x H x W (row-major), values normally in [0, 1].
// Every error is an InputError naming the file (or folder) and the problem.
#pragma once
#include <cstddef>
#include <cstdint>
#include <list>
#include <memory>
#include <random>
#include <string>
#include <unordered_map>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

// =========================================================================================
// Readers
// =========================================================================================
//
// format      what                                              key      scale
// "icvl"      ICVL .mat (v7.3/HDF5; MATLAB dims H x W x 31)      rad      ÷ 4095
// "cave"      CAVE .mat (the only numeric 3-D variable), or a   (any)    integer data ÷ the type's max
//             folder of PNG bands (then as "cave-png")                   (uint16: 65535); float data
//                                                                         with values > 1 ÷ 65535
// "cave-png"  a folder of one grayscale PNG per band, sorted by  -        16-bit ÷ 65535, 8-bit ÷ 255
//             the last number in the file name (x_ms_01.png ..
//             x_ms_31.png; x_1.png .. x_31.png sorts numerically)
// "harvard"   Harvard .mat (MATLAB dims H x W x 31)              ref      ÷ the cube's own max: the
//             original `ref` is not normalised to [0, 1] (values are calibrated reflectance with
//             an arbitrary scale), so each cube is scaled so its maximum is 1
// "kaist"     KAIST .mat (MATLAB dims H x W x 31)                HSI      integer ÷ the type's max;
//                                                                         float as is, ÷ the cube's
//                                                                         max when that exceeds 1
// "h5"        the project's HDF5 contract file (/cube, bands x H x W)     as read_cube ("auto")
// "auto"      a folder -> "cave-png"; a MATLAB file -> by its variables (rad -> icvl, ref ->
//             harvard, HSI -> kaist, else cave); another HDF5 file -> "h5" when it has /cube,
//             "icvl" when it has /rad (C order, bands first)
//
// .mat band axis: MATLAB's last axis when its length is expected_bands, else the first
// (read_cube's "auto" layout). PNG decoding uses libpng's simplified API: a 16-bit file is
// taken as linear (no gamma change when the file has no gAMA chunk or gAMA 1.0, which is
// how CAVE's files are written). Colour (RGB/RGBA/palette) and gray+alpha files are decoded
// to RGBA (8-bit or 16-bit, as the file) and accepted when every pixel is grey (R = G = B)
// and opaque (alpha at full scale), as in the one CAVE scene stored that way; otherwise an
// InputError names the file and the first coloured or transparent pixel.

// The resolved format of `path` (never "auto"); InputError naming the file when unknown.
std::string detect_scene_format(const std::string& path);

// One scene as bands x H x W. expected_bands = 0 skips the band check (for PNG folders it
// then accepts any number of files); otherwise a mismatch is an InputError. With
// wavelengths_nm (the configured band centres; size expected_bands), a band axis stored in
// the file must match it (read_cube, conform_band_axis: refused naming both grids, or
// interpolated with resample_bands). Every scene then passes conform_radiance (io.hpp):
// strongly negative values are refused, slightly negative ones set to 0, a maximum above 1
// divides the cube by it; each with a note.
RealStack load_scene(const std::string& path, const std::string& format = "auto", std::size_t expected_bands = 31,
                     const std::vector<double>& wavelengths_nm = {}, bool resample_bands = false);

// The PNG band files of a folder, sorted by band number (the last run of digits in each
// file stem); InputError for a file without a number or a repeated number.
std::vector<std::string> png_band_files(const std::string& dir);
// A folder of grayscale PNG bands as bands x H x W (see "cave-png" above).
RealStack read_png_band_folder(const std::string& dir, std::size_t expected_bands = 31);

struct SceneShape {
  std::size_t bands = 0, rows = 0, cols = 0;  // the cube load_scene returns: bands x rows x cols
};
bool operator==(const SceneShape& a, const SceneShape& b);

// The shape load_scene would return, from the file headers where possible (MATLAB variable
// info, HDF5 dataspace, PNG headers) and by reading the scene otherwise.
// With wavelengths_nm, a file that stores a band axis is read whole, so a grid that
// differs is refused here, when the index is built, rather than when the scene is first used.
SceneShape probe_scene(const std::string& path, const std::string& format = "auto", std::size_t expected_bands = 31,
                       const std::vector<double>& wavelengths_nm = {});

// Training data must carry information: InputError naming `path` when every value of the
// cube is the same (all zero, or constant). Such a scene gives the spectral prior nothing
// (an all-zero one makes every reconstruction score perfectly) and is refused when a design
// run loads its training scenes.
void check_training_scene(const RealStack& cube, const std::string& path);

// =========================================================================================
// Scene index and split
// =========================================================================================

struct SceneEntry {
  std::string path;      // a file, a PNG folder, or "synthetic:<k>"
  std::string format;    // resolved: "icvl", "cave", "cave-png", "harvard", "kaist", "h5", "synthetic"
  SceneShape shape;      // read once when the index is built
  std::uint64_t synthetic_seed = 0;  // for "synthetic" entries
};

// Indices into a SceneIndex, each list ascending.
struct SceneSplit {
  std::vector<std::size_t> train, val, test;
};

class SceneIndex {
 public:
  SceneIndex() = default;
  // Scenes under `paths`: files are taken as given; folders are searched recursively for
  // *.mat, *.h5, *.hdf5 files and for folders holding *.png files (one CAVE scene each).
  // Entries are sorted by path (so splits do not depend on directory order) and each
  // scene's shape is probed once here. `format` applies to every entry ("auto" detects per
  // file). InputError when a path is missing, no scene is found, or a scene is unreadable.
  // wavelengths_nm: the configured band centres (size expected_bands), checked against a band
  // axis stored in a scene file (load_scene); empty: not checked.
  explicit SceneIndex(const std::vector<std::string>& paths, const std::string& format = "auto",
                      std::size_t expected_bands = 31, const std::vector<double>& wavelengths_nm = {});

  // `count` synthetic scenes (synthetic_scene below) of size_px x size_px on cfg's band
  // grid; scene k uses a seed derived from (seed, k). Nothing is generated until load().
  static SceneIndex synthetic(const SystemConfig& cfg, std::size_t count, std::size_t size_px, std::uint64_t seed);

  std::size_t size() const { return entries_.size(); }
  const SceneEntry& operator[](std::size_t i) const { return entries_.at(i); }
  const std::vector<SceneEntry>& entries() const { return entries_; }
  std::size_t expected_bands() const { return bands_; }

  // Reads (or generates) scene i; InputError when its shape no longer matches the index.
  RealStack load(std::size_t i) const;

  // Scene-level random split, deterministic by seed: round(n * train_frac) train scenes,
  // round(n * val_frac) validation scenes, the rest test (ICVL's 201 with 0.83 / 0.085 ->
  // 167 / 17 / 17). Requires 0 <= fractions, train_frac + val_frac <= 1.
  SceneSplit split(std::uint64_t seed, double train_frac, double val_frac) const;

 private:
  std::vector<SceneEntry> entries_;
  std::size_t bands_ = 31;
  std::vector<double> wavelengths_nm_;  // configured band centres; empty: the file axis is not checked
  std::shared_ptr<const SystemConfig> synthetic_cfg_;  // for "synthetic" entries
};

// =========================================================================================
// Patches and augmentation
// =========================================================================================

struct PatchOrigin {
  std::size_t y = 0, x = 0;  // top-left corner of a size x size crop
};
bool operator==(const PatchOrigin& a, const PatchOrigin& b);

// Crop starts along one axis of `length`: 0, stride, 2 stride, ... while the crop fits, plus
// length - size when the last one does not reach the end (so the last row/column is always
// covered). InputError when size == 0, stride == 0 or size > length.
std::vector<std::size_t> patch_starts(std::size_t length, std::size_t size, std::size_t stride);
// All crops of a rows x cols image, row-major (y outer, x inner).
std::vector<PatchOrigin> patch_origins(std::size_t rows, std::size_t cols, std::size_t size, std::size_t stride);
// A per_axis x per_axis grid spread evenly from the first to the last possible position
// (starts round(k (L - size) / (per_axis - 1))), row-major.
std::vector<PatchOrigin> grid_origins(std::size_t rows, std::size_t cols, std::size_t size, std::size_t per_axis);

// cube[:, y : y + size, x : x + size] as bands x size x size; InputError when out of range.
RealStack crop_patch(const RealStack& cube, const PatchOrigin& origin, std::size_t size);
// cube[:, row : row + rows, col : col + cols] as bands x rows x cols; InputError when out of range.
RealStack crop_window(const RealStack& cube, std::size_t row, std::size_t col, std::size_t rows, std::size_t cols);
// Overlapping size x size crops at `stride` (patch_origins), row-major order.
std::vector<RealStack> extract_patches(const RealStack& cube, std::size_t size, std::size_t stride);
// The paper's 9 overlapping crops per scene: a 3 x 3 grid_origins grid (first, centred and
// last position along each axis; for ICVL's 1392 x 1300 at 512: rows 0, 440, 880 and
// columns 0, 394, 788). The release's 10th crop (the whole scene resized) is not made here.
std::vector<RealStack> paper_crops(const RealStack& cube, std::size_t size = 512);

// The 8 elements of the dihedral group D4 acting on the spatial axes (all bands alike):
// code = 4 * flip + rot (0..7): first mirror left-right when flip = 1, then rotate by
// rot x 90° counter-clockwise. A rows x cols input gives cols x rows for odd rot.
RealStack augment(const RealStack& cube, int code);
// The code g' with augment(augment(c, g), g') == c.
int augment_inverse(int code);

// =========================================================================================
// Patch sampler
// =========================================================================================

// A least-recently-used cache of decoded cubes, at most `capacity` held at once (memory:
// capacity x bands x H x W x 8 bytes; 4 ICVL cubes are about 1.8 GB).
class CubeCache {
 public:
  explicit CubeCache(std::size_t capacity);
  // The cube of scene i, loading it through index.load(i) on a miss.
  std::shared_ptr<const RealStack> get(const SceneIndex& index, std::size_t i);
  std::size_t loads() const { return loads_; }  // misses so far
  std::size_t held() const { return lru_.size(); }

 private:
  using Item = std::pair<std::size_t, std::shared_ptr<const RealStack>>;
  std::size_t capacity_;
  std::list<Item> lru_;  // most recently used first
  std::unordered_map<std::size_t, std::list<Item>::iterator> where_;
  std::size_t loads_ = 0;
};

struct PatchSamplerOptions {
  std::size_t patch_size = 512;
  std::size_t stride = 0;               // 0: the paper's 3 x 3 grid per scene; else patch_origins
  std::size_t random_per_scene = 0;     // > 0: this many uniformly random crops per scene per epoch instead
  std::size_t batch_size = 4;
  bool augment = true;                  // a uniformly drawn dihedral code per patch
  std::size_t cache_scenes = 4;         // LRU capacity (decoded cubes)
};

// One patch of a plan: scene index, crop origin, dihedral code.
struct PatchRef {
  std::size_t scene = 0;
  PatchOrigin origin;
  int code = 0;
};

// Yields batches of patches (each bands x patch_size x patch_size) from `scenes` of an
// index, deterministic by (seed, options). Each epoch
// shuffles the scenes, then takes them in groups of cache_scenes and shuffles all crops of
// a group together, so every cube is decoded once per epoch while batches still mix
// scenes. Batches are always full and run on across epoch boundaries.
class PatchSampler {
 public:
  PatchSampler(SceneIndex index, std::vector<std::size_t> scenes, const PatchSamplerOptions& opt, std::uint64_t seed);

  std::vector<RealStack> next_batch();
  const std::vector<PatchRef>& last_refs() const { return last_refs_; }  // of the last batch
  std::size_t epoch() const { return epoch_; }                          // epochs started, from 1
  std::size_t patches_per_epoch() const;
  const CubeCache& cache() const { return cache_; }

 private:
  void plan_epoch();
  std::vector<PatchOrigin> origins_for(std::size_t scene, std::mt19937_64& rng) const;

  SceneIndex index_;
  std::vector<std::size_t> scenes_;
  PatchSamplerOptions opt_;
  std::uint64_t seed_;
  CubeCache cache_;
  std::vector<PatchRef> plan_, last_refs_;
  std::size_t next_ = 0, epoch_ = 0;
};

// =========================================================================================
// Synthetic scenes
// =========================================================================================

// A "dead leaves" scene: a textured background plus K = 12..40 random occluding shapes
// (discs and ellipses, rotated rectangles, star-shaped polygons; log-uniform sizes of 3..30%
// of the side) drawn in painter's order with hard edges (no anti-aliasing, so every pixel holds exactly one material). Each material has a
// measured reflectance spectrum (a random table, then a random row, of the embedded
// synthetic_reflectance_files(); values clipped to [0, 1]) and the scene one illuminant
// (a random row of synthetic_illuminant_file(), scaled to max 1 on the band grid). Per
// pixel: cube(b, y, x) = albedo(y, x) * reflectance[label(y, x)][b] * illuminant_spd[b],
// albedo = exposure x global shading gradient x per-shape shading gradient x per-shape
// texture (smooth value noise), in (0, 1], so the cube is in [0, 1].
// Reproducible by seed (std::mt19937_64 and a hash-based noise, no random_device).
// Spectra are linearly interpolated onto cfg.wavelengths_nm(); outside the tables'
// 400..700 nm range is an InputError. size_px must be 1..16384.
struct SyntheticScene {
  RealStack cube;                                // bands x S x S
  std::vector<std::uint32_t> label;              // S x S row-major: 0 background, k = k-th shape
  Map2D albedo;                                  // S x S
  std::vector<std::string> material;             // per label: "<table file>:<row name>"
  std::vector<std::vector<double>> reflectance;  // per label, on the band grid
  std::string illuminant;                        // "<table file>:<name>"
  std::vector<double> illuminant_spd;            // on the band grid, max 1
};
SyntheticScene synthetic_scene_detail(const SystemConfig& cfg, std::size_t size_px, std::uint64_t seed);
RealStack synthetic_scene(const SystemConfig& cfg, std::size_t size_px, std::uint64_t seed);

// The embedded tables (data/ file names) the generator draws from: rows = spectra, a
// "name" column then one column per wavelength in nm.
const std::vector<std::string>& synthetic_reflectance_files();
const std::string& synthetic_illuminant_file();

}  // namespace qdo
