// qdo psf's work from its options (psf_outputs.hpp): the device started during the inputs, the
// stack computed once, the files written from the mapped float32 stack.
#include "qdo/design/psf_outputs.hpp"

#include <chrono>
#include <future>
#include <memory>

#include "qdo/design/option_inputs.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/runtime/strprintf.hpp"
#include "qdo/runtime/util.hpp"

namespace qdo {

bool save_native_from_option(const std::string& save) {
  bool native = false;
  for (const auto& s : split_items(save)) {
    if (s == "native")
      native = true;
    else
      reject("--save", s, "a comma-separated list of: native");
  }
  return native;
}

std::string psf_outputs_from_options(const TextOptions& a, const std::function<std::string()>& claim_dir) {
  const auto t_cmd = std::chrono::steady_clock::now();
  (void)save_native_from_option(a.get("save"));  // validated before any work
  // Several object points (the configuration's object_points, or --object-distances x
  // --field-angles) are one batched pass: points x bands planes.
  SystemConfig cfg = config_from_options(a, true);
  object_points_from_options(a, cfg);
  const Precision p = precision_from_string(a.get("precision", "f32"));
  // The device (context, kernels from the disk cache, FFT plans) starts on a second thread while
  // this one makes the design's heights and the output folder; an error in those inputs is
  // reported first (the device's own error only when the inputs are good). Nothing in the
  // device start touches HDF5, which is not thread-safe here.
  struct Started {
    std::unique_ptr<Runtime> rt;
    std::unique_ptr<Simulator> sim;
    double device_s = 0, setup_s = 0;
  };
  auto starting = std::async(std::launch::async, [&cfg, p, device = a.get("device")] {
    Started st;
    const auto t_dev = std::chrono::steady_clock::now();
    st.rt = std::make_unique<Runtime>(device);
    st.device_s = seconds_since(t_dev);
    const auto t0 = std::chrono::steady_clock::now();
    st.sim = std::make_unique<Simulator>(*st.rt, cfg, p);
    st.setup_s = seconds_since(t0);
    return st;
  });
  Map2D h;
  std::string dir;
  try {
    h = design_heights_from_options(cfg, a);
    dir = claim_dir();
  } catch (...) {
    starting.wait();
    throw;
  }
  const double inputs_s = seconds_since(t_cmd);
  Started st = starting.get();
  Runtime& rt = *st.rt;
  Simulator& sim = *st.sim;
  sim.set_keep_field(false);  // no adjoint follows (Simulator::set_keep_field)
  sim.set_heights(h);
  const auto t1 = std::chrono::steady_clock::now();
  sim.compute_psf();
  rt.queue().finish();
  const double psf_seconds = seconds_since(t1);
  // float32: the files are written from the device buffer mapped on the host (on a CPU device the
  // buffer itself); float64: read back into a host stack.
  const auto t_read = std::chrono::steady_clock::now();
  const std::size_t s = sim.sensor_size(), count = cfg.point_count() * cfg.bands * s * s;
  std::unique_ptr<MappedBuffer> mapped;
  RealStack host;
  std::unique_ptr<SensorStack> psf_s;
  if (p == Precision::F32) {
    mapped = std::make_unique<MappedBuffer>(rt.queue(), sim.psf_sensor_buffer(), CL_MAP_READ, count * sizeof(float));
    psf_s = std::make_unique<SensorStack>(cfg.point_count() * cfg.bands, s, s, mapped->as<const float>());
  } else {
    host = sim.psf_sensor();
    psf_s = std::make_unique<SensorStack>(host);
  }
  const double read_s = seconds_since(t_read);
  const auto t_write = std::chrono::steady_clock::now();
  write_concurrently(
      [&] {
        write_psf_h5(sim, *psf_s, h, dir, a.get("design"), save_native_from_option(a.get("save")), a.has("compress"));
        if (cfg.point_count() > 1) write_points_csv(cfg, psf_point_summaries(cfg, *psf_s), dir + "/points.csv");
      },
      [&] { write_psf_figures(cfg, *psf_s, h, dir); });
  const double write_s = seconds_since(t_write);
  const std::string points = cfg.point_count() > 1 ? to_str(cfg.point_count()) + " object points x " : std::string();
  std::string report = strprintf(
      "device: %s (%s)\nPSF stack: %s%zu bands x %zu x %zu (window %zu), %s, %.3f s (setup %.3f s: kernels %.3f s, FFT "
      "plans %.3f s)\n%s\nwrote %s/psf.h5, %spsf.png, design.png\n",
      rt.info().name.c_str(), rt.info().platform.c_str(), points.c_str(), cfg.bands, cfg.n, cfg.n, sim.geometry().m,
      to_string(p).c_str(), psf_seconds, st.setup_s, rt.build_seconds(), rt.fft_bake_seconds(),
      sim.sampling().summary().c_str(), dir.c_str(), cfg.point_count() > 1 ? "points.csv, " : "");
  return report + strprintf(
                      "time: inputs %.3f s, device %.3f s, setup %.3f s (both on a second thread during the inputs), "
                      "PSF %.3f s, "
                      "read-back %.3f s, files %.3f s; command %.3f s\n",
                      inputs_s, st.device_s, st.setup_s, psf_seconds, read_s, write_s, seconds_since(t_cmd));
}

}  // namespace qdo
