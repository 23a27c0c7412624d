// The problem of a design run: its training scenes and scene prior, the PSF target, and the
// objective of a step (design/problem.hpp), shared by the run loop (design_run.cpp) and gradcheck.
#include "design/problem.hpp"

#include <memory>
#include <random>
#include <utility>

#include "qdo/data/datasets.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/physics/optics.hpp"

namespace qdo {

namespace {

// Training scenes as S x S patches at the sensor pitch (S = sensor PSF size, so the Wiener
// prior, the PSF and the scenes share one grid).
std::vector<RealStack> training_scenes(const DesignRunOptions& o) {
  const std::size_t s = o.cfg.sensor_size_px();
  std::vector<RealStack> out;
  if (o.data.empty()) {
    const SceneIndex idx = SceneIndex::synthetic(o.cfg, o.synthetic_scenes, s, o.design.seed);
    for (std::size_t i = 0; i < idx.size(); ++i) out.push_back(idx.load(i));
    return out;
  }
  const SceneIndex idx(o.data, o.data_format, o.cfg.bands, o.cfg.wavelengths_nm());
  const SceneSplit split = idx.split(o.design.seed, 0.8, 0.1);
  const auto& use = split.train.empty() ? split.test : split.train;
  for (std::size_t i : use) {
    const RealStack cube = idx.load(i);
    check_training_scene(cube, idx[i].path);
    if (cube.rows < s || cube.cols < s)
      reject("data", idx[i].path, "scenes of at least " + to_str(s) + " x " + to_str(s) + " pixels (the sensor PSF size)");
    for (auto& p : extract_patches(cube, s, s / 2)) out.push_back(std::move(p));
  }
  return out;
}

}  // namespace

// The Wiener expected-error objective on the device for this run, when it asks for one
// (objective wiener, wiener_on device) and the device has float64 for the C x C solve; null
// otherwise (the CPU objective then runs).
std::unique_ptr<wiener::DeviceObjective> make_device_objective(Runtime& rt, const DesignRunOptions& o, const Problem& pb) {
  if (o.objective != Objective::Wiener || o.wiener_on != WienerOn::Device) return nullptr;
  if (!rt.has_fp64()) {  // float32 cannot hold σ² next to M's large eigenvalues (kernels/wiener.cl)
    if (!o.quiet)
      std::fprintf(stderr, "qdo: note: %s has no float64; the wiener objective runs on the CPU (double) instead\n",
                   rt.info().name.c_str());
    return nullptr;
  }
  return std::make_unique<wiener::DeviceObjective>(rt, o.precision, pb.srf, pb.prior, o.decoder_noise_sigma,
                                                   o.cfg.sensor_size_px());
}


PsfObjective make_objective(const DesignRunOptions& o, const Problem& pb, long step, wiener::DeviceObjective* dev) {
  if (o.objective == Objective::PsfTarget) return psf_target_objective(pb.target);
  const wiener::Loss loss = o.objective == Objective::Wiener      ? wiener::Loss::Expected
                            : o.objective == Objective::WienerMse ? wiener::Loss::Mse
                                                                  : wiener::Loss::Mae;
  if (loss == wiener::Loss::Expected && dev)
    return [dev](const RealStack& psf, RealStack& grad) {
      wiener::PsfObjective r = dev->expected(psf);
      grad = std::move(r.grad_psf);
      return r.value;
    };
  std::vector<RealStack> batch;
  if (loss != wiener::Loss::Expected) {
    std::mt19937_64 rng(o.design.seed * 1000003ull + std::uint64_t(step));
    for (std::size_t k = 0; k < o.batch; ++k) batch.push_back(pb.scenes[rng() % pb.scenes.size()]);
  }
  const double sigma = o.decoder_noise_sigma;
  const Problem* p = &pb;
  return [p, loss, sigma, batch](const RealStack& psf, RealStack& grad) {
    wiener::PsfObjective r = wiener::objective_psf(loss, psf, p->srf, p->prior, sigma, batch);
    grad = std::move(r.grad_psf);
    return r.value;
  };
}

PointObjective make_point_objective(const DesignRunOptions& o, const Problem& pb, long step, wiener::DeviceObjective* dev) {
  if (o.objective == Objective::PsfTarget) {
    const Problem* p = &pb;
    return [p](std::size_t point, const RealStack& psf, RealStack& grad) {
      if (point >= p->point_targets.size())
        reject("object point", point, "an index below the run's " + to_str(p->point_targets.size()) + " points");
      return p->point_targets[point](psf, grad);
    };
  }
  PsfObjective one = make_objective(o, pb, step, dev);
  return [one](std::size_t, const RealStack& psf, RealStack& grad) { return one(psf, grad); };
}

Problem make_problem(Runtime& rt, const DesignRunOptions& o) {
  Problem pb;
  pb.srf = sensor_response(o.cfg);
  if (o.objective == Objective::PsfTarget) {
    const std::size_t points = o.cfg.point_count();
    const Map2D file_h = o.target.kind == TargetSpec::Kind::File ? read_design(o.target.path).height_m : Map2D();
    for (std::size_t p = 0; p < points; ++p) {
      // One point: the configuration as it is (as before object points); several: point p's.
      const SystemConfig pc = points == 1 ? o.cfg : point_config(o.cfg, p);
      SystemConfig lens_cfg = pc;  // the lens focused for the point's distance
      if (points > 1 && !pc.object_points.empty()) {
        const ObjectPoint pt = pc.object_points[0];
        lens_cfg.object_points.clear();
        lens_cfg.scene_at_infinity = pt.at_infinity();
        if (!pt.at_infinity()) lens_cfg.scene_distance_m = pt.distance_m;
      }
      Simulator sim(rt, pc, o.precision);
      sim.set_heights(o.target.kind == TargetSpec::Kind::Lens ? lens_design(lens_cfg, o.target.wavelength_nm) : file_h);
      sim.compute_psf();
      RealStack t = sim.psf_sensor();
      if (p == 0) pb.target = t;
      pb.point_targets.push_back(psf_target_objective(t));
    }
    return pb;
  }
  if (o.objective == Objective::Network) {  // the network's training scenes; the prior (for Wiener evaluations) from their patches
    pb.joint = load_joint_data(o.cfg, o.data, o.data_format, o.synthetic_scenes, o.design.seed);
    const std::size_t s = o.cfg.sensor_size_px();
    for (const RealStack& c : pb.joint.train)
      for (auto& p : extract_patches(c, s, s / 2)) pb.scenes.push_back(std::move(p));
  } else {
    pb.scenes = training_scenes(o);
  }
  pb.prior = wiener::estimate_prior(pb.scenes, o.prior_bins);
  return pb;
}

std::vector<double> initial_params(const DesignRunOptions& o) {
  const SystemConfig& c = o.cfg;
  const Parameterization kind = o.design.parameterization;
  const std::size_t count = parameter_count(kind, c.n);
  std::vector<double> p(count, 0.0);
  if (o.init.kind == InitSpec::Kind::Flat) return p;
  if (o.init.kind == InitSpec::Kind::Half) {  // w = -1e-4: H = h_max (w + 1) / 2
    for (double& v : p) v = c.h_max_m() * (1.0 - 1e-4) / 2.0;
    return p;
  }
  if (o.init.kind == InitSpec::Kind::Random) {
    std::mt19937_64 rng(o.design.seed + 17);
    std::uniform_real_distribution<double> u(0.0, c.h_max_m());
    for (double& v : p) v = u(rng);
    return p;
  }
  const Map2D lens = lens_design(c, o.init.wavelength_nm);
  const std::size_t h = c.n / 2;
  for (std::size_t k = 0; k < count; ++k) {
    if (kind == Parameterization::Full2D) p[k] = lens.data[k];
    else if (kind == Parameterization::Radial) p[k] = lens(h, h + k);
    else p[k] = lens(h + k / h, h + k % h);
  }
  return p;
}

}  // namespace qdo
