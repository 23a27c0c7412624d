// Summary numbers of one PSF plane, for tables and figures of PSFs over object points: the peak,
// the intensity-weighted centroid and the radius around it that holds a fraction of the energy.
#pragma once
#include <cstddef>

namespace qdo {

struct PsfPlaneMetrics {
  double sum = 0;             // the plane's energy (1 for a PSF wholly inside the window)
  double peak = 0;            // the largest sample
  double centroid_x_m = 0;    // intensity-weighted centroid, metres from the window centre (S/2, S/2),
  double centroid_y_m = 0;    // x along columns, y along rows
  double ee80_radius_m = 0;   // radius around the centroid holding 80 % of the plane's energy
};

// plane: rows x cols samples (row-major) at pitch_m. Negative samples count as 0. An all-zero plane
// gives zeros.
PsfPlaneMetrics psf_plane_metrics(const double* plane, std::size_t rows, std::size_t cols, double pitch_m);

// Radius (metres) around (cx_m, cy_m), measured from the window centre, within which `fraction` of
// the plane's energy lies: sample centres sorted by distance, linearly interpolated between them.
double encircled_radius_m(const double* plane, std::size_t rows, std::size_t cols, double pitch_m, double cx_m, double cy_m,
                          double fraction);

}  // namespace qdo
