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
//
// The bindings are split by concern (qdo_bindings.hpp): the class Optics (qdo_optics.cpp), the
// design functions (qdo_design.cpp), the Wiener decoder (qdo_wiener.cpp) and the files (qdo_io.cpp).
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <string>

#include "arguments.hpp"
#include "qdo_bindings.hpp"
#include "qdo/data/config.hpp"
#include "qdo/data/data_root.hpp"
#include "qdo/data/datasets.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/runtime.hpp"

namespace py = pybind11;
using namespace qdo;
using namespace qdo::python;

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
      py::arg("root") = py::none(), "Where datasets are looked for (include/qdo/data/data_root.hpp), as a dict.");
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

  // The rest, by concern (qdo_bindings.hpp), in the order the module always defined them.
  bind_optics(m);
  bind_design(m);
  bind_wiener(m);
  bind_io(m);
}
