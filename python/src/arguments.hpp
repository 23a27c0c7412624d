// Argument checking and conversion of qdo's Python extension (python/src: qdo_module.cpp and the
// parts it binds): NumPy arrays of any byte order and layout checked (dtype by kind and size, shape, finiteness) and copied to C
// order, scalars, strings and paths checked and named, and the conversions between arrays and
// qdo's Map2D / RealStack (row-major, planes x rows x cols). A bad argument raises ValueError
// naming it and what is allowed (never printing an array); a copy that fails, MemoryError.
#pragma once
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include <cmath>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "qdo/runtime/error.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo::python {

namespace py = pybind11;

using Array = py::array_t<double, py::array::c_style>;

// ---------- Arguments ----------

// ValueError / MemoryError as pybind11 exceptions (raised with the GIL held).
[[noreturn]] inline void value_error(const std::string& msg) { throw py::value_error(msg); }
[[noreturn]] inline void memory_error(const std::string& msg) {
  PyErr_SetString(PyExc_MemoryError, msg.c_str());
  throw py::error_already_set();
}

inline std::string type_name(const py::handle& o) { return py::str(py::type::of(o).attr("__name__")); }

// A value for a message: its str() cut to 40 characters (a huge int or a long string stays short).
inline std::string short_str(const py::handle& o) {
  std::string s = py::str(o);
  return s.size() > 40 ? s.substr(0, 37) + "..." : s;
}

// One dimension of an expected shape: a fixed length, or a label ("H", "batch") for any length >= 1.
struct Dim {
  py::ssize_t n = -1;
  const char* label = nullptr;
  Dim(std::size_t v) : n(py::ssize_t(v)) {}  // NOLINT(google-explicit-constructor): {n, n} reads as a shape
  Dim(int v) : n(v) {}                       // NOLINT(google-explicit-constructor)
  Dim(const char* l) : label(l) {}           // NOLINT(google-explicit-constructor)
};

inline std::string shape_text(const py::array& a) {
  std::string s = "(";
  for (py::ssize_t k = 0; k < a.ndim(); ++k) s += (k ? ", " : "") + std::to_string(a.shape(k));
  return s + (a.ndim() == 1 ? ",)" : ")");
}

inline std::string shape_text(const std::vector<Dim>& want) {
  std::string s = "(", any;
  for (std::size_t k = 0; k < want.size(); ++k) {
    s += k ? ", " : "";
    if (want[k].label) {
      s += want[k].label;
      any += (any.empty() ? "" : ", ") + std::string(want[k].label);
    } else {
      s += std::to_string(want[k].n);
    }
  }
  return s + ")" + (any.empty() ? "" : " with " + any + " >= 1");
}

// The argument `name` as a C-order float64 array of the shape `want` (its rank = want.size()).
// The dtype is judged by kind and size (any float64: '<f8', '=f8', '>f8', h5py's descriptors),
// not by identity with NumPy's own descriptor; a big-endian or non-contiguous array (slices with
// steps, transposes, Fortran order, broadcasts) is copied. ValueError for another type, dtype,
// rank or shape (checked before any copy) or a non-finite entry; MemoryError when the copy fails.
inline Array checked(const py::handle& obj, const char* name, const std::vector<Dim>& want) {
  if (!py::isinstance<py::array>(obj))
    value_error(std::string(name) + ": expected a NumPy float64 array, got " + type_name(obj));
  const py::array a = py::reinterpret_borrow<py::array>(obj);
  const py::dtype dt = a.dtype();
  if (dt.kind() != 'f' || dt.itemsize() != 8)
    value_error(std::string(name) + ": dtype " + short_str(dt.attr("name")) +
                "; expected float64 (convert it with .astype(numpy.float64))");
  const std::string expected = shape_text(want);
  if (std::size_t(a.ndim()) != want.size())
    value_error(std::string(name) + ": " + std::to_string(a.ndim()) + " dimensions; expected " + std::to_string(want.size()) +
                ", shape " + expected);
  for (std::size_t k = 0; k < want.size(); ++k) {
    const py::ssize_t got = a.shape(py::ssize_t(k));
    if (want[k].label ? got < 1 : got != want[k].n)
      value_error(std::string(name) + ": shape " + shape_text(a) + "; expected " + expected);
  }
  Array c = Array::ensure(a);  // no copy for a C-order native float64 array
  if (!c)
    memory_error(std::string(name) + ": no memory for a C-order float64 copy of its shape " + shape_text(a) + " (" +
                 to_str(double(a.size()) * 8.0 / 1048576.0) + " MiB)");
  const double* p = c.data();
  for (py::ssize_t i = 0; i < c.size(); ++i)
    if (!std::isfinite(p[i])) value_error(std::string(name) + ": non-finite value at flat index " + std::to_string(i));
  return c;
}

// module.name (or the module when name is null), looked up once and kept for the life of the
// process: a handle, deliberately never released (a static py::object would be released by the
// C++ exit handlers after the interpreter is gone).
inline py::handle python_global(const char* module, const char* name) {
  py::object m = py::module_::import(module);
  return (name ? py::object(m.attr(name)) : m).release();
}

inline bool is_real_number(const py::handle& o) {
  if (py::isinstance<py::array>(o)) {  // a 0-d array of a real kind counts as a number
    const py::array a = py::reinterpret_borrow<py::array>(o);
    const char k = a.dtype().kind();
    return a.ndim() == 0 && (k == 'f' || k == 'i' || k == 'u');
  }
  static const py::handle real = python_global("numbers", "Real");
  return py::isinstance(o, real) && !py::isinstance<py::bool_>(o);
}

// A finite real number (Python or NumPy int or float, a 0-d array); ValueError naming `name` otherwise.
inline double real_arg(const py::handle& o, const char* name) {
  if (!is_real_number(o)) value_error(std::string(name) + ": expected a number, got " + type_name(o));
  const double v = py::float_(py::reinterpret_borrow<py::object>(o));
  if (!std::isfinite(v)) value_error(std::string(name) + ": " + short_str(o) + "; expected a finite number");
  return v;
}

// A real number > 0 (finite).
inline double positive_arg(const py::handle& o, const char* name) {
  const double v = real_arg(o, name);
  if (!(v > 0)) value_error(std::string(name) + ": " + short_str(o) + "; expected a finite number > 0");
  return v;
}

// An integer (Python or NumPy; not a bool or a float) in [lo, hi]; ValueError naming `name`,
// the value and the range otherwise, before anything of that size is allocated.
inline long long int_arg(const py::handle& o, const char* name, long long lo, long long hi) {
  static const py::handle integral = python_global("numbers", "Integral");
  const std::string range = "; expected an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]";
  if (!py::isinstance(o, integral) || py::isinstance<py::bool_>(o))
    value_error(std::string(name) + ": " + type_name(o) + " " + short_str(py::repr(o)) + range);
  const py::int_ i = py::reinterpret_borrow<py::object>(o);
  int overflow = 0;
  const long long v = PyLong_AsLongLongAndOverflow(i.ptr(), &overflow);
  if (overflow || v < lo || v > hi) value_error(std::string(name) + ": " + short_str(o) + range);
  return v;
}

inline std::string str_arg(const py::handle& o, const char* name) {
  if (!py::isinstance<py::str>(o)) value_error(std::string(name) + ": expected a str, got " + type_name(o));
  return py::str(o);
}

inline bool bool_arg(const py::handle& o, const char* name) {
  static const py::handle np_bool = python_global("numpy", "bool_");
  if (!py::isinstance<py::bool_>(o) && !py::isinstance(o, np_bool))
    value_error(std::string(name) + ": expected True or False, got " + type_name(o));
  return py::cast<bool>(py::bool_(py::reinterpret_borrow<py::object>(o)));
}

// A file path: str, bytes or os.PathLike (os.fspath), non-empty.
inline std::string path_arg(const py::handle& o, const char* name) {
  static const py::handle os = python_global("os", nullptr);
  if (!py::isinstance<py::str>(o) && !py::isinstance<py::bytes>(o) && !py::hasattr(o, "__fspath__"))
    value_error(std::string(name) + ": expected a path (str or os.PathLike), got " + type_name(o));
  const py::object s = os.attr("fsdecode")(os.attr("fspath")(o));
  if (!py::isinstance<py::str>(s)) value_error(std::string(name) + ": expected a path (str or os.PathLike), got " + type_name(o));
  const std::string p = py::str(s);
  if (p.empty()) value_error(std::string(name) + ": an empty path; expected a file name");
  return p;
}

// A 1-D sequence (list, tuple, array) of finite real numbers, possibly empty.
inline std::vector<double> reals_arg(const py::handle& o, const char* name) {
  if (py::isinstance<py::str>(o) || py::isinstance<py::bytes>(o) || !py::hasattr(o, "__len__"))
    value_error(std::string(name) + ": expected a sequence of numbers, got " + type_name(o));
  std::vector<double> v;
  for (const py::handle item : o) {
    if (!is_real_number(item))
      value_error(std::string(name) + ": item " + std::to_string(v.size()) + " is a " + type_name(item) + "; expected a number");
    const double x = py::float_(py::reinterpret_borrow<py::object>(item));
    if (!std::isfinite(x)) value_error(std::string(name) + ": item " + std::to_string(v.size()) + " = " + short_str(item) + "; expected a finite number");
    v.push_back(x);
  }
  return v;
}

// ---------- Conversions (shapes as the callers checked them) ----------

inline Map2D to_map(const Array& a) {  // rows x cols
  Map2D m(std::size_t(a.shape(0)), std::size_t(a.shape(1)));
  std::copy(a.data(), a.data() + a.size(), m.data.begin());
  return m;
}

inline RealStack to_stack(const Array& a) {  // planes x rows x cols
  RealStack s(std::size_t(a.shape(0)), std::size_t(a.shape(1)), std::size_t(a.shape(2)));
  std::copy(a.data(), a.data() + a.size(), s.data.begin());
  return s;
}

// a: batch x planes x rows x cols -> one planes x rows x cols stack per batch entry.
inline std::vector<RealStack> to_stacks(const Array& a) {
  const std::size_t batch = std::size_t(a.shape(0));
  std::vector<RealStack> v(batch, RealStack(std::size_t(a.shape(1)), std::size_t(a.shape(2)), std::size_t(a.shape(3))));
  for (std::size_t i = 0; i < batch; ++i) std::copy(a.data() + i * v[i].size(), a.data() + (i + 1) * v[i].size(), v[i].data.begin());
  return v;
}

inline Array from_stack(const RealStack& s) {
  Array a({py::ssize_t(s.planes), py::ssize_t(s.rows), py::ssize_t(s.cols)});
  std::copy(s.data.begin(), s.data.end(), a.mutable_data());
  return a;
}

// Same-shape stacks (planes x rows x cols each) -> batch x planes x rows x cols.
inline Array from_stacks(const std::vector<RealStack>& v, std::size_t planes, std::size_t rows, std::size_t cols) {
  Array a({py::ssize_t(v.size()), py::ssize_t(planes), py::ssize_t(rows), py::ssize_t(cols)});
  for (std::size_t i = 0; i < v.size(); ++i) std::copy(v[i].data.begin(), v[i].data.end(), a.mutable_data() + i * planes * rows * cols);
  return a;
}

inline Array from_map(const Map2D& m) {
  Array a({py::ssize_t(m.rows), py::ssize_t(m.cols)});
  std::copy(m.data.begin(), m.data.end(), a.mutable_data());
  return a;
}

}  // namespace qdo::python
