// The parts of qdo's Python extension: each adds its functions or classes to the module `_qdo`.
// PYBIND11_MODULE (qdo_module.cpp) calls them in this order, after its own functions.
#pragma once
#include <pybind11/pybind11.h>

void bind_optics(pybind11::module_& m);  // qdo_optics.cpp: the class Optics (PSF and camera on a device)
void bind_design(pybind11::module_& m);  // qdo_design.cpp: quantize, lens_design
void bind_wiener(pybind11::module_& m);  // qdo_wiener.cpp: estimate_prior, wiener_decode
void bind_io(pybind11::module_& m);      // qdo_io.cpp: cubes, designs, PNG images, figures, HDF5 datasets
