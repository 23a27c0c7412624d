// Fuzz target: CSV spectral tables: the parser, and the camera response built from a CSV file
// (SystemConfig::camera = path, srf_interpolate on).
#include <cmath>

#include "fuzz_util.hpp"
#include "qdo/data/config.hpp"
#include "qdo/data/io.hpp"
#include "qdo/physics/optics.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace qdo;
  const std::string text(reinterpret_cast<const char*>(data), size);
  try {
    const CsvTable t = parse_csv(text, "fuzz.csv");
    if (t.columns.size() != t.header.size() || t.raw.size() != t.header.size()) fuzz::fail("CSV columns != header");
    for (std::size_t c = 0; c < t.columns.size(); ++c)
      if (t.columns[c].size() != t.columns[0].size() || t.raw[c].size() != t.columns[0].size())
        fuzz::fail("CSV columns of different lengths");
  } catch (const InputError& e) {
    fuzz::expect_names(e, "fuzz.csv");
  }
  const std::string path = fuzz::scratch().write("camera.csv", data, size);
  static const SystemConfig base = [] {
    SystemConfig c = preset_config("small");
    c.bands = 4;
    c.wavelength_start_nm = 420;
    c.wavelength_step_nm = 90;
    c.srf_interpolate = true;
    return c;
  }();
  SystemConfig cfg = base;
  cfg.camera = path;
  try {
    const Eigen::MatrixXd s = sensor_response(cfg);
    for (Eigen::Index r = 0; r < s.rows(); ++r) {
      double sum = 0;
      for (Eigen::Index b = 0; b < s.cols(); ++b) {
        if (!std::isfinite(s(r, b)) || s(r, b) < 0) fuzz::fail("sensor_response accepted a negative or non-finite value");
        sum += s(r, b);
      }
      if (std::fabs(sum - 1) > 1e-9) fuzz::fail("sensor_response row does not sum to 1");
    }
  } catch (const InputError& e) {
    fuzz::expect_names(e, path);
  }
  return 0;
}
