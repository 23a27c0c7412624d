// The adjoint table (suite `adjoint`, run by tests/test_adjoint.cpp): every forward/adjoint pair of
// the PSF chain, the parameterizations and the quantizer, the radial engine, the encoders, the
// design loop, the Wiener decoder and joint training, one Stage row each, all through the one
// ladder body of tests/adjoint_ladder.hpp.
// Each group of rows is built next to the fixtures it needs: the PSF chain's, the camera
// references' and the DOE's in test_adjoint.cpp, the radial engine's in test_radial.cpp, the
// encoders' in test_encoders.cpp, the design loop's in test_design.cpp, the Wiener decoder's in
// test_wiener.cpp, joint training's in test_joint.cpp, the raw stage's in test_raw.cpp. (The camera operator's
// and the device Wiener objective's rows run in their own suites, test_camera.cpp and
// test_wiener_device.cpp, through the same body.)
#pragma once
#include <complex>
#include <vector>

#include "adjoint_ladder.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo::test {

namespace adjoint_rows {
std::vector<Stage> psf_chain();  // DOE phase, propagation, resampling, normalisation, heights -> PSF
std::vector<Stage> camera();     // convolution and sensor integration (reference); heights -> images (device)
std::vector<Stage> doe();        // parameter expansion, quantizer offsets
std::vector<Stage> radial();     // the radial engine's linear stages and its whole chain
std::vector<Stage> encoders();   // CASSI and the DOE camera as linear encoders
std::vector<Stage> design();     // the design loop's gradient in every mode, 2-D and radial paths
std::vector<Stage> wiener();     // PSF -> OTF, the Wiener objectives' gradients (OTF and PSF)
std::vector<Stage> joint();      // the patch camera (PSF -> patch images), the joint step's PSF gradient
std::vector<Stage> raw();        // the sensor as built: mosaic, gain, black level, clip mask (reference and device)
}  // namespace adjoint_rows

// A complex vector as interleaved (re, im) reals and back: the ladder's real inner product of two
// such vectors is Re <a, b>, so the adjoint of a complex-linear map A is A^H.
inline std::vector<double> interleave(const std::vector<cdouble>& z) {
  std::vector<double> x(2 * z.size());
  for (std::size_t i = 0; i < z.size(); ++i) {
    x[2 * i] = z[i].real();
    x[2 * i + 1] = z[i].imag();
  }
  return x;
}
inline std::vector<cdouble> deinterleave(const std::vector<double>& x) {
  std::vector<cdouble> z(x.size() / 2);
  for (std::size_t i = 0; i < z.size(); ++i) z[i] = cdouble(x[2 * i], x[2 * i + 1]);
  return z;
}

}  // namespace qdo::test
