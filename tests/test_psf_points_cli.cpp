// qdo psf with several object points: the points x bands x S x S stack of one batched pass equals
// one-point runs, the points' table in psf.h5 and points.csv, off-axis PSFs where their chief rays
// land, and a points stack refused as a camera PSF with the reason.
#include <doctest/doctest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "common.hpp"
#include "qdo/data/config.hpp"
#include "qdo/data/io.hpp"

namespace fs = std::filesystem;
using namespace qdo;
using namespace qdo::test;

namespace {

std::vector<std::vector<std::string>> read_csv_rows(const fs::path& p) {
  std::ifstream in(p);
  std::vector<std::vector<std::string>> rows;
  std::string line;
  while (std::getline(in, line)) {
    std::vector<std::string> cells;
    std::stringstream ss(line);
    std::string c;
    while (std::getline(ss, c, ',')) cells.push_back(c);
    rows.push_back(cells);
  }
  return rows;
}

}  // namespace

TEST_SUITE("objpts") {
  TEST_CASE("qdo psf with four object points writes a 4 x 31 x S x S stack equal to four one-point runs") {
    const fs::path t = temp_dir("psf_points");
    const std::string common = "psf --preset small --design lens:550 --out ";
    const Run four = qdo_run(common + (t / "four").string() + " --object-distances 0.5,1,2,inf");
    CAPTURE(four.out);
    REQUIRE(four.code == 0);
    const H5Dataset all = h5_read((t / "four" / "psf.h5").string(), "/psf_sensor");
    REQUIRE(all.shape.size() == 4);
    CHECK(all.shape[0] == 4);
    CHECK(all.shape[1] == 31);
    const std::size_t plane_stack = all.shape[1] * all.shape[2] * all.shape[3];
    const std::vector<std::string> d = {"0.5", "1", "2", "inf"};
    for (std::size_t p = 0; p < d.size(); ++p) {
      CAPTURE(d[p]);
      const Run one = qdo_run(common + (t / ("one_" + d[p])).string() + " --object-distances " + d[p]);
      REQUIRE(one.code == 0);
      const H5Dataset single = h5_read((t / ("one_" + d[p]) / "psf.h5").string(), "/psf_sensor");
      REQUIRE(single.shape == std::vector<std::size_t>{all.shape[1], all.shape[2], all.shape[3]});
      // The same float32 kernels on the same planes: equal to rounding (bit-equal on PoCL).
      double worst = 0, peak = 0;
      for (std::size_t k = 0; k < plane_stack; ++k) {
        worst = std::max(worst, std::abs(all.data[p * plane_stack + k] - single.data[k]));
        peak = std::max(peak, single.data[k]);
      }
      CHECK(worst <= 1e-6 * peak);
    }
    // The points' table: 1 / distance (0 at infinity) and the field angles, in the stack's order.
    const H5Dataset pts = h5_read((t / "four" / "psf.h5").string(), "/object_points");
    REQUIRE(pts.shape == std::vector<std::size_t>{4, 5});
    CHECK(pts.data[0] == doctest::Approx(2.0));
    CHECK(pts.data[5] == doctest::Approx(1.0));
    CHECK(pts.data[10] == doctest::Approx(0.5));
    CHECK(pts.data[15] == 0.0);
    const auto rows = read_csv_rows(t / "four" / "points.csv");
    REQUIRE(rows.size() == 5);
    CHECK(rows[4][1] == "inf");
    fs::remove_all(t);
  }

  TEST_CASE("qdo psf over field angles: each PSF's centroid sits at its chief ray's image point; a points stack is no camera PSF") {
    const fs::path t = temp_dir("psf_angles");
    const Run r = qdo_run("psf --preset small --design lens:550 --field-angles 0,1,2:-1 --out " + (t / "a").string());
    CAPTURE(r.out);
    REQUIRE(r.code == 0);
    const auto rows = read_csv_rows(t / "a" / "points.csv");
    REQUIRE(rows.size() == 4);
    const SystemConfig cfg = preset_config("small");
    for (std::size_t i = 1; i < rows.size(); ++i) {
      CAPTURE(i);
      const double ax = std::stod(rows[i][2]), ay = std::stod(rows[i][3]);
      const double cx = std::stod(rows[i][4]), cy = std::stod(rows[i][5]);   // chief ray, um
      const double gx = std::stod(rows[i][6]), gy = std::stod(rows[i][7]);   // centroid at 550 nm, um
      const double ee80 = std::stod(rows[i][9]);
      // The chief ray through the DOE centre meets the sensor at -z tan(theta).
      CHECK(cx == doctest::Approx(-cfg.sensor_distance_m * std::tan(ax * M_PI / 180) * 1e6).epsilon(1e-6));
      CHECK(cy == doctest::Approx(-cfg.sensor_distance_m * std::tan(ay * M_PI / 180) * 1e6).epsilon(1e-6));
      // A lens for 550 nm images the point there: the centroid within its own 80 % radius.
      CHECK(std::hypot(gx - cx, gy - cy) < ee80);
      CHECK(std::stod(rows[i][11]) > 0.99);  // the PSF is inside the window
    }
    const Run sim = qdo_run("simulate --preset small --psf " + (t / "a" / "psf.h5").string() + " --out " + (t / "sim").string());
    CHECK(sim.code == 2);
    CHECK(sim.out.find("3 object points") != std::string::npos);
    fs::remove_all(t);
  }
}
