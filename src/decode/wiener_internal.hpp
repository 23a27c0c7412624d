// Private to the host Wiener decoder (wiener.cpp, wiener_model.cpp): the FFT helpers, the scene
// checks and the per-frequency gather / scatter they share. Not installed; the public API is
// include/qdo/decode/wiener.hpp.
#pragma once
#include <fftw3.h>

#include <Eigen/Dense>

#include <cstddef>
#include <vector>

#include "qdo/runtime/error.hpp"
#include "qdo/runtime/fftw2.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo::wiener::detail {

using Eigen::MatrixXcd;
using Eigen::MatrixXd;
using Eigen::VectorXcd;

enum class Scale { None, InverseN };

inline void fft2(ComplexStack& s, int sign, Scale scale) { fftw2(s, sign == FFTW_FORWARD, scale == Scale::InverseN); }

inline ComplexStack to_complex(const RealStack& r) {
  ComplexStack c(r.planes, r.rows, r.cols);
  for (std::size_t i = 0; i < r.size(); ++i) c.data[i] = r.data[i];
  return c;
}

inline ComplexStack forward_fft(const RealStack& r) {
  ComplexStack c = to_complex(r);
  fft2(c, FFTW_FORWARD, Scale::None);
  return c;
}

// Real part of the normalised inverse transform.
inline RealStack inverse_fft_real(ComplexStack c) {
  fft2(c, FFTW_BACKWARD, Scale::InverseN);
  RealStack r(c.planes, c.rows, c.cols);
  for (std::size_t i = 0; i < c.size(); ++i) r.data[i] = c.data[i].real();
  return r;
}

inline void check_scenes(const std::vector<RealStack>& scenes, std::size_t bands, std::size_t rows, std::size_t cols) {
  if (scenes.empty()) reject("scenes.size()", 0, "at least one scene");
  for (std::size_t s = 0; s < scenes.size(); ++s)
    if (scenes[s].planes != bands || scenes[s].rows != rows || scenes[s].cols != cols)
      reject("scenes[" + to_str(s) + "]", shape(scenes[s]), shape(bands, rows, cols) + " (the OTF's shape)");
}

inline VectorXcd gather(const ComplexStack& s, std::size_t f) {
  VectorXcd v(static_cast<Eigen::Index>(s.planes));
  for (std::size_t b = 0; b < s.planes; ++b) v(static_cast<Eigen::Index>(b)) = s.data[b * s.plane_size() + f];
  return v;
}
inline void scatter(ComplexStack& s, std::size_t f, const VectorXcd& v) {
  for (std::size_t b = 0; b < s.planes; ++b) s.data[b * s.plane_size() + f] = v(static_cast<Eigen::Index>(b));
}

}  // namespace qdo::wiener::detail
