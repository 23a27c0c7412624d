#include <doctest/doctest.h>

#include <cmath>
#include <string>

#include "qdo/runtime/error.hpp"
#include "qdo/data/materials.hpp"

using qdo::material_by_name;

TEST_SUITE("materials") {
  TEST_CASE("reference indices") {
    // REFERENCE §1: SK-1300 n(700) = 1.45546; catalogue n_d of N-BK7 and fused silica.
    CHECK(std::abs(material_by_name("OHARA_SK1300").index(700) - 1.45546) < 1e-5);
    CHECK(std::abs(material_by_name("SCHOTT_N-BK7").index(587.6) - 1.5168) < 1e-4);
    CHECK(std::abs(material_by_name("fused_silica_Malitson1965").index(587.6) - 1.4585) < 1e-4);
    // NOA61: Cauchy A + B/l^2 + C/l^4 (l in um), written out independently.
    const double l_um = 0.589;
    const double cauchy = 1.5375 + 0.00829045 / (l_um * l_um) - 0.000211046 / std::pow(l_um, 4);
    const double n_noa = material_by_name("NOA61").index(589);
    CHECK(std::abs(n_noa - cauchy) < 1e-12);
    CHECK(std::abs(n_noa - 1.56) < 0.01);
  }

  TEST_CASE("normal dispersion 400-700 nm") {
    for (const auto& name : qdo::material_names()) {
      CAPTURE(name);
      const auto& m = material_by_name(name);
      CHECK(m.name == name);
      CHECK_FALSE(m.source.empty());
      CHECK(m.min_wavelength_nm <= 400);
      CHECK(m.max_wavelength_nm >= 700);
      double prev = m.index(400);
      for (double wl = 410; wl <= 700; wl += 10) {
        const double cur = m.index(wl);
        CHECK(cur < prev);
        CHECK(cur > 1.3);
        CHECK(cur < 1.7);
        prev = cur;
      }
    }
    CHECK(qdo::material_names().size() == 4);
  }

  TEST_CASE("out-of-range wavelength names the material and the argument") {
    const auto& sk = material_by_name("OHARA_SK1300");
    CHECK_THROWS_WITH_AS(sk.index(300, "my_wavelength_arg"), doctest::Contains("my_wavelength_arg"), qdo::InputError);
    CHECK_THROWS_WITH_AS(sk.index(300, "my_wavelength_arg"), doctest::Contains("OHARA_SK1300"), qdo::InputError);
    CHECK_THROWS_WITH_AS(sk.index(2000), doctest::Contains("wavelength_nm"), qdo::InputError);
    CHECK_THROWS_AS(sk.index(std::nan("")), qdo::InputError);
    CHECK_THROWS_WITH_AS(material_by_name("NOA61").index(350, "wavelength_start_nm"), doctest::Contains("NOA61"),
                         qdo::InputError);
    CHECK_NOTHROW(sk.index(sk.min_wavelength_nm));
    CHECK_NOTHROW(sk.index(sk.max_wavelength_nm));
  }

  TEST_CASE("unknown material lists the known names") {
    for (const char* expected : {"material", "unobtainium", "OHARA_SK1300", "SCHOTT_N-BK7", "fused_silica_Malitson1965", "NOA61"}) {
      CAPTURE(expected);
      CHECK_THROWS_WITH_AS(material_by_name("unobtainium"), doctest::Contains(expected), qdo::InputError);
    }
  }

  TEST_CASE("aliases") {
    CHECK(material_by_name("sk1300").name == "OHARA_SK1300");
    CHECK(material_by_name("SK-1300").name == "OHARA_SK1300");
    CHECK(material_by_name("bk7").name == "SCHOTT_N-BK7");
    CHECK(material_by_name("N-BK7").name == "SCHOTT_N-BK7");
    CHECK(material_by_name("fused_silica").name == "fused_silica_Malitson1965");
    CHECK(material_by_name("Silica").name == "fused_silica_Malitson1965");
    CHECK(material_by_name("noa61").name == "NOA61");
    CHECK(&material_by_name("BK7") == &material_by_name("SCHOTT_N-BK7"));
  }
}
