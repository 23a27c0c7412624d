#include "qdo/data/materials.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>

#include "qdo/runtime/error.hpp"

namespace qdo {
namespace {

// Coefficients copied as data from the project data set's spectral/sellmeier_coefficients.csv and
// noa61_cauchy.csv (sources named there and repeated in `source`).
std::vector<Material> make_table() {
  std::vector<Material> t;
  {
    Material m;
    m.name = "OHARA_SK1300";
    m.formula = "sellmeier3";
    const double c[6] = {7.44386780E-01, 4.95119834E-03, 3.60198890E-01, 1.41130274E-02, 9.18623119E-01, 1.00428510E+02};
    std::copy(c, c + 6, m.coef);
    // The release gives no validity range; we allow the visible/NIR range its data covers.
    m.min_wavelength_nm = 360;
    m.max_wavelength_nm = 1100;
    m.source = "wang-lizhi/QuantizationAwareDeepOptics constants.py (Sellmeier)";
    t.push_back(m);
  }
  {
    Material m;
    m.name = "SCHOTT_N-BK7";
    m.formula = "sellmeier3";
    const double c[6] = {1.03961212, 0.00600069867, 0.231792344, 0.0200179144, 1.01046945, 103.560653};
    std::copy(c, c + 6, m.coef);
    m.min_wavelength_nm = 300;  // Schott catalogue range 0.3-2.5 µm
    m.max_wavelength_nm = 2500;
    m.source = "Schott N-BK7 catalogue (as in QDO constants.py)";
    t.push_back(m);
  }
  {
    Material m;
    m.name = "fused_silica_Malitson1965";
    m.formula = "sellmeier3";
    const double c[6] = {0.6961663, 0.00467914825849, 0.4079426, 0.01351206307396, 0.8974794, 97.934002537921};
    std::copy(c, c + 6, m.coef);
    m.min_wavelength_nm = 210;
    m.max_wavelength_nm = 6700;
    m.source = "I.H. Malitson, JOSA 55, 1205 (1965), via refractiveindex.info";
    t.push_back(m);
  }
  {
    Material m;
    m.name = "NOA61";
    m.formula = "cauchy";
    const double c[6] = {1.5375, 0.00829045, -0.000211046, 0, 0, 0};
    std::copy(c, c + 6, m.coef);
    m.min_wavelength_nm = 400;  // Cauchy fit of visible data
    m.max_wavelength_nm = 1000;
    m.source = "Norland NOA61 Cauchy fit (QDO constants.py, refractiveindex.info)";
    t.push_back(m);
  }
  return t;
}

const std::vector<Material>& table() {
  static const std::vector<Material> t = make_table();
  return t;
}

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char ch) { return std::tolower(ch); });
  return s;
}

}  // namespace

double Material::index(double wavelength_nm, const std::string& argument) const {
  if (!std::isfinite(wavelength_nm) || wavelength_nm < min_wavelength_nm || wavelength_nm > max_wavelength_nm) {
    reject(argument, wavelength_nm,
           "outside the validity range of " + name + " (" + to_str(min_wavelength_nm) + " to " +
               to_str(max_wavelength_nm) + " nm)");
  }
  const double l_um = wavelength_nm * 1e-3;
  const double l2 = l_um * l_um;
  if (formula == "cauchy") return coef[0] + coef[1] / l2 + coef[2] / (l2 * l2);
  double n2 = 1.0;
  for (int i = 0; i < 3; ++i) n2 += coef[2 * i] * l2 / (l2 - coef[2 * i + 1]);
  return std::sqrt(n2);
}

const Material& material_by_name(const std::string& name) {
  const std::string l = lower(name);
  std::string canon = name;
  if (l == "sk1300" || l == "ohara_sk1300" || l == "sk-1300") canon = "OHARA_SK1300";
  else if (l == "bk7" || l == "n-bk7" || l == "schott_n-bk7") canon = "SCHOTT_N-BK7";
  else if (l == "fused_silica" || l == "silica" || l == "fused_silica_malitson1965") canon = "fused_silica_Malitson1965";
  else if (l == "noa61") canon = "NOA61";
  for (const auto& m : table())
    if (m.name == canon) return m;
  std::string allowed;
  for (const auto& m : table()) allowed += (allowed.empty() ? "" : ", ") + m.name;
  reject("material", name, "one of " + allowed);
}

std::vector<std::string> material_names() {
  std::vector<std::string> out;
  for (const auto& m : table()) out.push_back(m.name);
  return out;
}

}  // namespace qdo
