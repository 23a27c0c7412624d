// The figures the commands write, read back from their SVGs: each has its title, axis labels with
// units, a colour bar label or legend entries, and a PNG beside it (figure.hpp draws them).
#include <doctest/doctest.h>

#include <filesystem>
#include <string>
#include <vector>

#include "common.hpp"
#include "svg_text.hpp"

namespace fs = std::filesystem;
using namespace qdo::test;

namespace {

// `png` exists and its SVG holds every text of `expect` (as part of some <text> element).
void check_svg(const fs::path& png, const std::vector<std::string>& expect) {
  CAPTURE(png.string());
  REQUIRE(fs::is_regular_file(png));
  fs::path svg = png;
  svg.replace_extension(".svg");
  REQUIRE(fs::is_regular_file(svg));
  const auto texts = svg_texts(svg.string());
  for (const std::string& t : expect) {
    CAPTURE(t);
    CHECK(svg_has(texts, t));
  }
}

}  // namespace

TEST_SUITE("figure") {
  TEST_CASE("qdo psf, design and eval write figures with titles, axes in units, colour bars and legends") {
    const fs::path t = temp_dir("figure_commands");
    const Run psf = qdo_run("psf --preset small --design lens:550 --out " + (t / "psf").string());
    REQUIRE_MESSAGE(psf.code == 0, psf.out);
    check_svg(t / "psf" / "psf.png", {"PSF stack on the sensor", "400 nm", "700 nm", "x (µm)", "y (µm)", "PSF / panel maximum"});
    check_svg(t / "psf" / "design.png", {"DOE height map", "x (mm)", "y (mm)", "height (nm)"});
    const Run pts = qdo_run("psf --preset small --design lens:550 --object-distances 0.5,inf --out " + (t / "pts").string());
    REQUIRE_MESSAGE(pts.code == 0, pts.out);
    check_svg(t / "pts" / "psf.png", {"PSF of each object point", "0.5 m, 0 deg", "inf, 0 deg", "PSF / panel maximum"});
    const Run run = qdo_run("design --preset small --recipe qdo --mode qdo+a --levels 4 --epochs 2 --steps-per-epoch 2 --out " +
                            (t / "run").string());
    REQUIRE_MESSAGE(run.code == 0, run.out);
    check_svg(t / "run" / "loss.png", {"Training loss: run", "optimiser step", "loss", "loss per step"});
    check_svg(t / "run" / "design.png", {"DOE height map: run", "height (nm)"});
    check_svg(t / "run" / "psf.png", {"PSF stack on the sensor: run", "550 nm"});
    const Run ev = qdo_run("eval " + (t / "run").string() + " --renders 1 --out " + (t / "eval").string());
    REQUIRE_MESSAGE(ev.code == 0, ev.out);
    check_svg(t / "eval" / "spectra_0.png", {"Spectra of test patch 0", "wavelength (nm)", "radiance", "truth", "reconstruction"});
    fs::remove_all(t);
  }
}
