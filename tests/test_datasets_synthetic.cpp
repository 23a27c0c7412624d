// Training scenes, synthetic: generated scenes lie in [0, 1], are reproducible and are mixtures
// of the measured tables.
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <set>
#include <string>
#include <vector>

#include "common.hpp"
#include "datasets_common.hpp"
#include "qdo/data/config.hpp"
#include "qdo/data/datasets.hpp"
#include "qdo/runtime/embedded.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"

namespace fs = std::filesystem;
using namespace qdo;
using namespace qdo::test::datasets_suite;

TEST_SUITE("datasets") {
  TEST_CASE("synthetic scenes: in [0, 1], reproducible, mixtures of the measured tables") {
    const SystemConfig cfg = preset_config("paper");
    const SyntheticScene s = synthetic_scene_detail(cfg, 96, 1234);
    const std::size_t B = cfg.wavelengths_nm().size();
    REQUIRE(s.cube.planes == B);
    REQUIRE(s.cube.rows == 96);
    REQUIRE(s.cube.cols == 96);
    CHECK(std::all_of(s.cube.data.begin(), s.cube.data.end(), [](double v) { return std::isfinite(v) && v >= 0 && v <= 1; }));
    CHECK(*std::max_element(s.cube.data.begin(), s.cube.data.end()) > 0.05);
    CHECK(same(synthetic_scene(cfg, 96, 1234), s.cube));
    CHECK_FALSE(same(synthetic_scene(cfg, 96, 1235), s.cube));
    std::set<std::uint32_t> labels(s.label.begin(), s.label.end());
    CHECK(labels.size() >= 3);  // background plus visible shapes

    // Every material is a row of an embedded table (checked against the table here) and every
    // pixel is albedo x that row x the illuminant.
    auto table_row = [](const std::string& tag) {
      const std::size_t colon = tag.find(':');
      const CsvTable t = parse_csv(embedded_file(tag.substr(0, colon)), tag);
      const std::string name = tag.substr(colon + 1);
      for (std::size_t r = 0; r < t.raw[0].size(); ++r)
        if (t.raw[0][r] == name) {
          std::vector<double> v;
          for (std::size_t c = 1; c < t.header.size(); ++c) v.push_back(t.columns[c][r]);
          return v;
        }
      FAIL("row " << tag << " not found");
      return std::vector<double>();
    };
    std::vector<double> illum = table_row(s.illuminant);
    const double imax = *std::max_element(illum.begin(), illum.end());
    for (double& v : illum) v /= imax;
    REQUIRE(illum.size() == B);
    for (std::size_t b = 0; b < B; ++b) CHECK(s.illuminant_spd[b] == doctest::Approx(illum[b]).epsilon(1e-12));
    for (std::size_t m = 0; m < s.material.size(); ++m) {
      const std::vector<double> row = table_row(s.material[m]);
      for (std::size_t b = 0; b < B; ++b) REQUIRE(s.reflectance[m][b] == doctest::Approx(std::clamp(row[b], 0.0, 1.0)));
    }
    double worst = 0;
    for (std::size_t y = 0; y < 96; ++y)
      for (std::size_t x = 0; x < 96; ++x) {
        const std::size_t i = y * 96 + x;
        const std::vector<double>& r = s.reflectance[s.label[i]];
        // The best non-negative multiple of r x illuminant, and the residual.
        double num = 0, den = 0;
        for (std::size_t b = 0; b < B; ++b) {
          num += s.cube(b, y, x) * r[b] * illum[b];
          den += r[b] * illum[b] * r[b] * illum[b];
        }
        const double k = num / den;
        REQUIRE(k >= 0);
        CHECK(k == doctest::Approx(s.albedo.data[i]).epsilon(1e-9));
        for (std::size_t b = 0; b < B; ++b) worst = std::max(worst, std::abs(s.cube(b, y, x) - k * r[b] * illum[b]));
      }
    CHECK(worst < 1e-12);

    // Other band grids are interpolated; outside 400..700 nm is an InputError.
    SystemConfig fine = cfg;
    fine.wavelength_step_nm = 5;
    fine.bands = 61;
    const RealStack f = synthetic_scene(fine, 16, 5);
    CHECK(f.planes == 61);
    CHECK(std::all_of(f.data.begin(), f.data.end(), [](double v) { return std::isfinite(v) && v >= 0 && v <= 1; }));
    SystemConfig uv = cfg;
    uv.wavelength_start_nm = 380;
    CHECK_THROWS_AS(synthetic_scene(uv, 16, 5), InputError);
    CHECK_THROWS_AS(synthetic_scene(cfg, 0, 5), InputError);
  }
}
