// Statistics of a sweep over seeds: mean and standard deviation of every cell over
// seeds, and the paper's comparisons as paired differences with 95 % intervals. Pure functions
// on per-scene scores; run_grid writes their tables (sweep.hpp).
#pragma once
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

namespace qdo {

// One test scene's scores in one cell of one seed.
struct SceneScore {
  std::string mode;        // the cell's mode label (e.g. "qdo+a", "do", "qdo+a@resunet:depth=4,root=16")
  int levels = 0;          // 0: full precision
  std::uint64_t seed = 0;
  std::string scene;
  double psnr_db = 0, ssim = 0;
};

// The two-sided 95 % quantile of Student's t with `dof` degrees of freedom (t_{0.975, dof}); dof >= 1.
// Exact table values for dof 1..30, 40, 60, 120 (to 4 significant digits), between them interpolated
// linearly in 1/dof (error below 1e-3), 1.95996 beyond 120 is approached the same way.
double student_t_975(std::size_t dof);

// Mean, sample standard deviation (n - 1) and the half width of the 95 % t interval of `v`.
// sd and half width are NaN for fewer than 2 values; mean is NaN for none.
struct MeanInterval {
  std::size_t n = 0;
  double mean = 0, sd = 0, half_width = 0;
  double lo() const { return mean - half_width; }
  double hi() const { return mean + half_width; }
};
MeanInterval mean_interval(const std::vector<double>& v);

// A cell (mode, levels) over seeds: each seed's value is that seed's cell mean (its `mean` row,
// as the tables of one seed show it), the summary their mean and standard deviation.
struct CellSummary {
  std::string mode;
  int levels = 0;
  MeanInterval psnr_db, ssim, rmse, ergas;
};

// A comparison "a - b" at one level count, paired by seed and test scene.
struct PairedDifference {
  std::string a, b;             // mode labels
  int levels = 0;
  std::size_t seeds = 0;        // seeds with both cells
  MeanInterval psnr_db;         // over the (seed, scene) pairs: psnr(a) - psnr(b)
  MeanInterval ssim;
  MeanInterval psnr_db_seeds;   // over seeds of each seed's mean difference (dof = seeds - 1): the
                                // interval that also holds when scenes within a seed are correlated
};

// Every (a, b) of `comparisons` at every level count where both cells exist for at least one seed.
// Pairs are matched by (seed, scene); a scene missing from one side is left out of that pair.
std::vector<PairedDifference> paired_differences(const std::vector<SceneScore>& scores,
                                                 const std::vector<std::pair<std::string, std::string>>& comparisons);

// A difference's label: "L4  qdo+a − do  (9 pairs, 3 seeds)" (a decoder spec both sides share
// written once).
std::string difference_label(const PairedDifference& d);
// The figure of the differences (figure.hpp: PNG and SVG): one legend entry per difference, its
// mean and 95 % interval over the (seed, scene) pairs at x = 1, 2, ... in the order given, the
// seed-level intervals beside them as one more series, and a dashed line at 0 dB.
void write_difference_figure(const std::string& png_path, const std::vector<PairedDifference>& diffs);

}  // namespace qdo
