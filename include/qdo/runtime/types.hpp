// Core array types shared by every stage. All arrays are dense, row-major, C order.
#pragma once
#include <complex>
#include <cstddef>
#include <string>
#include <vector>

namespace qdo {

using cdouble = std::complex<double>;

// A stack of 2-D planes: shape (planes, rows, cols), element (p, y, x) at
// data[(p * rows + y) * cols + x]. Used for cubes (bands x H x W), PSF stacks
// (bands x N x N), sensor images (3 x H x W) and complex fields.
template <typename T>
struct Stack {
  std::size_t planes = 0, rows = 0, cols = 0;
  std::vector<T> data;

  Stack() = default;
  Stack(std::size_t p, std::size_t r, std::size_t c, T fill = T{})
      : planes(p), rows(r), cols(c), data(p * r * c, fill) {}

  std::size_t plane_size() const { return rows * cols; }
  std::size_t size() const { return data.size(); }
  T& operator()(std::size_t p, std::size_t y, std::size_t x) { return data[(p * rows + y) * cols + x]; }
  const T& operator()(std::size_t p, std::size_t y, std::size_t x) const {
    return data[(p * rows + y) * cols + x];
  }
  T* plane(std::size_t p) { return data.data() + p * rows * cols; }
  const T* plane(std::size_t p) const { return data.data() + p * rows * cols; }
};

// "P x R x C", for messages naming a shape.
inline std::string shape(std::size_t p, std::size_t r, std::size_t c) {
  return std::to_string(p) + " x " + std::to_string(r) + " x " + std::to_string(c);
}
template <typename T>
std::string shape(const Stack<T>& s) {
  return shape(s.planes, s.rows, s.cols);
}

using RealStack = Stack<double>;      // e.g. cube (bands x H x W), PSF (bands x N x N)
using ComplexStack = Stack<cdouble>;  // fields (bands x M x M)

// A single 2-D map, shape (rows, cols), row-major: element (y, x) at data[y * cols + x].
struct Map2D {
  std::size_t rows = 0, cols = 0;
  std::vector<double> data;
  Map2D() = default;
  Map2D(std::size_t r, std::size_t c, double fill = 0.0) : rows(r), cols(c), data(r * c, fill) {}
  double& operator()(std::size_t y, std::size_t x) { return data[y * cols + x]; }
  const double& operator()(std::size_t y, std::size_t x) const { return data[y * cols + x]; }
};

}  // namespace qdo
