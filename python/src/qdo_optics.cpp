// The class Optics of qdo's Python extension (qdo_module.cpp has the conventions): a configuration
// on an OpenCL device, its PSF source and camera operator with their adjoints, and the devices
// it shares with every other Optics on them.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <atomic>
#include <cstdint>
#include <limits>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "arguments.hpp"
#include "qdo_bindings.hpp"
#include "qdo/physics/camera.hpp"
#include "qdo/physics/capture_pipeline.hpp"
#include "qdo/physics/demosaic_reference.hpp"
#include "qdo/data/config.hpp"
#include "qdo/design/psf_spec.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/psf_source.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/physics/simulator.hpp"

namespace py = pybind11;
using namespace qdo;
using namespace qdo::python;

namespace {

// ---------- Devices ----------

// One OpenCL device as the bindings use it: the Runtime (its queue, kernel and FFT-plan caches
// are not thread-safe) and the lock every Optics on it holds for the whole of each call that
// touches the device.
struct Device {
  explicit Device(const std::string& selector) : rt(selector) {}
  Runtime rt;
  std::mutex mu;
};

// One Device per selector for the whole process (devices are slow to open; kernels and FFT plans
// are cached per Runtime). Called with the GIL held, which guards the map.
std::shared_ptr<Device> device_for(const std::string& selector) {
  static std::map<std::string, std::shared_ptr<Device>> devices;
  auto it = devices.find(selector);
  if (it == devices.end()) it = devices.emplace(selector, std::make_shared<Device>(selector)).first;
  return it->second;
}

// A configuration on a device: a height-map PSF source (psf_source.hpp; the Simulator's 2-D
// chain) and the camera operator (Camera, fed the PSF stack it is given), with their adjoints.
//
// Each call that touches the device (construction, psf, psf_vjp, camera, camera_vjp,
// destruction) releases the GIL, then holds the device's lock (Device::mu) for the whole call, so
// each call is atomic with respect to every other call on the same device, from any thread.
// Without forward arguments, an adjoint is that of this object's last forward call of the same
// kind, from whichever thread made it; with them (psf_vjp's height_m, camera_vjp's scene and psf)
// the forward is re-run inside the same locked call unless `forward` names the last forward call
// (its count), so the pair cannot be split by another thread. `psf_calls` / `camera_calls` count
// the forwards; psf_counted / camera_counted return the count of their own call, which the
// PyTorch layer passes back as `forward` (read separately, another thread's call could slip in).
class Optics {
 public:
  Optics(const std::string& config_json, const std::string& origin, const std::string& device, const std::string& precision)
      : cfg_(config_from_json_text(config_json, origin)), prec_(precision_from_string(precision)), dev_(device_for(device)) {
    cfg_.validate();
    py::gil_scoped_release unlocked;
    std::lock_guard<std::mutex> lock(dev_->mu);
    sim_ = std::make_unique<Simulator>(dev_->rt, cfg_, prec_);  // held as its PsfSource interface
    cam_ = std::make_unique<Camera>(dev_->rt, cfg_, prec_);
    s_ = sim_->sensor_size();
  }
  // Called with the GIL held; no holder of the device lock waits for the GIL, so taking it here
  // cannot deadlock. The device objects go before another thread's call may use the Runtime.
  ~Optics() {
    std::lock_guard<std::mutex> lock(dev_->mu);
    cam_.reset();
    pts_sim_.reset();
    sim_.reset();
  }
  Optics(const Optics&) = delete;
  Optics& operator=(const Optics&) = delete;

  std::string config_json() const { return config_to_json_text(cfg_); }
  std::string device_name() const { return dev_->rt.info().name; }
  std::string precision() const { return to_string(prec_); }
  std::size_t n() const { return cfg_.n; }
  std::size_t bands() const { return cfg_.bands; }
  std::size_t sensor_size() const { return s_; }
  std::vector<double> wavelengths_nm() const { return cfg_.wavelengths_nm(); }
  double h_max_m() const { return cfg_.h_max_m(); }
  const SystemConfig& config() const { return cfg_; }
  Array srf() const {  // 3 x bands
    const Eigen::MatrixXd s = sensor_response(cfg_);
    Array a({py::ssize_t(s.rows()), py::ssize_t(s.cols())});
    for (Eigen::Index c = 0; c < s.rows(); ++c)
      for (Eigen::Index b = 0; b < s.cols(); ++b) a.mutable_at(c, b) = s(c, b);
    return a;
  }
  std::uint64_t psf_calls() const { return psf_calls_; }
  std::uint64_t camera_calls() const { return camera_calls_; }

  // height_m: N x N (metres) -> the sensor-grid PSF stack, bands x S x S (as `qdo psf` writes
  // to /psf_sensor). object_points (None: the configuration's): a sequence of (distance_m,
  // field_x_deg, field_y_deg) triples, distance > 0 or inf (config.hpp ObjectPoint), checked as the
  // configuration's object_points are (ValueError naming the point and the limit). With object
  // points (given, or in the configuration) the stack is points x bands x S x S, all points in one
  // batched device pass.
  Array psf(const py::handle& height_obj, const py::handle& points_obj) {
    return psf_counted(height_obj, points_obj)[0].cast<Array>();
  }
  // The same with the count of this forward call (psf_calls right after it, from inside the
  // locked call): (psf, count), for psf_vjp's `forward`.
  py::tuple psf_counted(const py::handle& height_obj, const py::handle& points_obj) {
    const Map2D m = to_map(checked(height_obj, "height_m", {cfg_.n, cfg_.n}));
    const Points pts = points_arg(points_obj);
    RealStack out;
    std::uint64_t count = 0;
    {
      py::gil_scoped_release unlocked;
      std::lock_guard<std::mutex> lock(dev_->mu);
      out = psf_locked(m, pts);
      count = psf_calls_;
    }
    return py::make_tuple(stack_out(out, pts), count);
  }

  // grad_psf: bands x S x S (points x bands x S x S with object points), the gradient of a scalar
  // with respect to a psf() result -> its gradient with respect to the heights (N x N, per metre;
  // the points' contributions summed). height_m None: the adjoint at the last psf() call of any
  // thread with these object points; height_m given (N x N): at those heights, the forward re-run
  // in the same locked call unless `forward` equals psf_calls (it was the last one).
  Array psf_vjp(const py::handle& grad_obj, const py::handle& height_obj, std::uint64_t forward, const py::handle& points_obj) {
    const Points pts = points_arg(points_obj);
    const std::size_t np = pts ? pts->size() : cfg_.point_count();
    RealStack g;
    if (four_d(pts)) {
      const Array a = checked(grad_obj, "grad_psf", {np, cfg_.bands, s_, s_});
      g = RealStack(np * cfg_.bands, s_, s_);
      std::copy(a.data(), a.data() + a.size(), g.data.begin());
    } else {
      g = to_stack(checked(grad_obj, "grad_psf", {cfg_.bands, s_, s_}));
    }
    const bool at = !height_obj.is_none();
    Map2D m;
    if (at) m = to_map(checked(height_obj, "height_m", {cfg_.n, cfg_.n}));
    Map2D out;
    bool none_yet = false;
    {
      py::gil_scoped_release unlocked;
      std::lock_guard<std::mutex> lock(dev_->mu);
      if (at && (forward == 0 || forward != psf_calls_)) (void)psf_locked(m, pts);
      HeightMapPsfSource& sim = sim_for(pts);
      none_yet = psf_calls_ == 0 || !sim.psf_ready();
      if (!none_yet) out = sim.psf_sensor_vjp(g);
    }
    if (none_yet)
      value_error("grad_psf: no psf() call with these object points to take the adjoint of (call psf() first, or pass height_m)");
    return from_map(out);
  }

  // A PSF stack file as `qdo psf` writes it (/psf_sensor; psf_source.hpp's read_psf_stack_for):
  // bands x S x S, checked against this configuration's bands, sensor grid and pitch (ValueError
  // naming both when they differ), for camera() in place of psf(): the file-backed PSF source.
  // HDF5 with the GIL held; no device work.
  Array read_psf(const py::handle& path) const { return from_stack(read_psf_stack_for(cfg_, path_arg(path, "path"), "path")); }

  // The PSF named as the commands name it (psf_spec.hpp: qdo simulate's, image's, eval's and fit's
  // --psf and --design): psf a PSF stack file, read as read_psf reads it, or design lens:NM, flat
  // or a design .h5 (a run's or qdo fit's as-built design.h5), simulated on this configuration's
  // device -> bands x S x S. Exactly one of the two; both read and checked before any device work
  // (ValueError naming the argument otherwise).
  Array psf_from(const py::handle& psf_obj, const py::handle& design_obj) {
    const std::string psf = psf_obj.is_none() ? std::string() : path_arg(psf_obj, "psf");
    const std::string design = design_obj.is_none() ? std::string() : str_arg(design_obj, "design");
    if (psf.empty() && design.empty()) reject("psf", "None", "a PSF stack file, or design= lens:NM, flat or a design .h5 file");
    const PsfInput in = read_psf_input(psf_spec_from_options(psf, design, "psf", "design", "the PSF comes from one of them"), cfg_);
    RealStack out;
    {
      py::gil_scoped_release unlocked;
      std::lock_guard<std::mutex> lock(dev_->mu);
      out = psf_stack(dev_->rt, cfg_, prec_, in);
    }
    return from_stack(out);
  }

  // scenes: batch x bands x H x W, psf: bands x S x S -> batch x 3 x H x W sensor images through
  // the device camera operator (cfg.convolution, the sensor response, cfg's noise; exact: no
  // skipping).
  Array camera(const py::handle& scene_obj, const py::handle& psf_obj) {
    return camera_counted(scene_obj, psf_obj)[0].cast<Array>();
  }
  // The same with the count of this forward call: (images, count), for camera_vjp's `forward`.
  py::tuple camera_counted(const py::handle& scene_obj, const py::handle& psf_obj) {
    const Array sc = checked(scene_obj, "scene", {"batch", cfg_.bands, "H", "W"});
    const RealStack ps = to_stack(checked(psf_obj, "psf", {cfg_.bands, s_, s_}));
    const std::vector<RealStack> cubes = to_stacks(sc);
    std::vector<RealStack> rgb;
    std::uint64_t count = 0;
    {
      py::gil_scoped_release unlocked;
      std::lock_guard<std::mutex> lock(dev_->mu);
      rgb = camera_locked(cubes, ps);
      count = camera_calls_;
    }
    return py::make_tuple(from_stacks(rgb, 3, std::size_t(sc.shape(2)), std::size_t(sc.shape(3))), count);
  }

  // grad_rgb: batch x 3 x H x W, the gradient with respect to a camera() result -> (gradient on
  // its psf, bands x S x S; gradient on its scenes, batch x bands x H x W). scene and psf None:
  // the adjoint of the last camera() call of any thread; given: of camera(scene, psf), re-run in
  // the same locked call unless `forward` equals camera_calls.
  py::tuple camera_vjp(const py::handle& grad_obj, const py::handle& scene_obj, const py::handle& psf_obj,
                       std::uint64_t forward) {
    const Array ga = checked(grad_obj, "grad_rgb", {"batch", 3, "H", "W"});
    if (scene_obj.is_none() != psf_obj.is_none())
      value_error(std::string(scene_obj.is_none() ? "scene" : "psf") + ": None; give both scene and psf, or neither");
    const bool at = !scene_obj.is_none();
    std::vector<RealStack> cubes;
    RealStack ps;
    if (at) {
      cubes = to_stacks(checked(scene_obj, "scene", {std::size_t(ga.shape(0)), cfg_.bands, std::size_t(ga.shape(2)),
                                                     std::size_t(ga.shape(3))}));
      ps = to_stack(checked(psf_obj, "psf", {cfg_.bands, s_, s_}));
    }
    const std::vector<RealStack> gr = to_stacks(ga);
    const std::vector<std::size_t> got{std::size_t(ga.shape(0)), std::size_t(ga.shape(2)), std::size_t(ga.shape(3))};
    Camera::Gradient res;
    bool none_yet = false;
    std::vector<std::size_t> last;  // batch, H, W of the forward call the adjoint is of
    {
      py::gil_scoped_release unlocked;
      std::lock_guard<std::mutex> lock(dev_->mu);
      if (at && (forward == 0 || forward != camera_calls_)) (void)camera_locked(cubes, ps);
      none_yet = camera_calls_ == 0;
      last = last_images_;
      if (!none_yet && last == got) res = cam_->vjp(gr, true);
    }
    if (none_yet) value_error("grad_rgb: no camera() call to take the adjoint of (call camera() first, or pass scene and psf)");
    if (last != got)
      value_error("grad_rgb: shape " + shape_text(ga) + "; expected (" + std::to_string(last[0]) + ", 3, " + std::to_string(last[1]) +
                  ", " + std::to_string(last[2]) + "), the images of the last camera() call");
    return py::make_tuple(from_stack(res.psf), from_stacks(res.scenes, cfg_.bands, std::size_t(ga.shape(2)), std::size_t(ga.shape(3))));
  }

  // One scene through the capture pipeline (capture_pipeline.hpp, the chain `qdo simulate` runs):
  // scene bands x H x W, psf bands x S x S -> a dict of the frame's arrays: "clean" and "rgb"
  // (3 x H x W: before noise and clip, and after), "clipped_fraction", and with raw
  // (the configuration's cfa a mosaic) "raw_dn" (1 x H x W, code values) and "demosaiced"
  // (3 x H x W, linear). noise: the configuration's shot and read noise (scene 0's counters, as
  // qdo simulate draws them). demosaic: "bilinear" or "mhc". Bad arguments are ValueErrors naming
  // them, before any device work.
  py::dict capture(const py::handle& scene_obj, const py::handle& psf_obj, bool raw, bool noise, const std::string& demosaic) {
    const Array sc = checked(scene_obj, "scene", {cfg_.bands, "H", "W"});
    const RealStack scene = to_stack(sc);
    const RealStack ps = to_stack(checked(psf_obj, "psf", {cfg_.bands, s_, s_}));
    PipelineOptions o;
    o.noise = noise;
    o.raw = raw;
    o.demosaic = demosaic_method_from_string(demosaic, "demosaic");  // InputError -> ValueError
    if (raw && cfg_.cfa == Cfa::None)
      value_error("raw: True needs a mosaic; the configuration's cfa is none (give a config with \"cfa\": \"rggb\", ...)");
    CaptureFrame f;
    {
      py::gil_scoped_release unlocked;
      std::lock_guard<std::mutex> lock(dev_->mu);
      CapturePipeline pipe(dev_->rt, cfg_, prec_, o);
      f = pipe.run(ps, scene);
    }
    py::dict d;
    d["clean"] = from_stack(f.clean);
    d["rgb"] = from_stack(f.rgb);
    d["clipped_fraction"] = f.clip.fraction();
    if (raw) {
      d["raw_dn"] = from_stack(f.raw_dn);
      d["demosaiced"] = from_stack(f.demosaiced);
    }
    return d;
  }

 private:
  // Object points of a call: none (the configuration's own) or a list, checked.
  using Points = std::optional<std::vector<ObjectPoint>>;
  // A sequence of (distance_m, field_x_deg, field_y_deg) (distance a number, inf or "inf"),
  // validated with the configuration (ValueError naming the point, the value and the limit).
  Points points_arg(const py::handle& o) const {
    if (o.is_none()) return std::nullopt;
    if (py::isinstance<py::str>(o) || !py::hasattr(o, "__len__"))
      value_error("object_points: expected a sequence of (distance_m, field_x_deg, field_y_deg), got " + type_name(o));
    std::vector<ObjectPoint> v;
    for (const py::handle item : o) {
      const std::string name = "object_points[" + std::to_string(v.size()) + "]";
      if (py::isinstance<py::str>(item) || !py::hasattr(item, "__len__") || py::len(item) != 3)
        value_error(name + ": expected (distance_m, field_x_deg, field_y_deg), got " + short_str(item));
      const py::sequence t = py::reinterpret_borrow<py::sequence>(item);
      ObjectPoint p;
      if (py::isinstance<py::str>(t[0]) && py::str(t[0]).cast<std::string>() == "inf")
        p.distance_m = std::numeric_limits<double>::infinity();
      else if (is_real_number(t[0]))
        p.distance_m = py::float_(py::reinterpret_borrow<py::object>(t[0]));
      else
        value_error(name + " distance: " + short_str(t[0]) + "; expected a number of metres > 0 or inf");
      p.field_x_deg = real_arg(t[1], (name + " field_x_deg").c_str());
      p.field_y_deg = real_arg(t[2], (name + " field_y_deg").c_str());
      v.push_back(p);
    }
    if (v.empty()) value_error("object_points: an empty sequence; give at least one point, or None for the configuration's");
    SystemConfig c = cfg_;
    c.object_points = v;
    c.validate();  // InputError -> ValueError, naming the point and the limit
    return v;
  }
  // Whether a call's stack has the points axis: points given, or in the configuration.
  bool four_d(const Points& pts) const { return pts.has_value() || !cfg_.object_points.empty(); }
  Array stack_out(const RealStack& s, const Points& pts) const {
    if (!four_d(pts)) return from_stack(s);
    const std::size_t np = s.planes / cfg_.bands;
    Array a({py::ssize_t(np), py::ssize_t(cfg_.bands), py::ssize_t(s.rows), py::ssize_t(s.cols)});
    std::copy(s.data.begin(), s.data.end(), a.mutable_data());
    return a;
  }
  // The simulator of a call (device lock held): the configuration's, or the one of the given
  // points, made when a call names points other than the last call with points did.
  HeightMapPsfSource& sim_for(const Points& pts) {
    if (!pts) return *sim_;
    const auto same = [&](const std::vector<ObjectPoint>& a) {
      if (a.size() != pts->size()) return false;
      for (std::size_t i = 0; i < a.size(); ++i)
        if (a[i].distance_m != (*pts)[i].distance_m || a[i].field_x_deg != (*pts)[i].field_x_deg ||
            a[i].field_y_deg != (*pts)[i].field_y_deg)
          return false;
      return true;
    };
    if (!pts_sim_ || !same(pts_sim_->config().object_points)) {
      pts_sim_.reset();
      SystemConfig c = cfg_;
      c.object_points = *pts;
      pts_sim_ = std::make_unique<Simulator>(dev_->rt, c, prec_);
    }
    return *pts_sim_;
  }

  // The forwards, with the device lock held (and the GIL released).
  RealStack psf_locked(const Map2D& m, const Points& pts = std::nullopt) {
    HeightMapPsfSource& sim = sim_for(pts);
    sim.set_heights(m);
    sim.compute_psf();
    ++psf_calls_;
    return sim.psf_sensor();
  }
  std::vector<RealStack> camera_locked(const std::vector<RealStack>& cubes, const RealStack& ps) {
    cam_->set_psf(ps);
    SkipOptions exact;
    exact.exact = true;
    std::vector<RealStack> rgb = cam_->images(cubes, exact);
    last_images_ = {cubes.size(), cubes.front().rows, cubes.front().cols};
    ++camera_calls_;
    return rgb;
  }

  SystemConfig cfg_;
  Precision prec_;
  std::shared_ptr<Device> dev_;  // before the device objects: destroyed after them
  std::unique_ptr<HeightMapPsfSource> sim_;
  std::unique_ptr<HeightMapPsfSource> pts_sim_;  // the last object points given to psf()/psf_vjp()
  std::unique_ptr<Camera> cam_;
  std::size_t s_ = 0;  // S, the sensor grid
  std::vector<std::size_t> last_images_;  // batch, H, W of the last camera() call (device lock)
  // Forward counts, written under the device lock, read by Python without it.
  std::atomic<std::uint64_t> psf_calls_{0}, camera_calls_{0};
};

}  // namespace

void bind_optics(py::module_& m) {
  py::class_<Optics>(m, "Optics")
      .def(py::init([](const py::handle& config_json, const py::handle& origin, const py::handle& device,
                       const py::handle& precision) {
             const std::string prec = str_arg(precision, "precision");
             if (prec != "f32" && prec != "f64") value_error("precision: '" + prec + "'; expected 'f32' or 'f64'");
             return std::make_unique<Optics>(str_arg(config_json, "config"), str_arg(origin, "config"),
                                             str_arg(device, "device"), prec);
           }),
           py::arg("config_json"), py::arg("origin"), py::arg("device"), py::arg("precision"))
      .def_property_readonly("config_json", &Optics::config_json)
      .def_property_readonly("device_name", &Optics::device_name)
      .def_property_readonly("precision", &Optics::precision)
      .def_property_readonly("n", &Optics::n)
      .def_property_readonly("bands", &Optics::bands)
      .def_property_readonly("sensor_size", &Optics::sensor_size)
      .def_property_readonly("wavelengths_nm", &Optics::wavelengths_nm)
      .def_property_readonly("h_max_m", &Optics::h_max_m)
      .def_property_readonly("psf_calls", &Optics::psf_calls)
      .def_property_readonly("camera_calls", &Optics::camera_calls)
      .def("srf", &Optics::srf)
      .def("psf", &Optics::psf, py::arg("height_m"), py::arg("object_points") = py::none())
      .def("psf_counted", &Optics::psf_counted, py::arg("height_m"), py::arg("object_points") = py::none())
      .def("psf_vjp", &Optics::psf_vjp, py::arg("grad_psf"), py::arg("height_m") = py::none(), py::arg("forward") = 0,
           py::arg("object_points") = py::none())
      .def("read_psf", &Optics::read_psf, py::arg("path"))
      .def("psf_from", &Optics::psf_from, py::arg("psf") = py::none(), py::arg("design") = py::none())
      .def("camera", &Optics::camera, py::arg("scene"), py::arg("psf"))
      .def("capture", &Optics::capture, py::arg("scene"), py::arg("psf"), py::arg("raw") = false, py::arg("noise") = true,
           py::arg("demosaic") = "bilinear")
      .def("camera_counted", &Optics::camera_counted, py::arg("scene"), py::arg("psf"))
      .def("camera_vjp", &Optics::camera_vjp, py::arg("grad_rgb"), py::arg("scene") = py::none(), py::arg("psf") = py::none(),
           py::arg("forward") = 0);
}
