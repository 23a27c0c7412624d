// qdo as a library: a standalone program, built against an installed qdo (find_package(qdo),
// target qdo::qdo), that computes the PSF stack of a random DOE for the "small" preset on the
// OpenCL device QDO_DEVICE selects (as `qdo psf --preset small` does, without the files).
//
// Prints the number of bands, N, and each band's PSF sum; exits 1 when any sum is non-finite or
// differs from 1 by more than 1e-3 (each band of the PSF stack is normalised to 1), 2 on an error.
#include <cmath>
#include <cstdio>
#include <exception>
#include <random>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/runtime/types.hpp"

int main() {
  try {
    const qdo::SystemConfig cfg = qdo::preset_config("small");  // N = 256, 31 bands 400..700 nm
    cfg.validate();

    // Heights: N x N, row-major, metres, uniform in [0, h_max] (one 2π phase at the base wavelength).
    std::mt19937_64 rng(1);
    std::uniform_real_distribution<double> u(0.0, cfg.h_max_m());
    qdo::Map2D heights(cfg.n, cfg.n);
    for (double& h : heights.data) h = u(rng);

    qdo::Runtime rt;  // device from QDO_DEVICE (cpu, gpu, ...), else the first GPU, else the first CPU
    qdo::Simulator sim(rt, cfg, qdo::Precision::F32);
    sim.set_heights(heights);
    sim.compute_psf();
    // PSF stack: bands x N x N, row-major, fraction of the band's energy per sample.
    const qdo::RealStack psf = sim.psf_native();
    const std::vector<double> wl = cfg.wavelengths_nm();  // bands

    std::printf("device: %s (%s)\n", rt.info().name.c_str(), rt.info().platform.c_str());
    std::printf("bands: %zu\nN: %zu\n", psf.planes, psf.rows);
    if (psf.planes != cfg.bands || psf.rows != cfg.n || psf.cols != cfg.n) {
      std::fprintf(stderr, "consumer: PSF stack is %zu x %zu x %zu, expected %zu x %zu x %zu\n", psf.planes, psf.rows,
                   psf.cols, cfg.bands, cfg.n, cfg.n);
      return 1;
    }
    double worst = 0;
    bool ok = true;
    for (std::size_t b = 0; b < psf.planes; ++b) {
      const double* p = psf.plane(b);  // N x N
      double sum = 0;
      for (std::size_t i = 0; i < psf.plane_size(); ++i) sum += p[i];
      const double dev = std::fabs(sum - 1.0);
      if (!std::isfinite(sum) || !(dev <= 1e-3)) ok = false;
      if (std::isfinite(dev) && dev > worst) worst = dev;
      std::printf("band %zu (%.0f nm): psf sum %.6f\n", b, wl[b], sum);
    }
    if (!ok) {
      std::fprintf(stderr, "consumer: a band's PSF sum is non-finite or differs from 1 by more than 1e-3\n");
      return 1;
    }
    std::printf("consumer: ok (max |sum - 1| = %.2e)\n", worst);
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "consumer: %s\n", e.what());
    return 2;
  }
}
