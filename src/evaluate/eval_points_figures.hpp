// The figures of qdo eval-points (private to src/design/): quality against object distance and
// field angle (two panels each) and the PSF of every point at the middle band.
#pragma once
#include <filesystem>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/evaluate/eval_points.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

// OUT/quality_vs_distance.png, quality_vs_angle.png, psf_vs_distance.png, psf_vs_angle.png (each
// with its .svg). dpsf: one bands x S x S stack per res.distances row; apsf: per res.angles row.
void write_points_figures(const std::filesystem::path& out, const EvalPointsResult& res, const EvalPointsOptions& o,
                          const SystemConfig& cfg, const std::vector<RealStack>& dpsf, const std::vector<RealStack>& apsf);

}  // namespace qdo
