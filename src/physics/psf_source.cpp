#include "qdo/physics/psf_source.hpp"

#include <cmath>
#include <utility>

#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"

namespace qdo {

namespace {
std::string shape3(std::size_t a, std::size_t b, std::size_t c) { return to_str(a) + " x " + to_str(b) + " x " + to_str(c); }

std::string band_range(const std::vector<double>& nm) {
  if (nm.empty()) return "no bands";
  return to_str(nm.size()) + " bands, " + to_str(nm.front()) + " ... " + to_str(nm.back()) + " nm";
}
}  // namespace

void check_psf_stack(const RealStack& psf, const SystemConfig& cfg, const std::string& origin, double sum_tolerance) {
  const std::size_t s = cfg.sensor_size_px();
  if (psf.planes != cfg.bands || psf.rows != s || psf.cols != s)
    throw InputError(origin + ": a PSF stack of " + shape3(psf.planes, psf.rows, psf.cols) +
                     "; the configuration's sensor grid needs bands x S x S = " + shape3(cfg.bands, s, s));
  const std::size_t plane = s * s;
  for (std::size_t b = 0; b < psf.planes; ++b) {
    double sum = 0;
    for (std::size_t i = 0; i < plane; ++i) {
      const double v = psf.data[b * plane + i];
      if (!std::isfinite(v) || v < 0)
        throw InputError(origin + ": band " + to_str(b) + " pixel (" + to_str(i / s) + ", " + to_str(i % s) + ") = " +
                         to_str(v) + ": a PSF holds finite values >= 0");
      sum += v;
    }
    if (!(std::fabs(sum - 1.0) <= sum_tolerance))
      throw InputError(origin + ": band " + to_str(b) + " (" + to_str(cfg.wavelengths_nm()[b]) + " nm) sums to " + to_str(sum) +
                       ": each band of a PSF stack sums to 1 within " + to_str(sum_tolerance) +
                       " (fraction of band energy per sensor pixel, as qdo psf writes it)");
  }
}

StackPsfSource::StackPsfSource(Runtime& rt, const SystemConfig& cfg, Precision p, const RealStack& psf_sensor,
                               std::string origin)
    : rt_(rt), cfg_(cfg), prec_(p), origin_(std::move(origin)) {
  cfg_.validate();
  s_ = cfg_.sensor_size_px();
  check_psf_stack(psf_sensor, cfg_, origin_);
  rt_.require(p);
  psf_ = cl::Buffer(rt_.context(), CL_MEM_READ_ONLY, psf_sensor.size() * real_size(p));
  set(psf_sensor);
}

void StackPsfSource::set(const RealStack& psf_sensor) {
  check_psf_stack(psf_sensor, cfg_, origin_);
  rt_.write_reals(psf_, psf_sensor.data.data(), psf_sensor.size(), prec_);
  host_ = psf_sensor;
  ++generation_;
}

std::vector<double> StackPsfSource::parameter_vjp(const cl::Buffer&) {
  throw Error(origin_ + ": a fixed PSF stack has no parameters to take a gradient to");
}

RealStack read_psf_stack_for(const SystemConfig& cfg, const std::string& path, const std::string& argument) {
  PsfStackFile f = read_psf_stack_file(path);
  const std::string origin = "argument '" + argument + "' = " + path;
  const std::size_t s = cfg.sensor_size_px();
  const std::vector<double> grid = cfg.wavelengths_nm();
  const std::string have = "the file holds " + f.dataset + " " + shape3(f.psf_sensor.planes, f.psf_sensor.rows, f.psf_sensor.cols) +
                           " (" + band_range(f.wavelengths_nm) + ") at a pitch of " + to_str(f.pitch_m * 1e6) + " um";
  const std::string need = "the configuration's sensor grid is " + shape3(cfg.bands, s, s) + " (" + band_range(grid) +
                           ") at a pitch of " + to_str(cfg.sensor_pitch_m * 1e6) + " um";
  bool same = f.psf_sensor.planes == cfg.bands && f.psf_sensor.rows == s &&
              std::fabs(f.pitch_m - cfg.sensor_pitch_m) <= 1e-9 * cfg.sensor_pitch_m;
  for (std::size_t b = 0; same && b < grid.size(); ++b)
    same = std::fabs(f.wavelengths_nm[b] - grid[b]) <= kBandAxisToleranceNm;
  if (!same) throw InputError(origin + ": " + have + "; " + need);
  check_psf_stack(f.psf_sensor, cfg, origin);
  return std::move(f.psf_sensor);
}

std::unique_ptr<StackPsfSource> psf_source_from_file(Runtime& rt, const SystemConfig& cfg, Precision p,
                                                     const std::string& path, const std::string& argument) {
  const RealStack psf = read_psf_stack_for(cfg, path, argument);
  return std::make_unique<StackPsfSource>(rt, cfg, p, psf, "PSF file '" + path + "'");
}

}  // namespace qdo
