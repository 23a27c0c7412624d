// The design functions of qdo's Python extension (qdo_module.cpp has the conventions): the
// quantizer of a height map and the lens design of a configuration.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <string>

#include "arguments.hpp"
#include "qdo_bindings.hpp"
#include "qdo/data/config.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/runtime/error.hpp"

namespace py = pybind11;
using namespace qdo;
using namespace qdo::python;

namespace {

Quantizer make_quantizer(long long levels, const std::string& placement) {
  Quantizer q;
  q.levels = int(levels);
  q.placement = placement_from_string(placement);
  q.validate();
  return q;
}

}  // namespace

void bind_design(py::module_& m) {
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
}
