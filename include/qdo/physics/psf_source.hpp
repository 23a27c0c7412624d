// Where a spectral PSF stack comes from: the seam between the optics that make a PSF and every
// stage that consumes one (the camera, the design loop, `qdo eval`, the test-set evaluation, the
// Python package). A PsfSource yields the sensor-grid stack on the device and, where it has
// parameters, takes the vector-Jacobian product back to them.
//
//   stack: planes x S x S reals of precision(), row-major, plane p = band p (a batched simulator
//          has designs x points x bands planes, design-major then point-major: plane
//          (d * points + q) * bands + b, points = config().point_count(), the object points of
//          config().points()), S = config().sensor_size_px(), the optical axis at (S/2, S/2) for
//          every point (an off-axis point's PSF lies near its chief-ray image (-z tan θx, -z tan θy)),
//          each plane summing to 1 (fraction of the band energy reaching the window, per sensor pixel).
//
// Implementations: Simulator (the 2-D path: parameters = the N x N height map, metres, row-major;
// a HeightMapPsfSource),
// RadialEngine (the radial path: parameters = the N/2 ring heights, metres, from the centre out)
// and StackPsfSource (a fixed stack, e.g. read from a file: no parameters, no gradient).
#pragma once
#include <CL/opencl.hpp>

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

class PsfSource {
 public:
  virtual ~PsfSource() = default;

  virtual Runtime& runtime() const = 0;
  virtual const SystemConfig& config() const = 0;
  virtual Precision precision() const = 0;
  // S: the edge of one plane of the sensor-grid stack.
  virtual std::size_t sensor_size() const = 0;
  // Planes of the stack: config().bands for every source of one design and one object point;
  // points x bands for a Simulator whose configuration lists object points.
  virtual std::size_t psf_planes() const = 0;
  // Whether psf_sensor_buffer() holds a stack (a simulator before its first compute_psf() has none).
  virtual bool psf_ready() const = 0;
  // The device stack (layout above), valid until the source changes it; psf_generation() changes
  // with every new stack, so consumers that cache something derived from it (OTFs, crops) know
  // when to rebuild.
  virtual const cl::Buffer& psf_sensor_buffer() const = 0;
  virtual std::uint64_t psf_generation() const = 0;
  // A host copy of the stack (planes x S x S, double).
  virtual RealStack psf_sensor() const = 0;

  // Number of the source's own parameters (0: a fixed stack).
  virtual std::size_t parameter_count() const = 0;
  // dL/dparameters (parameter_count() values, the layout the implementation documents) for a
  // gradient dL/dstack on the device (planes x S x S reals of precision(), row-major; read, not
  // modified). An Error for a source without parameters or before a stack exists.
  virtual std::vector<double> parameter_vjp(const cl::Buffer& g_psf_sensor) = 0;

  // One line for reports and errors: "simulated (2-D, N = 512)", "file 'x/psf.h5'".
  virtual std::string describe() const = 0;
};

// A PSF source whose parameters are an N x N height map (metres, row-major, N = config().n): what
// the design loop (Designer, design.hpp) drives. Implemented by Simulator.
class HeightMapPsfSource : public PsfSource {
 public:
  // Uploads the heights (N x N, finite, within [0, 2 h_max]; InputError otherwise).
  virtual void set_heights(const Map2D& height_m) = 0;
  // Makes the stack of the current heights (psf_generation() changes).
  virtual void compute_psf() = 0;
  // dL/dH (N x N, per metre) at the current heights for dL/dstack (planes x S x S), from the host
  // or from the device (a buffer in psf_sensor_buffer()'s layout, read, not modified).
  virtual Map2D psf_sensor_vjp(const RealStack& g_psf_sensor) = 0;
  virtual Map2D psf_sensor_vjp(const cl::Buffer& g_psf_sensor) = 0;
  std::size_t parameter_count() const override { return config().n * config().n; }
  std::vector<double> parameter_vjp(const cl::Buffer& g_psf_sensor) override { return psf_sensor_vjp(g_psf_sensor).data; }
};

// A fixed stack held on the device: a PSF measured on a built camera, computed elsewhere or read
// from a file written by `qdo psf` (read_psf_stack_file, io.hpp). No parameters.
class StackPsfSource final : public PsfSource {
 public:
  // psf_sensor: config().bands x S x S (S = cfg.sensor_size_px()), finite, >= 0, each band
  // summing to 1 within 1e-4 (as `qdo psf` writes it; a float32 file sums to 1 within its
  // rounding). An InputError naming `origin`, the shape found and the one the configuration needs,
  // before any device work. cfg is validated; the precision is checked against the device.
  StackPsfSource(Runtime& rt, const SystemConfig& cfg, Precision p, const RealStack& psf_sensor, std::string origin);
  // Replaces the stack (same checks); psf_generation() changes.
  void set(const RealStack& psf_sensor);

  Runtime& runtime() const override { return rt_; }
  const SystemConfig& config() const override { return cfg_; }
  Precision precision() const override { return prec_; }
  std::size_t sensor_size() const override { return s_; }
  std::size_t psf_planes() const override { return cfg_.bands; }
  bool psf_ready() const override { return true; }
  const cl::Buffer& psf_sensor_buffer() const override { return psf_; }
  std::uint64_t psf_generation() const override { return generation_; }
  RealStack psf_sensor() const override { return host_; }
  std::size_t parameter_count() const override { return 0; }
  std::vector<double> parameter_vjp(const cl::Buffer& g_psf_sensor) override;
  std::string describe() const override { return origin_; }

 private:
  Runtime& rt_;
  SystemConfig cfg_;
  Precision prec_;
  std::size_t s_ = 0;
  std::string origin_;
  RealStack host_;
  cl::Buffer psf_;
  std::uint64_t generation_ = 0;
};

// Checks a stack against a configuration (shape bands x S x S, finite, >= 0, bands summing to 1
// within `sum_tolerance`): an InputError "<origin>: ..." naming what was found and what the
// configuration needs. Used by StackPsfSource and by the file reader's callers.
void check_psf_stack(const RealStack& psf_sensor, const SystemConfig& cfg, const std::string& origin,
                     double sum_tolerance = 1e-4);

// The stack of a PSF file (read_psf_stack_file, io.hpp: `qdo psf`'s psf.h5) as a source for `cfg`:
// its bands (wavelengths within kBandAxisToleranceNm), its S x S size and its pixel pitch must be
// the configuration's; otherwise an InputError "argument '<argument>' = PATH: the file holds ...;
// the configuration's sensor grid is ..." naming both. Checked before any device work.
// The same check without a device: the file's stack (bands x S x S), for commands that check every
// input before they start one.
RealStack read_psf_stack_for(const SystemConfig& cfg, const std::string& path, const std::string& argument = "--psf");
std::unique_ptr<StackPsfSource> psf_source_from_file(Runtime& rt, const SystemConfig& cfg, Precision p,
                                                     const std::string& path, const std::string& argument = "--psf");

}  // namespace qdo
