// SensorStage (include/qdo/physics/sensor.hpp): the launcher of kernels/sensor.cl.
#include "qdo/physics/sensor.hpp"

#include <vector>

#include "physics/device_buffers.hpp"
#include "qdo/physics/optics.hpp"

namespace qdo {

SensorStage::SensorStage(Runtime& rt, const SystemConfig& cfg, Precision p)
    : rt_(rt), cfg_(cfg), prec_(p), srf_(sensor_response(cfg)) {
  k_sensor_ = rt_.kernel("sensor.cl", "sensor_integrate", p);
  std::vector<double> srf(srf_.size());
  for (Eigen::Index c = 0; c < 3; ++c)
    for (Eigen::Index b = 0; b < srf_.cols(); ++b) srf[static_cast<std::size_t>(c * srf_.cols() + b)] = srf_(c, b);
  srf_buf_ = detail::upload_real(rt_, srf, prec_);
}

void SensorStage::run(const cl::Buffer& cube, cl::Buffer& rgb, std::size_t hw, std::size_t scenes) {
  rt_.launch_1d(k_sensor_, scenes * 3 * hw, prec_, cube, srf_buf_, rgb, int(hw), int(cfg_.bands),
                Real{cfg_.read_noise_sigma}, Real{cfg_.full_well_photons}, cl_uint(cfg_.noise_seed & 0xffffffffull),
                cl_uint(cfg_.noise_seed >> 32), int(scenes));
}

}  // namespace qdo
