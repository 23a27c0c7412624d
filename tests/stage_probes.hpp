// Host copies of the PSF chain's fields for tests, made by the stages themselves (FieldStage,
// PropagationStage) built on a Simulator's runtime, configuration and precision from its current
// heights (one design). Fresh stages and buffers per call: the Simulator's own state (its field,
// sampling report and adjoints) is left alone. Fields: bands x M x M, centred window of
// PropagationGeometry (the layout of ref::doe_field and ref::propagate).
#pragma once
#include <doctest/doctest.h>

#include <vector>

#include "qdo/physics/field.hpp"
#include "qdo/physics/propagate.hpp"
#include "qdo/physics/simulator.hpp"

namespace qdo::test {

namespace probe_detail {
// The simulator's heights (N x N) in a new device buffer of its precision.
inline cl::Buffer heights_buffer(const Simulator& sim) {
  Runtime& rt = sim.runtime();
  const Map2D h = sim.heights();
  cl::Buffer b(rt.context(), CL_MEM_READ_WRITE, h.data.size() * real_size(sim.precision()));
  rt.write_reals(b, h.data.data(), h.data.size(), sim.precision());
  return b;
}
inline cl::Buffer field_buffer(const Simulator& sim) {
  const std::size_t m = sim.geometry().m;
  return cl::Buffer(sim.runtime().context(), CL_MEM_READ_WRITE, sim.config().bands * m * m * 2 * real_size(sim.precision()));
}
}  // namespace probe_detail

// The field just after the DOE.
inline ComplexStack field_after_doe(const Simulator& sim) {
  FieldStage field(sim.runtime(), sim.config(), sim.precision(), 1, sim.phase_fp64());
  cl::Buffer f = probe_detail::field_buffer(sim);
  field.run(probe_detail::heights_buffer(sim), f);
  return field.centred(f);
}

// The field after propagation over the sensor distance (unpruned: the whole window), and the
// sampling report of that propagation when `sampling` is given (energy_outside_window 0: no crop).
inline ComplexStack field_after_propagation(const Simulator& sim, SamplingReport* sampling = nullptr) {
  FieldStage field(sim.runtime(), sim.config(), sim.precision(), 1, sim.phase_fp64());
  PropagationStage propagation(sim.runtime(), sim.config(), sim.precision());
  cl::Buffer f = probe_detail::field_buffer(sim);
  field.run(probe_detail::heights_buffer(sim), f);
  propagation.run(f, sim.config().sensor_distance_m, true, false);
  if (sampling) *sampling = propagation.sampling(nullptr);
  return field.centred(f);
}

// An arbitrary bands x M x M field (any layout) propagated over z_m on the device.
inline ComplexStack propagate_field(const Simulator& sim, const ComplexStack& field, double z_m) {
  const std::size_t m = sim.geometry().m;
  REQUIRE(field.planes == sim.config().bands);
  REQUIRE(field.rows == m);
  REQUIRE(field.cols == m);
  Runtime& rt = sim.runtime();
  std::vector<double> flat(field.size() * 2);
  for (std::size_t i = 0; i < field.size(); ++i) {
    flat[2 * i] = field.data[i].real();
    flat[2 * i + 1] = field.data[i].imag();
  }
  cl::Buffer f = probe_detail::field_buffer(sim);
  rt.write_reals(f, flat.data(), flat.size(), sim.precision());
  PropagationStage propagation(rt, sim.config(), sim.precision());
  propagation.run(f, z_m, false, false);
  rt.read_reals(f, flat.data(), flat.size(), sim.precision());
  ComplexStack out(field.planes, field.rows, field.cols);
  for (std::size_t i = 0; i < out.size(); ++i) out.data[i] = cdouble(flat[2 * i], flat[2 * i + 1]);
  return out;
}

}  // namespace qdo::test
