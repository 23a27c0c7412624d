// The adjoint table (suite `adjoint`, run by tests/test_adjoint.cpp): every forward/adjoint pair of
// the PSF chain, the parameterizations and the quantizer, the radial engine, the encoders, the
// design loop, the Wiener decoder, joint training and the raw stage, one Stage row each, all
// through the one ladder body of tests/adjoint_ladder.hpp.
// Each group of rows is built next to the fixtures it needs, in the test file of its operator, and
// registers itself there: QDO_ADJOINT_ROWS(id, "title") { ... return rows; }. A new operator's rows
// touch no central list; the suite runs every registered group (its seeds derived from the title,
// so adding a group changes no other group's inputs). (The camera operator's and the device Wiener
// objective's rows run in their own suites, test_camera.cpp and test_wiener_device.cpp, through the
// same body.)
#pragma once
#include <complex>
#include <string>
#include <vector>

#include "adjoint_ladder.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo::test {

// A registered group of rows: its title and the function that builds them.
struct AdjointGroup {
  std::string title;
  std::vector<Stage> (*rows)();
};
// Every group registered by QDO_ADJOINT_ROWS in the test binary, in registration order.
inline std::vector<AdjointGroup>& adjoint_groups() {
  static std::vector<AdjointGroup> groups;
  return groups;
}
struct AdjointGroupRegistrar {
  AdjointGroupRegistrar(const char* title, std::vector<Stage> (*rows)()) { adjoint_groups().push_back({title, rows}); }
};

// A complex vector as interleaved (re, im) reals and back: the ladder's real inner product of two
// such vectors is Re <a, b>, so the adjoint of a complex-linear map A is A^H.
inline std::vector<double> interleave(const std::vector<cdouble>& z) {
  std::vector<double> x(2 * z.size());
  for (std::size_t i = 0; i < z.size(); ++i) {
    x[2 * i] = z[i].real();
    x[2 * i + 1] = z[i].imag();
  }
  return x;
}
inline std::vector<cdouble> deinterleave(const std::vector<double>& x) {
  std::vector<cdouble> z(x.size() / 2);
  for (std::size_t i = 0; i < z.size(); ++i) z[i] = cdouble(x[2 * i], x[2 * i + 1]);
  return z;
}

}  // namespace qdo::test

// Defines and registers a group of adjoint-table rows: QDO_ADJOINT_ROWS(id, "title") { ... }, the
// body returning std::vector<qdo::test::Stage>; id is an identifier unique in the test binary.
#define QDO_ADJOINT_ROWS(ID, TITLE)                                                                        \
  static std::vector<::qdo::test::Stage> qdo_adjoint_rows_##ID();                                          \
  static const ::qdo::test::AdjointGroupRegistrar qdo_adjoint_registrar_##ID(TITLE, &qdo_adjoint_rows_##ID); \
  static std::vector<::qdo::test::Stage> qdo_adjoint_rows_##ID()
