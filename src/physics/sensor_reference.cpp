#include "qdo/physics/sensor_reference.hpp"

#include <cmath>
#include <thread>

#include "qdo/runtime/error.hpp"
#include "qdo/runtime/rng.hpp"

namespace qdo::ref {

RealStack sensor_integrate(const RealStack& blurred, const Eigen::MatrixXd& srf) {
  if (srf.rows() != 3 || static_cast<std::size_t>(srf.cols()) != blurred.planes)
    reject("srf", to_str(srf.rows()) + " x " + to_str(srf.cols()), "3 x bands with bands = " + to_str(blurred.planes));
  const std::size_t hw = blurred.plane_size();
  RealStack rgb(3, blurred.rows, blurred.cols);
  Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>> x(
      blurred.data.data(), static_cast<Eigen::Index>(blurred.planes), static_cast<Eigen::Index>(hw));
  Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>> y(rgb.data.data(), 3,
                                                                                       static_cast<Eigen::Index>(hw));
  y.noalias() = srf * x;
  return rgb;
}

void add_noise(RealStack& rgb, double read_noise_sigma, double full_well_photons, unsigned long long seed,
               std::size_t scene_index) {
  if (!(read_noise_sigma >= 0) || !std::isfinite(read_noise_sigma)) reject("read_noise_sigma", read_noise_sigma, ">= 0, finite");
  if (!(full_well_photons >= 0) || !std::isfinite(full_well_photons)) reject("full_well_photons", full_well_photons, ">= 0, finite");
  if (read_noise_sigma == 0 && full_well_photons == 0) return;
  const std::size_t hw = rgb.plane_size();
  if (full_well_photons == 0) {
    // Read noise alone: each value's draw is independent of the others (counter-based), so the
    // planes' pixels are split between two threads when there are enough of them; the values are
    // those of the loop below, bit for bit.
    const auto add_rows = [&](std::size_t p0, std::size_t p1) {
      for (std::size_t c = 0; c < rgb.planes; ++c) {
        double* plane = rgb.plane(c);
        for (std::size_t p = p0; p < p1; ++p) plane[p] += read_noise_sigma * noise_gaussian(seed, (scene_index * hw + p) * 3 + c);
      }
    };
    constexpr std::size_t kThreadedPixels = 1u << 14;
    if (hw < kThreadedPixels) {
      add_rows(0, hw);
    } else {
      std::thread other(add_rows, hw / 2, hw);
      add_rows(0, hw / 2);
      other.join();
    }
    return;
  }
  for (std::size_t c = 0; c < rgb.planes; ++c)
    for (std::size_t p = 0; p < hw; ++p) {
      const NoiseDraw d = noise_draw(seed, (scene_index * hw + p) * 3 + c);
      double v = rgb.plane(c)[p];
      if (full_well_photons > 0) v = poisson_from(std::fmax(v, 0.0) * full_well_photons, d) / full_well_photons;
      rgb.plane(c)[p] = v + read_noise_sigma * d.gaussian;
    }
}

RealStack sensor_integrate_vjp(const RealStack& g_rgb, const Eigen::MatrixXd& srf) {
  if (g_rgb.planes != 3 || srf.rows() != 3) reject("g_rgb", g_rgb.planes, "3 channels");
  RealStack out(static_cast<std::size_t>(srf.cols()), g_rgb.rows, g_rgb.cols);
  for (std::size_t b = 0; b < out.planes; ++b)
    for (std::size_t p = 0; p < out.plane_size(); ++p) {
      double acc = 0;
      for (std::size_t ch = 0; ch < 3; ++ch) acc += srf(Eigen::Index(ch), Eigen::Index(b)) * g_rgb.plane(ch)[p];
      out.plane(b)[p] = acc;
    }
  return out;
}

}  // namespace qdo::ref
