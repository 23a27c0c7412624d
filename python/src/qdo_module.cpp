// qdo's Python extension `qdo._qdo` (pybind11): a thin layer over the C++ library the `qdo` tool
// uses (qdo_core, linked statically); no physics is implemented here. The Python package
// (python/qdo/__init__.py, python/qdo/torch.py) wraps it.
//
// Arrays: NumPy float64 of any byte order and memory layout (copied to C order when they are
// not), shapes as documented per function (bands x S x S PSF stacks, bands x H x W scenes,
// 3 x H x W sensor images, N x N height maps in metres). Every argument is checked (type, dtype,
// shape, finiteness, range) before any allocation or device work; a bad one raises ValueError
// naming it, its value (never an array's contents) and what is allowed; an array that cannot be
// copied raises MemoryError naming it. qdo::InputError -> ValueError, any other qdo::Error ->
// RuntimeError.
//
// Threads: every call that uses an OpenCL device releases the GIL and then holds the lock of
// that device (one per device selector, shared by every Optics on it, since they share its
// Runtime: queue, kernel and FFT-plan caches) for the whole call. Everything else (HDF5, PNG,
// the CPU Wiener decoder) runs with the GIL held.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <atomic>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <map>
#include <memory>
#include <limits>
#include <optional>
#include <mutex>
#include <string>
#include <vector>

#include "arguments.hpp"
#include "qdo/data_root.hpp"
#include "qdo/figure.hpp"
#include "qdo/camera.hpp"
#include "qdo/config.hpp"
#include "qdo/datasets.hpp"
#include "qdo/doe.hpp"
#include "qdo/error.hpp"
#include "qdo/io.hpp"
#include "qdo/optics.hpp"
#include "qdo/psf_source.hpp"
#include "qdo/runtime.hpp"
#include "qdo/simulator.hpp"
#include "qdo/wiener.hpp"

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

// The scene a cube file or PNG band folder gives `qdo simulate --scene PATH [--key KEY]
// [--resample-bands]` under configuration cfg (src/cli/cli_util.cpp, scene_from_args, the same
// library calls in the same order): bands x H x W on cfg's band grid, in [0, 1].
RealStack read_scene(const SystemConfig& cfg, const std::string& path, const std::string& key, bool resample) {
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec)) {  // a CAVE folder of PNG bands
    if (!key.empty()) reject("key", key, "\"\" for a PNG band folder ('" + path + "')");
    RealStack png = read_png_band_folder(path, cfg.bands);
    conform_radiance(png, "folder '" + path + "'");
    return png;
  }
  CubeReadOptions o;
  o.key = key;
  o.expected_bands = cfg.bands;
  o.wavelengths_nm = cfg.wavelengths_nm();
  o.resample_bands = resample;
  RealStack cube = read_cube(path, o);
  conform_radiance(cube, "file '" + path + "'");
  return cube;
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

Quantizer make_quantizer(long long levels, const std::string& placement) {
  Quantizer q;
  q.levels = int(levels);
  q.placement = placement_from_string(placement);
  q.validate();
  return q;
}

// The configuration a read_cube call's scene must fit: JSON text as the Python wrapper gives it.
SystemConfig scene_config(const py::handle& config_json, const py::handle& origin) {
  SystemConfig c = config_from_json_text(str_arg(config_json, "config"), str_arg(origin, "config"));
  c.validate();
  return c;
}

// estimate_prior's bins: 4096 radial bins already resolve every frequency radius of a
// 5000-pixel-wide grid; the covariances take bins x bands x bands doubles, at most 2^27 (1 GiB).
constexpr long long kMaxPriorBins = 4096;
constexpr double kMaxPriorValues = double(std::size_t(1) << 27);

}  // namespace

PYBIND11_MODULE(_qdo, m) {
  m.doc() = "qdo's C++ library (OpenCL optics, camera, Wiener decoder, files); use the `qdo` package.";
  m.attr("__version__") = QDO_VERSION;

  // qdo::InputError (bad arguments, bad files) -> ValueError; other qdo errors -> RuntimeError.
  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const InputError& e) {
      PyErr_SetString(PyExc_ValueError, e.what());
    } catch (const Error& e) {
      PyErr_SetString(PyExc_RuntimeError, e.what());
    } catch (const cl::Error& e) {
      PyErr_SetString(PyExc_RuntimeError, (std::string("OpenCL: ") + e.what() + " " + cl_error_name(e.err())).c_str());
    }
  });

  // Every function takes its arguments as Python objects and converts them itself (the helpers
  // above), so that a wrong one is a short ValueError naming it, never pybind11's TypeError
  // that prints every argument (whole arrays included).
  m.def("preset_json", [](const py::handle& name) { return config_to_json_text(preset_config(str_arg(name, "name"))); },
        py::arg("name"), "The configuration of a preset (small, paper) as JSON text.");
  m.def(
      "data_root",
      [](const py::handle& root) {
        if (!root.is_none()) set_data_root(path_arg(root, "root"), "root");
        const DataRoot r = data_root();
        if (!root.is_none()) set_data_root("");
        py::dict d;
        d["path"] = r.path;
        d["source"] = r.source;
        d["exists"] = r.exists;
        d["looked"] = r.looked;
        return d;
      },
      py::arg("root") = py::none(), "Where datasets are looked for (include/qdo/data_root.hpp), as a dict.");
  m.def(
      "dataset_path",
      [](const py::handle& name, const py::handle& root) {
        if (!root.is_none()) set_data_root(path_arg(root, "root"), "root");
        try {
          const std::string p = resolve_dataset(str_arg(name, "name"), "name");
          if (!root.is_none()) set_data_root("");
          return p;
        } catch (...) {
          if (!root.is_none()) set_data_root("");
          throw;
        }
      },
      py::arg("name"), py::arg("root") = py::none(), "A dataset name resolved under the data root (a path is returned as given).");
  m.def("devices", [] {
    py::list out;
    for (const DeviceInfo& d : list_devices()) {
      py::dict e;
      e["platform"] = d.platform;
      e["name"] = d.name;
      e["type"] = d.type;
      e["driver_version"] = d.driver_version;
      e["fp64"] = d.fp64;
      e["compute_units"] = d.compute_units;
      e["selector"] = std::to_string(d.platform_index) + ":" + std::to_string(d.device_index);
      out.append(e);
    }
    return out;
  });

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
      .def("camera", &Optics::camera, py::arg("scene"), py::arg("psf"))
      .def("camera_counted", &Optics::camera_counted, py::arg("scene"), py::arg("psf"))
      .def("camera_vjp", &Optics::camera_vjp, py::arg("grad_rgb"), py::arg("scene") = py::none(), py::arg("psf") = py::none(),
           py::arg("forward") = 0);

  m.def(
      "quantize",
      [](const py::handle& h_obj, const py::handle& h_max_obj, const py::handle& levels, const py::handle& placement) {
        const Array h = checked(h_obj, "height_m", {"N", "M"});
        const double h_max_m = positive_arg(h_max_obj, "h_max_m");
        const Quantizer q = make_quantizer(int_arg(levels, "levels", 2, 65536), str_arg(placement, "placement"));
        return from_map(quantize_heights(to_map(h), h_max_m, q, 1.0));
      },
      py::arg("height_m"), py::arg("h_max_m"), py::arg("levels"), py::arg("placement") = "inclusive");
  m.def(
      "lens_design",
      [](const py::handle& config_json, const py::handle& wavelength_nm) {
        const double nm = positive_arg(wavelength_nm, "wavelength_nm");
        return from_map(lens_design(config_from_json_text(str_arg(config_json, "config")), nm));
      },
      py::arg("config_json"), py::arg("wavelength_nm"));

  m.def(
      "estimate_prior",
      [](const py::handle& scenes_obj, const py::handle& bins_obj) {
        const std::size_t bins = std::size_t(int_arg(bins_obj, "bins", 2, kMaxPriorBins));
        const Array s = checked(scenes_obj, "scenes", {"count", "bands", "H", "W"});
        const double values = double(bins) * double(s.shape(1)) * double(s.shape(1));
        if (values > kMaxPriorValues)
          value_error("bins: " + std::to_string(bins) + " with " + std::to_string(s.shape(1)) + " bands makes " +
                      to_str(values) + " covariance values; expected bins x bands x bands <= 2^27");
        const wiener::SpectralPrior p = wiener::estimate_prior(to_stacks(s), bins);
        Array cov({py::ssize_t(p.bins), py::ssize_t(p.bands), py::ssize_t(p.bands)});  // bins x bands x bands
        std::copy(p.cov.begin(), p.cov.end(), cov.mutable_data());
        return cov;
      },
      py::arg("scenes"), py::arg("bins") = 16);
  m.def(
      "wiener_decode",
      [](const py::handle& y_obj, const py::handle& psf_obj, const py::handle& srf_obj, const py::handle& cov_obj,
         const py::handle& sigma_obj) {
        const Array y = checked(y_obj, "y", {3, "H", "W"});
        const Array p = checked(psf_obj, "psf", {"bands", "S", "S"});
        if (p.shape(1) != p.shape(2)) value_error("psf: shape " + shape_text(p) + "; expected (bands, S, S), square planes");
        const std::size_t bands = std::size_t(p.shape(0));
        const Array s = checked(srf_obj, "srf", {3, bands});
        const Array c = checked(cov_obj, "prior", {"bins", bands, bands});
        const double sigma = real_arg(sigma_obj, "noise_sigma");
        if (sigma < 0) value_error("noise_sigma: " + short_str(sigma_obj) + "; expected a finite number >= 0");
        wiener::SpectralPrior pr;
        pr.bins = std::size_t(c.shape(0));
        pr.bands = bands;
        pr.rows = std::size_t(y.shape(1));
        pr.cols = std::size_t(y.shape(2));
        pr.cov.assign(c.data(), c.data() + c.size());
        Eigen::MatrixXd srf(s.shape(0), s.shape(1));  // 3 x bands
        for (py::ssize_t i = 0; i < s.shape(0); ++i)
          for (py::ssize_t j = 0; j < s.shape(1); ++j) srf(i, j) = s.at(i, j);
        try {
          return from_stack(wiener::decode(to_stack(y), wiener::psf_to_otf(to_stack(p), pr.rows, pr.cols), srf, pr, sigma));
        } catch (const InputError&) {
          throw;
        } catch (const Error& e) {
          // With noise_sigma > 0 the filter is never singular: a singular one is noise_sigma = 0's.
          if (sigma == 0) value_error(std::string("noise_sigma: 0; ") + e.what());
          throw;
        }
      },
      py::arg("y"), py::arg("psf"), py::arg("srf"), py::arg("prior"), py::arg("noise_sigma"));

  m.def(
      "read_cube",
      [](const py::handle& path, const py::handle& key, const py::handle& config_json, const py::handle& origin,
         const py::handle& resample) {
        const std::string p = path_arg(path, "path"), k = str_arg(key, "key");
        const bool rs = bool_arg(resample, "resample_bands");
        return from_stack(read_scene(scene_config(config_json, origin), p, k, rs));
      },
      py::arg("path"), py::arg("key"), py::arg("config_json"), py::arg("origin"), py::arg("resample_bands"));
  m.def(
      "write_cube",
      [](const py::handle& path, const py::handle& cube_obj, const py::handle& wavelengths) {
        const std::string p = path_arg(path, "path");
        const RealStack cube = to_stack(checked(cube_obj, "cube", {"bands", "H", "W"}));
        write_cube(p, cube, reals_arg(wavelengths, "wavelengths_nm"));
      },
      py::arg("path"), py::arg("cube"), py::arg("wavelengths_nm"));
  m.def(
      "read_design",
      [](const py::handle& path) {
        const Design d = read_design(path_arg(path, "path"));
        return py::make_tuple(from_map(d.height_m), d.pitch_m, d.levels_m);
      },
      py::arg("path"));
  m.def(
      "write_design",
      [](const py::handle& path, const py::handle& h_obj, const py::handle& pitch_m, const py::handle& levels_m) {
        const std::string p = path_arg(path, "path");
        Design d;
        d.height_m = to_map(checked(h_obj, "height_m", {"N", "N"}));
        d.pitch_m = positive_arg(pitch_m, "pitch_m");
        d.levels_m = reals_arg(levels_m, "levels_m");
        write_design(p, d, {{"written_by", "qdo python " QDO_VERSION}});
      },
      py::arg("path"), py::arg("height_m"), py::arg("pitch_m"), py::arg("levels_m") = py::tuple());
  m.def(
      "write_rgb_png",
      [](const py::handle& path, const py::handle& rgb_obj) {
        const std::string p = path_arg(path, "path");
        write_rgb_png(p, to_stack(checked(rgb_obj, "rgb", {3, "H", "W"})));
      },
      py::arg("path"), py::arg("rgb"));
  m.def(
      "write_psf_figure",
      [](const py::handle& path, const std::string& title, const py::handle& stack_obj, const py::handle& wavelengths,
         const py::handle& pitch_m, std::size_t crop) {
        const std::string p = path_arg(path, "path");
        const RealStack st = to_stack(checked(stack_obj, "stack", {"planes", "H", "W"}));
        write_psf_figure(p, title, st, reals_arg(wavelengths, "wavelengths_nm"), positive_arg(pitch_m, "pitch_m"), crop);
      },
      py::arg("path"), py::arg("title"), py::arg("stack"), py::arg("wavelengths_nm"), py::arg("pitch_m"), py::arg("crop") = 0);
  m.def(
      "write_height_figure",
      [](const py::handle& path, const std::string& title, const py::handle& map_obj, const py::handle& pitch_m,
         const std::string& value_label) {
        const std::string p = path_arg(path, "path");
        write_height_figure(p, title, to_map(checked(map_obj, "height_m", {"H", "W"})), positive_arg(pitch_m, "pitch_m"), value_label);
      },
      py::arg("path"), py::arg("title"), py::arg("height_m"), py::arg("pitch_m"), py::arg("value_label") = "height (nm)");
  m.def(
      "read_h5",
      [](const py::handle& path, const py::handle& name) {
        const H5Dataset d = h5_read(path_arg(path, "path"), str_arg(name, "name"));
        std::vector<py::ssize_t> shape(d.shape.begin(), d.shape.end());
        Array a(shape);
        std::copy(d.data.begin(), d.data.end(), a.mutable_data());
        return a;
      },
      py::arg("path"), py::arg("name"));
}
