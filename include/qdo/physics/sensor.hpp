// The RGB sensor on the device (kernels/sensor.cl): per-pixel integration of a band cube with the
// sensor response (Eq. 7) and the reproducible noise of cfg (shot noise at full_well_photons, read
// noise read_noise_sigma, Philox counters from noise_seed). The CPU references are
// ref::sensor_integrate and ref::add_noise (cpu_reference.hpp).
#pragma once
#include <CL/opencl.hpp>

#include <Eigen/Dense>

#include <cstddef>

#include "qdo/data/config.hpp"
#include "qdo/runtime/runtime.hpp"

namespace qdo {

class SensorStage {
 public:
  // One per (configuration, precision); the configuration is taken as valid. Uploads
  // sensor_response(cfg).
  SensorStage(Runtime& rt, const SystemConfig& cfg, Precision p);
  SensorStage(const SensorStage&) = delete;
  SensorStage& operator=(const SensorStage&) = delete;

  // cube (scenes x bands x hw reals of the precision, row-major) -> rgb (scenes x 3 x hw):
  // rgb[k][c][p] = sum_b srf(c, b) cube[k][b][p], then noise with counter (k * hw + p) * 3 + c.
  void run(const cl::Buffer& cube, cl::Buffer& rgb, std::size_t hw, std::size_t scenes);
  // The sensor response, 3 x bands, rows normalised to unit sum.
  const Eigen::MatrixXd& srf() const { return srf_; }

 private:
  Runtime& rt_;
  SystemConfig cfg_;
  Precision prec_;
  Eigen::MatrixXd srf_;
  cl::Kernel k_sensor_;
  cl::Buffer srf_buf_;  // 3 x bands reals, row-major
};

}  // namespace qdo
