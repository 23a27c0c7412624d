// qdo's Python extension `qdo._qdo` (pybind11): a thin layer over the C++ library the `qdo` tool
// uses (qdo_core, linked statically); no physics is implemented here. The Python package
// (python/qdo/__init__.py, python/qdo/torch.py) wraps it.
//
// Arrays: NumPy float64, C order, shapes as documented per function (bands x S x S PSF stacks,
// bands x H x W scenes, 3 x H x W sensor images, N x N height maps in metres). Every argument is
// checked (dtype, shape, finiteness) before any device work; a bad one raises ValueError naming
// it. qdo::InputError -> ValueError, any other qdo::Error -> RuntimeError.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <cmath>
#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "qdo/camera.hpp"
#include "qdo/config.hpp"
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

namespace {

using Array = py::array_t<double, py::array::c_style>;

// The argument `name` as a C-order float64 array of the given rank (shape checked by the
// caller); ValueError for another dtype, rank or a non-finite entry.
Array checked(const py::handle& obj, const char* name, std::size_t rank) {
  if (!py::isinstance<py::array>(obj))
    throw py::value_error(std::string(name) + ": expected a NumPy float64 array, got " +
                          std::string(py::str(py::type::of(obj).attr("__name__"))));
  const py::array a = py::reinterpret_borrow<py::array>(obj);
  if (!a.dtype().is(py::dtype::of<double>()))
    throw py::value_error(std::string(name) + ": dtype " + std::string(py::str(a.dtype())) + "; expected float64");
  if (static_cast<std::size_t>(a.ndim()) != rank)
    throw py::value_error(std::string(name) + ": " + std::to_string(a.ndim()) + " dimensions; expected " +
                          std::to_string(rank));
  Array c = Array::ensure(a);
  const double* p = c.data();
  for (py::ssize_t i = 0; i < c.size(); ++i)
    if (!std::isfinite(p[i])) throw py::value_error(std::string(name) + ": non-finite value at flat index " + std::to_string(i));
  return c;
}

std::string shape_of(const Array& a) {
  std::string s = "(";
  for (py::ssize_t k = 0; k < a.ndim(); ++k) s += (k ? ", " : "") + std::to_string(a.shape(k));
  return s + ")";
}

void require_shape(const Array& a, const char* name, const std::vector<std::size_t>& want) {
  bool ok = static_cast<std::size_t>(a.ndim()) == want.size();
  for (std::size_t k = 0; ok && k < want.size(); ++k) ok = static_cast<std::size_t>(a.shape(py::ssize_t(k))) == want[k];
  if (!ok) {
    std::string w = "(";
    for (std::size_t k = 0; k < want.size(); ++k) w += (k ? ", " : "") + std::to_string(want[k]);
    throw py::value_error(std::string(name) + ": shape " + shape_of(a) + "; expected " + w + ")");
  }
}

RealStack to_stack(const Array& a) {
  RealStack s(std::size_t(a.shape(0)), std::size_t(a.shape(1)), std::size_t(a.shape(2)));
  std::copy(a.data(), a.data() + a.size(), s.data.begin());
  return s;
}

Array from_stack(const RealStack& s) {
  Array a({py::ssize_t(s.planes), py::ssize_t(s.rows), py::ssize_t(s.cols)});
  std::copy(s.data.begin(), s.data.end(), a.mutable_data());
  return a;
}

Array from_map(const Map2D& m) {
  Array a({py::ssize_t(m.rows), py::ssize_t(m.cols)});
  std::copy(m.data.begin(), m.data.end(), a.mutable_data());
  return a;
}

// One Runtime per device selector for the whole process (devices are slow to open; kernels and
// FFT plans are cached per Runtime).
std::shared_ptr<Runtime> runtime_for(const std::string& device) {
  static std::map<std::string, std::shared_ptr<Runtime>> runtimes;
  auto it = runtimes.find(device);
  if (it == runtimes.end()) it = runtimes.emplace(device, std::make_shared<Runtime>(device)).first;
  return it->second;
}

// A configuration on a device: a height-map PSF source (psf_source.hpp; the Simulator's 2-D
// chain) and the camera operator (Camera, fed the PSF stack it is given), with their adjoints. Each adjoint is the adjoint of this object's last forward call of the
// same kind; `psf_calls` / `camera_calls` count the forwards so that the PyTorch layer can tell
// whether it must re-run one before a backward.
class Optics {
 public:
  Optics(const std::string& config_json, const std::string& origin, const std::string& device, const std::string& precision)
      : cfg_(config_from_json_text(config_json, origin)), prec_(precision_from_string(precision)), rt_(runtime_for(device)) {
    cfg_.validate();
    sim_ = std::make_unique<Simulator>(*rt_, cfg_, prec_);  // held as its PsfSource interface
    cam_ = std::make_unique<Camera>(*rt_, cfg_, prec_);
  }

  std::string config_json() const { return config_to_json_text(cfg_); }
  std::string device_name() const { return rt_->info().name; }
  std::string precision() const { return to_string(prec_); }
  std::size_t n() const { return cfg_.n; }
  std::size_t bands() const { return cfg_.bands; }
  std::size_t sensor_size() const { return sim_->sensor_size(); }
  std::vector<double> wavelengths_nm() const { return cfg_.wavelengths_nm(); }
  double h_max_m() const { return cfg_.h_max_m(); }
  Array srf() const {
    const Eigen::MatrixXd s = sensor_response(cfg_);
    Array a({py::ssize_t(s.rows()), py::ssize_t(s.cols())});
    for (Eigen::Index c = 0; c < s.rows(); ++c)
      for (Eigen::Index b = 0; b < s.cols(); ++b) a.mutable_at(c, b) = s(c, b);
    return a;
  }
  std::uint64_t psf_calls() const { return psf_calls_; }
  std::uint64_t camera_calls() const { return camera_calls_; }

  // height_m: N x N (metres) -> the sensor-grid PSF stack, bands x S x S (as `qdo psf` writes
  // to /psf_sensor).
  Array psf(const py::handle& height_obj) {
    const Array h = checked(height_obj, "height_m", 2);
    require_shape(h, "height_m", {cfg_.n, cfg_.n});
    Map2D m(cfg_.n, cfg_.n);
    std::copy(h.data(), h.data() + h.size(), m.data.begin());
    RealStack out;
    {
      py::gil_scoped_release unlocked;
      sim_->set_heights(m);
      sim_->compute_psf();
      out = sim_->psf_sensor();
    }
    ++psf_calls_;
    return from_stack(out);
  }

  // grad_psf: bands x S x S, the gradient of a scalar with respect to the last psf() result ->
  // its gradient with respect to height_m (N x N, per metre).
  Array psf_vjp(const py::handle& grad_obj) {
    if (psf_calls_ == 0) throw py::value_error("grad_psf: no psf() call to take the adjoint of");
    const Array g = checked(grad_obj, "grad_psf", 3);
    require_shape(g, "grad_psf", {cfg_.bands, sensor_size(), sensor_size()});
    const RealStack gs = to_stack(g);
    Map2D out;
    {
      py::gil_scoped_release unlocked;
      out = sim_->psf_sensor_vjp(gs);
    }
    return from_map(out);
  }

  // A PSF stack file as `qdo psf` writes it (/psf_sensor; psf_source.hpp's read_psf_stack_for):
  // bands x S x S, checked against this configuration's bands, sensor grid and pitch (ValueError
  // naming both when they differ), for camera() in place of psf(): the file-backed PSF source.
  Array read_psf(const std::string& path) const { return from_stack(read_psf_stack_for(cfg_, path, "path")); }

  // scenes: batch x bands x H x W, psf: bands x S x S -> batch x 3 x H x W sensor images through
  // the device camera operator (cfg.convolution, the sensor response, cfg's noise; exact: no
  // skipping).
  Array camera(const py::handle& scene_obj, const py::handle& psf_obj) {
    const Array sc = checked(scene_obj, "scene", 4);
    const Array p = checked(psf_obj, "psf", 3);
    if (std::size_t(sc.shape(1)) != cfg_.bands || sc.shape(0) < 1 || sc.shape(2) < 1 || sc.shape(3) < 1)
      throw py::value_error("scene: shape " + shape_of(sc) + "; expected (batch, " + std::to_string(cfg_.bands) +
                            ", H, W) with batch, H, W >= 1");
    require_shape(p, "psf", {cfg_.bands, sensor_size(), sensor_size()});
    const std::size_t batch = std::size_t(sc.shape(0)), h = std::size_t(sc.shape(2)), w = std::size_t(sc.shape(3));
    std::vector<RealStack> cubes(batch, RealStack(cfg_.bands, h, w));
    for (std::size_t i = 0; i < batch; ++i)
      std::copy(sc.data() + i * cubes[i].size(), sc.data() + (i + 1) * cubes[i].size(), cubes[i].data.begin());
    const RealStack ps = to_stack(p);
    std::vector<RealStack> rgb;
    {
      py::gil_scoped_release unlocked;
      cam_->set_psf(ps);
      SkipOptions exact;
      exact.exact = true;
      rgb = cam_->images(cubes, exact);
    }
    ++camera_calls_;
    Array out({py::ssize_t(batch), py::ssize_t(3), py::ssize_t(h), py::ssize_t(w)});
    for (std::size_t i = 0; i < batch; ++i) std::copy(rgb[i].data.begin(), rgb[i].data.end(), out.mutable_data() + i * 3 * h * w);
    return out;
  }

  // grad_rgb: batch x 3 x H x W, the gradient with respect to the last camera() result ->
  // (gradient on its psf, bands x S x S; gradient on its scenes, batch x bands x H x W).
  py::tuple camera_vjp(const py::handle& grad_obj) {
    if (camera_calls_ == 0) throw py::value_error("grad_rgb: no camera() call to take the adjoint of");
    const Array g = checked(grad_obj, "grad_rgb", 4);
    if (g.shape(1) != 3) throw py::value_error("grad_rgb: shape " + shape_of(g) + "; expected (batch, 3, H, W)");
    const std::size_t batch = std::size_t(g.shape(0)), h = std::size_t(g.shape(2)), w = std::size_t(g.shape(3));
    std::vector<RealStack> gr(batch, RealStack(3, h, w));
    for (std::size_t i = 0; i < batch; ++i)
      std::copy(g.data() + i * 3 * h * w, g.data() + (i + 1) * 3 * h * w, gr[i].data.begin());
    Camera::Gradient res;
    {
      py::gil_scoped_release unlocked;
      res = cam_->vjp(gr, true);
    }
    Array gs({py::ssize_t(batch), py::ssize_t(cfg_.bands), py::ssize_t(h), py::ssize_t(w)});
    for (std::size_t i = 0; i < batch; ++i)
      std::copy(res.scenes[i].data.begin(), res.scenes[i].data.end(), gs.mutable_data() + i * cfg_.bands * h * w);
    return py::make_tuple(from_stack(res.psf), gs);
  }

 private:
  SystemConfig cfg_;
  Precision prec_;
  std::shared_ptr<Runtime> rt_;
  std::unique_ptr<HeightMapPsfSource> sim_;
  std::unique_ptr<Camera> cam_;
  std::uint64_t psf_calls_ = 0, camera_calls_ = 0;
};

Quantizer make_quantizer(int levels, const std::string& placement) {
  Quantizer q;
  q.levels = levels;
  q.placement = placement_from_string(placement);
  q.validate();
  return q;
}

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

  m.def("preset_json", [](const std::string& name) { return config_to_json_text(preset_config(name)); }, py::arg("name"),
        "The configuration of a preset (small, paper) as JSON text.");
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
      .def(py::init<const std::string&, const std::string&, const std::string&, const std::string&>(), py::arg("config_json"),
           py::arg("origin"), py::arg("device"), py::arg("precision"))
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
      .def("psf", &Optics::psf, py::arg("height_m"))
      .def("psf_vjp", &Optics::psf_vjp, py::arg("grad_psf"))
      .def("read_psf", &Optics::read_psf, py::arg("path"))
      .def("camera", &Optics::camera, py::arg("scene"), py::arg("psf"))
      .def("camera_vjp", &Optics::camera_vjp, py::arg("grad_rgb"));

  m.def(
      "quantize",
      [](const py::handle& h_obj, double h_max_m, int levels, const std::string& placement) {
        const Array h = checked(h_obj, "height_m", 2);
        if (!(h_max_m > 0) || !std::isfinite(h_max_m)) throw py::value_error("h_max_m: " + std::to_string(h_max_m) + "; expected > 0");
        Map2D mp(std::size_t(h.shape(0)), std::size_t(h.shape(1)));
        std::copy(h.data(), h.data() + h.size(), mp.data.begin());
        return from_map(quantize_heights(mp, h_max_m, make_quantizer(levels, placement), 1.0));
      },
      py::arg("height_m"), py::arg("h_max_m"), py::arg("levels"), py::arg("placement") = "inclusive");
  m.def(
      "lens_design",
      [](const std::string& config_json, double wavelength_nm) {
        return from_map(lens_design(config_from_json_text(config_json), wavelength_nm));
      },
      py::arg("config_json"), py::arg("wavelength_nm"));

  m.def(
      "estimate_prior",
      [](const py::handle& scenes_obj, std::size_t bins) {
        const Array s = checked(scenes_obj, "scenes", 4);
        std::vector<RealStack> v;
        const std::size_t per = std::size_t(s.shape(1) * s.shape(2) * s.shape(3));
        for (py::ssize_t i = 0; i < s.shape(0); ++i) {
          RealStack c(std::size_t(s.shape(1)), std::size_t(s.shape(2)), std::size_t(s.shape(3)));
          std::copy(s.data() + std::size_t(i) * per, s.data() + std::size_t(i + 1) * per, c.data.begin());
          v.push_back(std::move(c));
        }
        const wiener::SpectralPrior p = wiener::estimate_prior(v, bins);
        Array cov({py::ssize_t(p.bins), py::ssize_t(p.bands), py::ssize_t(p.bands)});
        std::copy(p.cov.begin(), p.cov.end(), cov.mutable_data());
        return cov;
      },
      py::arg("scenes"), py::arg("bins") = 16);
  m.def(
      "wiener_decode",
      [](const py::handle& y_obj, const py::handle& psf_obj, const py::handle& srf_obj, const py::handle& cov_obj,
         double noise_sigma) {
        const Array y = checked(y_obj, "y", 3), p = checked(psf_obj, "psf", 3), s = checked(srf_obj, "srf", 2),
                    c = checked(cov_obj, "prior", 3);
        wiener::SpectralPrior pr;
        pr.bins = std::size_t(c.shape(0));
        pr.bands = std::size_t(c.shape(1));
        pr.rows = std::size_t(y.shape(1));
        pr.cols = std::size_t(y.shape(2));
        pr.cov.assign(c.data(), c.data() + c.size());
        Eigen::MatrixXd srf(s.shape(0), s.shape(1));
        for (py::ssize_t i = 0; i < s.shape(0); ++i)
          for (py::ssize_t j = 0; j < s.shape(1); ++j) srf(i, j) = s.at(i, j);
        const RealStack psf = to_stack(p);
        return from_stack(wiener::decode(to_stack(y), wiener::psf_to_otf(psf, pr.rows, pr.cols), srf, pr, noise_sigma));
      },
      py::arg("y"), py::arg("psf"), py::arg("srf"), py::arg("prior"), py::arg("noise_sigma"));

  m.def(
      "read_cube",
      [](const std::string& path, const std::string& key) {
        CubeReadOptions o;
        o.key = key;
        return from_stack(read_cube(path, o));
      },
      py::arg("path"), py::arg("key") = "");
  m.def(
      "read_design",
      [](const std::string& path) {
        const Design d = read_design(path);
        return py::make_tuple(from_map(d.height_m), d.pitch_m, d.levels_m);
      },
      py::arg("path"));
  m.def(
      "write_design",
      [](const std::string& path, const py::handle& h_obj, double pitch_m, const std::vector<double>& levels_m) {
        const Array h = checked(h_obj, "height_m", 2);
        Design d;
        d.height_m = Map2D(std::size_t(h.shape(0)), std::size_t(h.shape(1)));
        std::copy(h.data(), h.data() + h.size(), d.height_m.data.begin());
        d.pitch_m = pitch_m;
        d.levels_m = levels_m;
        write_design(path, d, {{"written_by", "qdo python " QDO_VERSION}});
      },
      py::arg("path"), py::arg("height_m"), py::arg("pitch_m"), py::arg("levels_m") = std::vector<double>{});
  m.def(
      "write_rgb_png",
      [](const std::string& path, const py::handle& rgb_obj) {
        const Array a = checked(rgb_obj, "rgb", 3);
        if (a.shape(0) != 3) throw py::value_error("rgb: shape " + shape_of(a) + "; expected (3, H, W)");
        write_rgb_png(path, to_stack(a));
      },
      py::arg("path"), py::arg("rgb"));
  m.def(
      "write_montage_png",
      [](const std::string& path, const py::handle& stack_obj, const std::vector<double>& wavelengths_nm, double gamma) {
        write_montage_png(path, to_stack(checked(stack_obj, "stack", 3)), wavelengths_nm, gamma);
      },
      py::arg("path"), py::arg("stack"), py::arg("wavelengths_nm") = std::vector<double>{}, py::arg("gamma") = 0.5);
  m.def(
      "write_map_png",
      [](const std::string& path, const py::handle& map_obj) {
        const Array a = checked(map_obj, "map", 2);
        Map2D mp(std::size_t(a.shape(0)), std::size_t(a.shape(1)));
        std::copy(a.data(), a.data() + a.size(), mp.data.begin());
        write_map_png(path, mp);
      },
      py::arg("path"), py::arg("map"));
  m.def(
      "read_h5",
      [](const std::string& path, const std::string& name) {
        const H5Dataset d = h5_read(path, name);
        std::vector<py::ssize_t> shape(d.shape.begin(), d.shape.end());
        Array a(shape);
        std::copy(d.data.begin(), d.data.end(), a.mutable_data());
        return a;
      },
      py::arg("path"), py::arg("name"));
}
