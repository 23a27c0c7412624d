// The files of qdo's Python extension (qdo_module.cpp has the conventions): spectral cubes and
// PNG band folders, designs, RGB PNG images, PSF and height-map figures, HDF5 datasets.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <filesystem>
#include <string>
#include <vector>

#include "arguments.hpp"
#include "qdo_bindings.hpp"
#include "qdo/data/config.hpp"
#include "qdo/data/datasets.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/figure.hpp"
#include "qdo/data/io.hpp"
#include "qdo/data/scenes.hpp"

namespace py = pybind11;
using namespace qdo;
using namespace qdo::python;

namespace {

// The scene a cube file or PNG band folder gives `qdo simulate --scene PATH [--key KEY]
// [--resample-bands]` under configuration cfg (scene_from_options, qdo/design/option_inputs.hpp: the same
// library calls in the same order): bands x H x W on cfg's band grid, in [0, 1].
// The configuration a read_cube call's scene must fit: JSON text as the Python wrapper gives it.
SystemConfig scene_config(const py::handle& config_json, const py::handle& origin) {
  SystemConfig c = config_from_json_text(str_arg(config_json, "config"), str_arg(origin, "config"));
  c.validate();
  return c;
}

}  // namespace

void bind_io(py::module_& m) {
  m.def(
      "read_cube",
      [](const py::handle& path, const py::handle& key, const py::handle& config_json, const py::handle& origin,
         const py::handle& resample) {
        const std::string p = path_arg(path, "path"), k = str_arg(key, "key");
        const bool rs = bool_arg(resample, "resample_bands");
        return from_stack(qdo::read_scene(scene_config(config_json, origin), p, k, rs, "key"));
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
