// Step 7 of qdo calibrate (calibrate.hpp: choose_centre): the one centre every band's S x S
// window shares, by CalibrationOptions::centre.
#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "qdo/physics/calibrate.hpp"
#include "calibrate_internal.hpp"
#include "qdo/runtime/strprintf.hpp"

namespace qdo {
namespace {

using calibrate_detail::median_of;

// The light's centroid (frame px, unrounded): of the sum over bands of each band's unit-sum image
// with values below 3 x its noise set to 0, within the S x S window around the sum's brightest
// pixel, then around that centroid once more (noise far from the point stays out).
void light_centroid(const std::vector<Map2D>& signal_dn, const std::vector<Map2D>& noise_scale,
                    const std::vector<double>& noise_dn, std::size_t s, double& py, double& px) {
  const std::size_t rows = signal_dn.front().rows, cols = signal_dn.front().cols;
  Map2D acc(rows, cols);
  for (std::size_t b = 0; b < signal_dn.size(); ++b) {
    const double med = median_of(signal_dn[b].data), thr = 3 * noise_dn[b];
    std::vector<double> lit(acc.data.size());
    double tot = 0;
    for (std::size_t i = 0; i < lit.size(); ++i) {
      const double v = signal_dn[b].data[i] - med;
      tot += lit[i] = v > thr * noise_scale[b].data[i] ? v : 0;
    }
    if (tot <= 0) continue;
    for (std::size_t i = 0; i < acc.data.size(); ++i) acc.data[i] += lit[i] / tot;
  }
  const std::size_t at = std::size_t(std::max_element(acc.data.begin(), acc.data.end()) - acc.data.begin());
  py = double(at / cols);
  px = double(at % cols);
  for (int pass = 0; pass < 2; ++pass) {
    double sy = 0, sx = 0, st = 0;
    const double half = double(s) / 2;
    for (std::size_t y = 0; y < rows; ++y)
      for (std::size_t x = 0; x < cols; ++x) {
        if (std::abs(double(y) - py) > half || std::abs(double(x) - px) > half) continue;
        sy += acc(y, x) * double(y);
        sx += acc(y, x) * double(x);
        st += acc(y, x);
      }
    if (st > 0) py = sy / st, px = sx / st;
  }
}

}  // namespace

CentreChoice choose_centre(const std::vector<Map2D>& signal_dn, const std::vector<Map2D>& noise_scale,
                           const std::vector<double>& noise_dn, std::size_t s, const CalibrationOptions& opt) {
  CentreChoice c;
  const std::size_t rows = signal_dn.front().rows, cols = signal_dn.front().cols;
  const long frame_cy = long(rows / 2), frame_cx = long(cols / 2);
  switch (opt.centre) {
    case CentreRule::given:
      c.row = opt.centre_row;
      c.col = opt.centre_col;
      c.rule = "given";
      return c;
    case CentreRule::frame:
      c.row = frame_cy;
      c.col = frame_cx;
      c.rule = "frame centre";
      return c;
    case CentreRule::automatic:
    case CentreRule::centroid:
      break;
  }
  double py = 0, px = 0;
  light_centroid(signal_dn, noise_scale, noise_dn, s, py, px);
  c.row = std::lround(py);
  c.col = std::lround(px);
  c.rule = "centroid";
  if (opt.centre == CentreRule::centroid) return c;
  const double away = std::hypot(py - double(frame_cy), px - double(frame_cx));
  const std::string where = strprintf("the light's centroid (%.2f, %.2f) lies %.2f px from the frame's centre (%ld, %ld)", py, px,
                                      away, frame_cy, frame_cx);
  if (away <= kFrameCentreReachPx) {
    c.row = frame_cy;
    c.col = frame_cx;
    c.rule = "frame centre (automatic: " + where + ", within " + strprintf("%g", kFrameCentreReachPx) + " px)";
  } else {
    c.rule = "centroid (automatic: " + where + ", more than " + strprintf("%g", kFrameCentreReachPx) + " px)";
    c.note = "centre: " + where + ", so the window is centred on the centroid; a DOE's centroid lies a pixel "
             "or two from its optical axis, and the stack (and every cube reconstructed with it) is registered "
             "to the centroid: give --centre ROW,COL at the axis's pixel where it is known";
  }
  return c;
}

}  // namespace qdo
