// Dispersion of DOE materials. Wavelengths in nm at the interface; the formulas use µm.
#pragma once
#include <string>
#include <vector>

namespace qdo {

struct Material {
  std::string name;        // canonical name, e.g. "OHARA_SK1300"
  std::string formula;     // "sellmeier3" or "cauchy"
  double coef[6] = {0, 0, 0, 0, 0, 0};  // Sellmeier: B1,C1,B2,C2,B3,C3 (C in µm²); Cauchy: A,B,C
  double min_wavelength_nm = 0, max_wavelength_nm = 0;  // validity range of the formula
  std::string source;      // where the coefficients come from

  // Refractive index at wavelength_nm. Throws InputError naming `argument` when the
  // wavelength is outside [min_wavelength_nm, max_wavelength_nm].
  double index(double wavelength_nm, const std::string& argument = "wavelength_nm") const;
};

// Known materials: OHARA_SK1300, SCHOTT_N-BK7, fused_silica_Malitson1965, NOA61.
// Aliases accepted (case-insensitive): sk1300, bk7, n-bk7, fused_silica, silica, noa61.
const Material& material_by_name(const std::string& name);
std::vector<std::string> material_names();

}  // namespace qdo
