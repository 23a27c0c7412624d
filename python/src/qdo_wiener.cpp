// The Wiener decoder of qdo's Python extension (qdo_module.cpp has the conventions): the spectral
// prior of a set of scenes, and the CPU decoder of sensor images with it.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <cstdint>
#include <string>

#include "arguments.hpp"
#include "qdo_bindings.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/decode/tiled.hpp"
#include "qdo/decode/wiener.hpp"

namespace py = pybind11;
using namespace qdo;
using namespace qdo::python;

namespace {

// estimate_prior's bins: 4096 radial bins already resolve every frequency radius of a
// 5000-pixel-wide grid; the covariances take bins x bands x bands doubles, at most 2^27 (1 GiB).
constexpr long long kMaxPriorBins = 4096;
constexpr double kMaxPriorValues = double(std::size_t(1) << 27);

}  // namespace

void bind_wiener(py::module_& m) {
  m.def(
      "estimate_prior",
      [](const py::handle& scenes_obj, const py::handle& bins_obj) {
        const std::size_t bins = std::size_t(int_arg(bins_obj, "bins", 2, kMaxPriorBins));
        const Array s = checked(scenes_obj, "scenes", {"count", "bands", "H", "W"});
        const double values = double(bins) * double(s.shape(1)) * double(s.shape(1));
        if (values > kMaxPriorValues)
          value_error("bins: " + std::to_string(bins) + " with " + std::to_string(s.shape(1)) + " bands makes " +
                      to_str(values) + " covariance values; expected bins x bands x bands <= 2^27");
        const wiener::SpectralPrior p = wiener::estimate_prior(to_stacks(s), bins);
        Array cov({py::ssize_t(p.bins), py::ssize_t(p.bands), py::ssize_t(p.bands)});  // bins x bands x bands
        std::copy(p.cov.begin(), p.cov.end(), cov.mutable_data());
        return cov;
      },
      py::arg("scenes"), py::arg("bins") = 16);
  m.def(
      "wiener_decode",
      [](const py::handle& y_obj, const py::handle& psf_obj, const py::handle& srf_obj, const py::handle& cov_obj,
         const py::handle& sigma_obj, const std::string& boundary) {
        if (boundary != "circular" && boundary != "linear")
          value_error("boundary: '" + boundary + "'; expected 'circular' or 'linear'");
        const Array y = checked(y_obj, "y", {3, "H", "W"});
        const Array p = checked(psf_obj, "psf", {"bands", "S", "S"});
        if (p.shape(1) != p.shape(2)) value_error("psf: shape " + shape_text(p) + "; expected (bands, S, S), square planes");
        const std::size_t bands = std::size_t(p.shape(0));
        const Array s = checked(srf_obj, "srf", {3, bands});
        const Array c = checked(cov_obj, "prior", {"bins", bands, bands});
        const double sigma = real_arg(sigma_obj, "noise_sigma");
        if (sigma < 0) value_error("noise_sigma: " + short_str(sigma_obj) + "; expected a finite number >= 0");
        wiener::SpectralPrior pr;
        pr.bins = std::size_t(c.shape(0));
        pr.bands = bands;
        pr.rows = std::size_t(y.shape(1));
        pr.cols = std::size_t(y.shape(2));
        pr.cov.assign(c.data(), c.data() + c.size());
        Eigen::MatrixXd srf(s.shape(0), s.shape(1));  // 3 x bands
        for (py::ssize_t i = 0; i < s.shape(0); ++i)
          for (py::ssize_t j = 0; j < s.shape(1); ++j) srf(i, j) = s.at(i, j);
        if (boundary == "linear") {
          // y as a camera records it: the window of a scene larger by the PSF (tiled.hpp).
          if (!(sigma > 0)) value_error("noise_sigma: " + short_str(sigma_obj) + "; expected > 0 with boundary='linear'");
          return from_stack(wiener_decode_linear(to_stack(y), to_stack(p), srf, pr, sigma));
        }
        try {
          return from_stack(wiener::decode(to_stack(y), wiener::psf_to_otf(to_stack(p), pr.rows, pr.cols), srf, pr, sigma));
        } catch (const InputError&) {
          throw;
        } catch (const Error& e) {
          // With noise_sigma > 0 the filter is never singular: a singular one is noise_sigma = 0's.
          if (sigma == 0) value_error(std::string("noise_sigma: 0; ") + e.what());
          throw;
        }
      },
      py::arg("y"), py::arg("psf"), py::arg("srf"), py::arg("prior"), py::arg("noise_sigma"), py::arg("boundary") = "circular");
}
