// The paper release's image formation, exactly as measured (REFERENCE §1), offered for comparing
// with the paper's numbers. Per band, for a scene on the sensor grid (S x S, one value per 2x2 DOE
// samples in the paper's geometry) and the PSF on the DOE grid (N x N, axis at (N/2, N/2)):
//   1. bilinear resize of the scene to N x N (TF2 tf.image.resize, BILINEAR: half-pixel centres,
//      edge clamp, no antialias);
//   2. symmetric (mirror, edge repeated) padding by `before` = ceil((N - S)/2) and `after` =
//      floor((N - S)/2) per axis to G x G, G = 2N - S (1536 at the paper preset);
//   3. circular convolution over G x G with the PSF placed as the release's psf2otf places it:
//      zero-padded by psf_before = (G - N)/2 + 1 and psf_after = (G - N)/2 - 1 (even G - N; odd:
//      ceil and floor), then circularly shifted so padded index split = G - (G + 1)/2 goes to 0.
//      For even G - N the PSF's axis lands one DOE sample (4 µm) past the origin in both axes: the
//      image moves by half a sensor pixel (a 2-tap average [x(i-1) + x(i)]/2 per axis for a point
//      PSF at N = 2S);
//   4. crop [before, before + N) per axis and bilinear resize to S x S.
// Not circular on the scene grid and not linear; the sensor integration (Eq. 7, per pixel) is
// linear and commutes with the resizes, so the RGB image is ref::sensor_integrate of the result.
// Noise: the release adds its training noise to the hyperspectral image on the DOE grid before
// the sensor; qdo adds its noise model to the RGB image (not reproduced here).
#pragma once
#include <CL/opencl.hpp>

#include <cstddef>

#include "qdo/runtime/runtime.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

struct ReleaseGeometry {
  std::size_t s = 0, n = 0, g = 0;          // scene side S, PSF side N, padded side G = 2N - S
  std::size_t before = 0, after = 0;        // mirror padding of the up-sampled scene
  std::size_t psf_before = 0, psf_after = 0;  // zero padding of the PSF (psf2otf)
  std::size_t split = 0;                    // ifftshift: padded index `split` goes to 0
};
// Throws InputError naming the argument unless S >= 1 and N >= S + 2 (the release's crop
// [before : -after] is empty for after = 0).
ReleaseGeometry release_geometry(std::size_t s, std::size_t n);

// The same on the OpenCL device (kernels/release.cl, FFTs of G x G per band). float32 or float64.
class ReleaseImager {
 public:
  // bands, scene side S, PSF side N (release_geometry(S, N) must hold).
  ReleaseImager(Runtime& rt, Precision p, std::size_t bands, std::size_t s, std::size_t n);
  ReleaseImager(const ReleaseImager&) = delete;
  ReleaseImager& operator=(const ReleaseImager&) = delete;
  // The PSF stack (bands x N x N, finite); its OTF stays on the device for later blur() calls.
  void set_psf(const RealStack& psf_native);
  // cube: bands x S x S, finite -> bands x S x S (set_psf first).
  RealStack blur(const RealStack& cube);
  const ReleaseGeometry& geometry() const { return geo_; }

 private:
  Runtime& rt_;
  Precision prec_;
  std::size_t bands_;
  ReleaseGeometry geo_;
  bool have_psf_ = false;
  cl::Kernel k_up_pad_, k_place_, k_cmul_, k_crop_down_;
  cl::Buffer psf_, otf_, scene_, work_, out_;
};

}  // namespace qdo
